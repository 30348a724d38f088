"""Node processes forked from a preloaded parent instead of started from nothing.

A twinslam node process spends ~1.5 s of CPU before its first frame: 0.7 s importing rclpy,
numpy, OpenCV, GTSAM and the project, 0.8 s for numba to load its cached kernels (its runtime
compiled anew, its linear-algebra check importing SciPy). A run starts three such processes,
an evaluation dozens, and on a busy 2-core machine a node took ~30 s to come up. A *fork
server* pays that once: a process imports the node modules and loads their kernels, then forks
one child per node asked for; each child is the node's own process (own pid, signals, exit
code, DDS participant) with the environment, arguments and working directory it was asked
for, and its stdout and stderr on the asker's pipes — the same contract as ``python -m``.

Protocol (one ``AF_UNIX`` ``SOCK_SEQPACKET`` socket, JSON messages): the client sends
``{"ref", "module", "argv", "env", "cwd", "netns"}`` with the child's stdout and stderr as
ancillary file descriptors (``SCM_RIGHTS``); ``netns``, when not null, is a network
namespace the child enters before it runs (a host of :mod:`twinslam.hosts.netns`: its
DDS participants then live on that host's interfaces, and ``/proc/net`` shows them, as under
``ip netns exec``); the server answers ``{"ref", "pid"}`` once forked and
``{"pid", "code"}`` when the child has exited (``code`` as :attr:`subprocess.Popen.returncode`:
negative for a signal). The server ends when its socket closes; its children are killed with
it (``PR_SET_PDEATHSIG``), so no node outlives the process that asked for it unseen.

Only what fork keeps is preloaded: modules and compiled kernels — no rclpy context, no DDS
participant, no thread of its own. The libraries it imports start some: gdb on a running server
shows liblttng-ust's two listener threads (rcl's tracing, loaded with rclpy) and one more
waiting on a condition variable beside the main thread (2026-12-01). A child forked while one
of them holds a lock would find it locked. While no LTTng session daemon runs, the two
listeners wait on a futex in shared memory (``/dev/shm/lttng-ust-wait-*``, a bare futex call
from ``ust_listener_thread``, no mutex wait), holding no lock from their first try at start
until a daemon appears: no lock a child would inherit held. What stalled forked edges a few
times under load — and once an edge started by ``python -m`` — is not known
(docs/benchmarks/test-suite.md, 2026-12-01, night).
Whatever a library reads from the environment at import (threads of
the BLAS, numba's settings, ``PYTHONPATH``) must be what the child would have read, so a
server serves only requests whose environment equals its own but for the ROS/DDS settings
(:data:`PER_CHILD_PREFIXES`) and what changes with every call (:data:`PER_CHILD_NAMES`);
:class:`ForkServers` starts one server per such environment.
"""

from __future__ import annotations

import atexit
import ctypes
import ctypes.util
import json
import os
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import traceback
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO, Any, Protocol

#: environment variables a forked child may set for itself: read when the child makes its
#: rclpy context and DDS participant, never at import
PER_CHILD_PREFIXES = ("ROS_", "RMW_", "FASTRTPS_", "FASTDDS_", "CYCLONEDDS_", "RCUTILS_")
#: variables that change with every call of the asker and that no module reads at import:
#: pytest names the running test in PYTEST_CURRENT_TEST, and keying on it started a server
#: (~4 s of CPU) for every test that launched nodes — 25 in one run of the suite; the player
#: reads its cache of decoded frames (twinslam.sequences.decoded_frames) when it opens its
#: sequence
PER_CHILD_NAMES = frozenset({"PYTEST_CURRENT_TEST", "TWINSLAM_FRAME_CACHE",
                             "TWINSLAM_FRAME_CACHE_GB"})
#: the largest request (the environment dominates it)
MAX_MESSAGE = 1 << 20
#: how long a server may take to preload before it is given up (a fresh checkout compiles the
#: kernels: about a minute on 2 cores)
READY_TIMEOUT_S = 300.0
PR_SET_NAME = 15                #: prctl options (linux/prctl.h)
PR_SET_PDEATHSIG = 1
CLONE_NEWNET = 0x40000000       #: setns(2)'s namespace type of a network namespace


class ForkServerError(RuntimeError):
    """The fork server could not be started, or failed to fork a child."""


