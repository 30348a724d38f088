"""A private ROS 2 domain on this machine, for tests, benchmarks and the demo.

Every ``LoopbackDomain`` holds a domain id no other live domain on this machine uses (claimed
with a lock file while it is open, and checked by binding its discovery port) and discovery
limited to this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), with the project's Fast
DDS profile. Node processes started through it inherit that environment and are stopped
(SIGTERM, then SIGKILL) when the domain closes, so a failing test never leaves processes behind.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import queue
import random
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any

from twinslam.hosts.fastdds import (
    ENV_KEYS,
    REPO_ROOT,
    domain_id_from_env,
    installed_profile,
    ros_env,
)
from twinslam.hosts.forked import ForkServers, NodeProcess
from twinslam.hosts.native_stacks import native_stacks
from twinslam.parent_watch import PARENT_ENV

#: participant indexes whose unicast ports a claim checks: RTPS gives participant i of
#: domain d the ports 7400 + 250 d + 10 + 2 i (discovery) and + 11 + 2 i (user data), and a
#: domain's 250 ports hold 120 of them
PARTICIPANT_INDEXES = 120


def _domain_ports_free(domain_id: int) -> bool:
    """Whether no participant of any index holds a unicast port of domain ``domain_id`` on
    this machine. The first participant's discovery port alone (7400 + 250 d + 10) does not
    see a participant at a later index — one the nodes that held the first indexes pushed
    there (Cyclone's ``ParticipantIndex`` auto) and that outlives them — and a run that drew
    its id would hear what it still sends. Checked since a live run's monitor heard another
    test's hostile samples (2026-12-05); that this is how they crossed is not proven."""
    base = 7400 + 250 * domain_id + 10
    for port in range(base, min(base + 2 * PARTICIPANT_INDEXES, 65536)):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                return False
    return True


def _claims_dir() -> Path:
    """Where this machine's users of loopback domains hold their claims (one lock file an id)."""
    folder = Path(tempfile.gettempdir()) / f"twinslam-ros-domains-{os.getuid()}"
    folder.mkdir(mode=0o700, exist_ok=True)
    return folder


#: seconds a killed node is given to be gone (its stop's SIGTERM came first, with ``timeout``)
KILLED_EXIT_S = 30.0


class DomainClaim:
    """A domain id of ``ids`` (100..229) held by this process until :meth:`release` (or its
    exit), claimed in ``folder`` (this machine's claims unless given).

    A free discovery port alone does not reserve an id: two processes that look at the same
    moment (parallel test workers, ``evaluate --jobs``) both see it free until their first
    participant binds it, and their nodes would then talk across runs. The claim is an
    exclusive ``flock`` on a file of the id, which the kernel drops when the holder exits, so a
    killed run never leaves an id taken; the port check still skips an id that something
    outside this scheme (a ROS system on the machine, a participant a released claim left
    behind) is using. ``ports_free`` is that check (tests of the locks alone give one that
    does not look at the machine's ports, which any process on it may hold for a moment).
    """

    def __init__(self, rng: random.Random | None = None, ids: range = range(100, 230),
                 folder: Path | None = None,
                 ports_free: Callable[[int], bool] = _domain_ports_free) -> None:
        rng = rng or random.Random(os.getpid() ^ time.monotonic_ns())
        candidates = list(ids)
        rng.shuffle(candidates)
        folder = folder or _claims_dir()
        for domain_id in candidates:
            fd = os.open(folder / f"{domain_id}.lock", os.O_RDWR | os.O_CREAT, 0o600)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                os.close(fd)
                continue
            if _domain_ports_free(domain_id):
                self.domain_id, self._fd = domain_id, fd
                return
            os.close(fd)
        raise RuntimeError(f"no free DDS domain id in {ids.start}..{ids.stop - 1} on this "
                           "machine")

    def release(self) -> None:
        """Give the id back (closing the file drops the lock); idempotent."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def pick_domain_id(rng: random.Random | None = None) -> int:
    """A domain id in 100..229 claimed for the rest of this process's life (see
    :class:`DomainClaim`; a :class:`LoopbackDomain` gives its id back when it closes)."""
    claim = DomainClaim(rng)
    _HELD_FOR_LIFE.append(claim)
    return claim.domain_id


#: claims of :func:`pick_domain_id`, held until the process exits
_HELD_FOR_LIFE: list[DomainClaim] = []


class ProcessDomain:
    """The processes of one DDS domain: each started with that domain's environment, each
    stopped (SIGTERM, then SIGKILL) when the domain closes, so a failing test never leaves
    processes behind. Subclasses say where a host's processes run and with which DDS
    environment (:class:`LoopbackDomain`, :class:`twinslam.hosts.netns.NetnsHosts`)."""

    def __init__(self, domain_id: int) -> None:
        self.domain_id = domain_id
        self.processes: list[NodeProcess] = []
        #: each process's stderr (its log) so far, by pid, read by a thread as it comes: a
        #: chatty node must never block on a full pipe (64 KB) that nobody reads
        self._logs: dict[int, list[str]] = {}
        self._log_threads: dict[int, threading.Thread] = {}

    def base_env(self) -> dict[str, str]:
        """The current environment with this domain's id and the repository on the path —
        less the process a node of this process's own starter would end with: a node this
        domain starts ends with this process (:meth:`spawn`), a forked one with its server."""
        env = dict(os.environ)
        env.pop(PARENT_ENV, None)
        env.update({
            "ROS_DOMAIN_ID": str(self.domain_id),
            "PYTHONUNBUFFERED": "1",
            "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT),
                                                        os.environ.get("PYTHONPATH")])),
        })
        return env

    def env_for(self, host: str | None) -> dict[str, str]:
        raise NotImplementedError

    def command(self, host: str | None, argv: list[str]) -> list[str]:
        """``argv`` as it must be run to execute on ``host``."""
        return argv

    def network_namespace(self, host: str | None) -> str | None:
        """The network namespace a process on ``host`` runs in, where it is not this
        process's own (None: this machine's network)."""
        return None

    def monitor_scope(self) -> contextlib.AbstractContextManager[None]:
        """Where this process's own participants must be made to watch the domain."""
        return contextlib.nullcontext()

    def spawn(self, args: list[str], host: str | None = None, forks: ForkServers | None = None,
              **kwargs: object) -> NodeProcess:
        """Start ``python args...`` on this domain (on ``host`` where the domain has hosts);
        stdout/stderr are captured as text. With ``forks``, a preloaded module is forked from
        its fork server, the child entering the host's network namespace where the host has
        one (what ``ip netns exec`` would run it in)."""
        argv = [sys.executable, *args]
        env = self.env_for(host)
        proc: NodeProcess | None = None
        netns = self.network_namespace(host)
        if forks is not None and not kwargs and (netns or self.command(host, argv) == argv):
            proc = forks.spawn(args, env, netns)
        if proc is None:
            # a node ends with this process even where it is killed outright (a forked one
            # dies with its fork server, which dies with this process)
            env = {**env, PARENT_ENV: str(os.getpid())}
            proc = subprocess.Popen(  # type: ignore[call-overload]
                self.command(host, argv), env=env, text=True, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, cwd=str(REPO_ROOT), **kwargs)
            assert proc is not None
        self.processes.append(proc)
        lines: list[str] = []
        self._logs[proc.pid] = lines
        thread = threading.Thread(target=_pump_lines, args=(proc.stderr, lines), daemon=True,
                                  name=f"log-{proc.pid}")
        thread.start()
        self._log_threads[proc.pid] = thread
        return proc

    def log(self, proc: NodeProcess) -> str:
        """What ``proc`` has written to stderr so far."""
        return "".join(self._logs.get(proc.pid, []))

    def wait_for_log(self, proc: NodeProcess, text: str, timeout: float) -> bool:
        """Wait (bounded) until ``proc`` logged ``text``; False if it did not, or exited."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.log(proc):
                return True
            if proc.poll() is not None:
                time.sleep(0.2)             # the last lines may still be in the pipe
                return text in self.log(proc)
            time.sleep(0.05)
        return False

    def stop(self, proc: NodeProcess, timeout: float = 5.0) -> tuple[int, str, str]:
        """SIGTERM, wait up to ``timeout`` s, SIGKILL if needed; returns (code, out, err). A
        process still running after ``timeout`` is asked for its stacks first
        (:meth:`ask_for_stacks`): the log then says where it was stuck."""
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.ask_for_stacks(proc)
            proc.kill()
            # SIGKILL always ends it, but only once each of its threads is scheduled to exit:
            # on a host a test run and a CPU hog fill, a thread at the lowest priority (the
            # edge's word learning) may wait seconds for a core
            proc.wait(timeout=KILLED_EXIT_S)
        assert proc.returncode is not None
        thread = self._log_threads.get(proc.pid)
        if thread is not None:
            thread.join(timeout=5)
        out = proc.stdout.read() if proc.stdout is not None and not proc.stdout.closed else ""
        return proc.returncode, out or "", self.log(proc)

    def ask_for_stacks(self, proc: NodeProcess, wait_s: float = 1.0) -> None:
        """Ask a running node for every thread's Python stack (SIGUSR1: the nodes' stacks
        signal, ``twinslam.node_runtime.node_main.STACKS_SIGNAL``) and give it ``wait_s`` to
        reach its log. A process that is no node ends on it (SIGUSR1's default action)."""
        if proc.poll() is None:
            proc.send_signal(signal.SIGUSR1)
            time.sleep(wait_s)

    def log_with_stacks(self, proc: NodeProcess, chars: int = 6000) -> str:
        """The last ``chars`` of a node's log once it printed its threads' stacks
        (:meth:`ask_for_stacks`), and their native stacks where gdb can read them
        (:func:`~twinslam.hosts.native_stacks.native_stacks`): what a test that waited in vain
        for it shows."""
        self.ask_for_stacks(proc)
        native = native_stacks(proc.pid) if proc.poll() is None else None
        log = self.log(proc)[-chars:]
        return log if native is None else f"{log}\n--- native stacks (gdb) ---\n{native}"

    def close(self) -> None:
        for proc in self.processes:
            if proc.poll() is None:
                self.stop(proc)

    def __enter__(self) -> ProcessDomain:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def _pump_lines(stream: Any, lines: list[str]) -> None:
    for line in stream:
        lines.append(line)


class LoopbackDomain(ProcessDomain):
    """Context manager: a domain id on this machine only + the processes started in it."""

    def __init__(self, domain_id: int | None = None) -> None:
        self._claim: DomainClaim | None = None
        if domain_id is None:
            self._claim = DomainClaim()
            domain_id = self._claim.domain_id
        super().__init__(domain_id)
        self._saved_env: dict[str, str | None] = {}

    @property
    def env(self) -> dict[str, str]:
        """Environment for a process on this domain (the current one plus the DDS settings)."""
        env = self.base_env()
        env.pop("ROS_STATIC_PEERS", None)
        env.update(ros_env(self.domain_id))
        return env

    def env_for(self, host: str | None) -> dict[str, str]:
        return self.env                 # every "host" is this machine's loopback

    def activate(self) -> None:
        """Point *this* process's future contexts at the domain (set before ``rclpy.init``)."""
        env = self.env
        for key in ENV_KEYS:
            self._saved_env.setdefault(key, os.environ.get(key))
            if key in env:
                os.environ[key] = env[key]
            else:
                os.environ.pop(key, None)

    def close(self) -> None:
        super().close()
        if self._claim is not None:
            self._claim.release()
        for key, value in self._saved_env.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value

    def __enter__(self) -> LoopbackDomain:
        return self


class JsonLines:
    """Reads a child's stdout JSON lines on a thread, so waiting on them is bounded in time.

    Tests and benchmarks talk to the node processes they spawn through such lines.
    """

    def __init__(self, proc: NodeProcess) -> None:
        self.proc = proc
        self.lines: queue.Queue[dict[str, Any]] = queue.Queue()
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            line = line.strip()
            if line.startswith("{"):
                self.lines.put(json.loads(line))

    def next(self, event: str, timeout: float) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError(f"no {event!r} line within {timeout} s "
                                   f"(process exit code {self.proc.poll()})")
            try:
                item = self.lines.get(timeout=remaining)
            except queue.Empty:
                continue
            if item.get("event") == event:
                return item


class EnvironmentDomain(LoopbackDomain):
    """The domain of the environment ($ROS_DOMAIN_ID, discovery range, static peers) as it is,
    with the project's Fast DDS profile unless $FASTRTPS_DEFAULT_PROFILES_FILE names one: what
    ``twinslam launch`` runs on without ``--loopback`` or ``--hosts``."""

    def __init__(self) -> None:
        super().__init__(domain_id_from_env())

    @property
    def env(self) -> dict[str, str]:
        env = self.base_env()
        env.setdefault("FASTRTPS_DEFAULT_PROFILES_FILE", str(installed_profile()))
        return env