def enter_network_namespace(path: str) -> None:
    """Move the calling thread into the network namespace at ``path`` (``/run/netns/NAME``, or
    a ``/proc/…/ns/net`` to come back); OSError naming it when the kernel refuses (it needs
    CAP_SYS_ADMIN). Threads and participants made afterwards live there."""
    libc = ctypes.CDLL(None, use_errno=True)
    fd = os.open(path, os.O_RDONLY)
    try:
        if libc.setns(fd, CLONE_NEWNET) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"setns({path}) failed: {os.strerror(err)}")
    finally:
        os.close(fd)


def import_time_env(env: Mapping[str, str]) -> tuple[tuple[str, str], ...]:
    """The part of ``env`` a preloaded process has already read: all but the per-child
    settings."""
    return tuple(sorted((k, v) for k, v in env.items()
                        if not k.startswith(PER_CHILD_PREFIXES) and k not in PER_CHILD_NAMES))


# -- the server ------------------------------------------------------------------------------

def serve(sock: socket.socket, mains: Mapping[str, Callable[[list[str] | None], int]]) -> None:
    """Fork a child per request read from ``sock`` until it closes; ``mains`` maps a module
    name to the function ``python -m module`` would run (its ``main``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # a terminal's Ctrl-C is for the nodes
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_r, False)
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda _signum, _frame: None)
    selector = selectors.DefaultSelector()
    selector.register(sock, selectors.EVENT_READ)
    selector.register(wake_r, selectors.EVENT_READ)
    while True:
        for key, _ in selector.select():
            if key.fileobj is sock:
                try:
                    data, fds, _, _ = socket.recv_fds(sock, MAX_MESSAGE, 2)
                except ConnectionResetError:
                    data, fds = b"", []
                if not data:
                    return
                request = json.loads(data)
                request["server_pid"] = os.getpid()
                try:
                    pid = os.fork()
                except OSError as exc:
                    _send(sock, {"ref": request["ref"], "error": str(exc)})
                    pid = -1
                if pid == 0:
                    _become_child(request, fds, mains, (sock.fileno(), wake_r, wake_w))
                for fd in fds:
                    os.close(fd)
                if pid > 0:
                    _send(sock, {"ref": request["ref"], "pid": pid})
            else:
                while True:
                    try:
                        if not os.read(wake_r, 512):
                            break
                    except BlockingIOError:
                        break
        _reap(sock)


def _reap(sock: socket.socket) -> None:
    while True:
        try:
            pid, status = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            return
        _send(sock, {"pid": pid, "code": os.waitstatus_to_exitcode(status)})


def _send(sock: socket.socket, message: dict[str, Any]) -> None:
    try:
        sock.send(json.dumps(message).encode())
    except OSError:
        pass                            # the client is gone: the server ends at its next read


def _become_child(request: dict[str, Any], fds: list[int],
                  mains: Mapping[str, Callable[[list[str] | None], int]],
                  server_fds: tuple[int, ...]) -> None:
    """The forked child: the asked-for process, then exit (never returns)."""
    code = 1
    try:
        _die_with_parent(process_name(request["module"]))
        if os.getppid() != request["server_pid"]:    # the server died before the line above
            os._exit(1)
        signal.set_wakeup_fd(-1)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for fd in server_fds:
            os.close(fd)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(fds[0], 1)
        os.dup2(fds[1], 2)
        for fd in (null, *fds):
            os.close(fd)
        sys.stdout = open(1, "w", buffering=1, encoding="utf-8", closefd=False)
        sys.stderr = open(2, "w", buffering=1, encoding="utf-8", errors="backslashreplace",
                          closefd=False)
        if request.get("netns"):
            enter_network_namespace(request["netns"])
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        sys.argv = list(request["argv"])
        code = mains[request["module"]](None)
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if not isinstance(exc.code, int) and exc.code is not None:
            print(exc.code, file=sys.stderr)
    except KeyboardInterrupt:
        traceback.print_exc()
        _flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)     # as Python ends on an unhandled one
        os.kill(os.getpid(), signal.SIGINT)
    except BaseException:
        traceback.print_exc()
        code = 1
    try:
        atexit._run_exitfuncs()
    finally:
        _flush()
        os._exit(code & 0xFF)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


def process_name(module: str) -> str:
    """The name ``top`` and ``ps -o comm`` show for a child running ``module`` (15 bytes at most):
    its package for a ``….node`` module (``device_tracker``), else its last part."""
    return module.removesuffix(".node").rsplit(".", 1)[-1][:15]


def _die_with_parent(name: str) -> None:
    """SIGKILL this process when the server dies, and name it ``name`` (Linux): a forked child
    would otherwise show the server's name."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is not None:
        libc = ctypes.CDLL(libc_name, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        libc.prctl(PR_SET_NAME, ctypes.c_char_p(name.encode()[:15]))


# -- the client ------------------------------------------------------------------------------

class NodeProcess(Protocol):
    """What the launchers use of a node's process: a :class:`subprocess.Popen` started with
    ``text=True`` and piped stdout/stderr, or a :class:`ForkedProcess`."""

    @property
    def pid(self) -> int: ...
    @property
    def returncode(self) -> int | None: ...
    @property
    def stdout(self) -> IO[str] | None: ...
    @property
    def stderr(self) -> IO[str] | None: ...
    def poll(self) -> int | None: ...
    def wait(self, timeout: float | None = None) -> int: ...
    def send_signal(self, sig: int) -> None: ...
    def kill(self) -> None: ...


class ForkedProcess:
    """A child of a fork server, used like a :class:`subprocess.Popen` started with
    ``text=True`` and piped stdout/stderr."""

    def __init__(self, pid: int, args: list[str], stdout: IO[str], stderr: IO[str]) -> None:
        self.pid = pid
        self.args = args
        self.stdout: IO[str] | None = stdout
        self.stderr: IO[str] | None = stderr
        self.returncode: int | None = None
        self._done = threading.Event()

    def _exited(self, code: int) -> None:
        self.returncode = code
        self._done.set()

    def poll(self) -> int | None:
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        if not self._done.wait(timeout):
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:          # never signal a pid that may have been reused
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """A running server process (``python -m server_module``) and the children it forked."""

    def __init__(self, server_module: str, env: Mapping[str, str], cwd: Path) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        self.modules: frozenset[str] = frozenset()
        self._sock = ours
        self._lock = threading.Lock()
        self._next_ref = 0
        self._pending: dict[int, tuple[threading.Event, dict[str, Any]]] = {}
        self._children: dict[int, ForkedProcess] = {}
        self._early: dict[int, int] = {}       #: exit codes that came before their child's pid
        self._alive = True
        self._errors = tempfile.TemporaryFile(mode="w+")   #: the server's own stderr
        try:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", server_module, str(theirs.fileno())], env=dict(env),
                cwd=str(cwd), pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL, stderr=self._errors)
        finally:
            theirs.close()
        self._sock.settimeout(READY_TIMEOUT_S)
        try:                                    # the server says which modules it preloaded
            ready = self._sock.recv(MAX_MESSAGE)
        except TimeoutError:
            self._proc.kill()
            ready = b""
        self._sock.settimeout(None)
        if not ready:
            self._proc.wait()
            self._errors.seek(0)
            err = self._errors.read()
            self._errors.close()
            self._sock.close()
            raise ForkServerError(f"the fork server {server_module} ended at start "
                                  f"({self._proc.returncode}): {err.strip()[-1500:]}")
        self.modules = frozenset(json.loads(ready)["modules"])
        self._reader = threading.Thread(target=self._read, daemon=True, name="fork-server")
        self._reader.start()

    @property
    def alive(self) -> bool:
        return self._alive

    def spawn(self, module: str, args: list[str], env: Mapping[str, str], cwd: Path,
              timeout: float = 30.0, netns: str | None = None) -> ForkedProcess:
        """Fork ``python -m module args...`` with ``env`` and ``cwd`` (in the network
        namespace at ``netns`` if given)."""
        out_r, out_w = os.pipe()
        err_r, err_w = os.pipe()
        with self._lock:
            ref = self._next_ref
            self._next_ref += 1
            answered = threading.Event()
            reply: dict[str, Any] = {}
            self._pending[ref] = (answered, reply)
            message = {"ref": ref, "module": module, "argv": [module, *args], "env": dict(env),
                       "cwd": str(cwd), "netns": netns}
            try:
                socket.send_fds(self._sock, [json.dumps(message).encode()], [out_w, err_w])
            except OSError:
                del self._pending[ref]
                os.close(out_r)
                os.close(err_r)
                raise
            finally:
                os.close(out_w)
                os.close(err_w)
        if not answered.wait(timeout) or "pid" not in reply:
            os.close(out_r)
            os.close(err_r)
            raise ForkServerError(f"the fork server did not fork {module}: "
                                  f"{reply.get('error', 'no answer')}")
        proc = ForkedProcess(int(reply["pid"]), [module, *args],
                             open(out_r, encoding="utf-8", errors="replace"),
                             open(err_r, encoding="utf-8", errors="replace"))
        with self._lock:
            self._children[proc.pid] = proc
            early = self._early.pop(proc.pid, None)
        if early is not None:
            proc._exited(early)
        return proc

    def _read(self) -> None:
        while True:
            try:
                data = self._sock.recv(MAX_MESSAGE)
            except OSError:
                data = b""
            if not data:
                break
            message = json.loads(data)
            with self._lock:
                if "ref" in message:
                    answered, reply = self._pending.pop(message["ref"])
                    reply.update(message)
                    answered.set()
                    continue
                child = self._children.pop(message["pid"], None)
                if child is None:
                    self._early[message["pid"]] = message["code"]
            if child is not None:
                child._exited(int(message["code"]))
        # the server is gone, and its children with it (PR_SET_PDEATHSIG)
        with self._lock:
            self._alive = False
            orphans = list(self._children.values())
            self._children.clear()
            for answered, _ in self._pending.values():
                answered.set()
        for child in orphans:
            child._exited(-signal.SIGKILL)

    def close(self) -> None:
        """End the server (its remaining children are killed with it)."""
        try:
            self._sock.shutdown(socket.SHUT_RDWR)   # wakes the reader: the server sees EOF
        except OSError:
            pass
        self._sock.close()
        try:
            self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        self._errors.close()


class ForkServers:
    """One :class:`ForkServer` of ``server_module`` (which preloads ``modules``) per import-time
    environment, started on first use and kept for the life of this process."""

    def __init__(self, server_module: str, modules: frozenset[str], cwd: Path) -> None:
        self.server_module, self.modules, self.cwd = server_module, modules, cwd
        self._servers: dict[tuple[tuple[str, str], ...], ForkServer] = {}
        self._failed: dict[tuple[tuple[str, str], ...], str] = {}   #: not tried again
        self._lock = threading.Lock()
        atexit.register(self.close)

    def server_for(self, env: Mapping[str, str]) -> ForkServer:
        key = import_time_env(env)
        with self._lock:
            if key in self._failed:
                raise ForkServerError(self._failed[key])
            server = self._servers.get(key)
            if server is None or not server.alive:
                try:
                    server = ForkServer(self.server_module, env, self.cwd)
                except ForkServerError as exc:
                    self._failed[key] = str(exc)
                    raise
                self._servers[key] = server
            return server

    def spawn(self, args: list[str], env: Mapping[str, str], netns: str | None = None
              ) -> NodeProcess | None:
        """``python args...`` forked when ``args`` is ``-m MODULE ...`` of a preloaded module,
        in the network namespace at ``netns`` if given (None otherwise, or when no server
        could be started: the caller starts it itself)."""
        if len(args) < 2 or args[0] != "-m" or args[1] not in self.modules:
            return None
        try:
            return self.server_for(env).spawn(args[1], args[2:], env, self.cwd, netns=netns)
        except (ForkServerError, OSError) as exc:
            print(f"twinslam: starting {args[1]} without the fork server ({exc})",
                  file=sys.stderr)
            return None

    def close(self) -> None:
        with self._lock:
            servers, self._servers = list(self._servers.values()), {}
        for server in servers:
            server.close()


def run_server(argv: list[str], mains: Mapping[str, Callable[[list[str] | None], int]],
               preload: Callable[[], None] = lambda: None) -> int:
    """The server process's main: ``argv[1]`` is its socket's descriptor; ``preload`` loads
    what the children should find loaded (kernels) before the server says it is ready."""
    sock = socket.socket(fileno=int(argv[1]))
    preload()
    sock.send(json.dumps({"modules": sorted(mains)}).encode())
    serve(sock, mains)
    return 0
