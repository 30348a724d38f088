"""Private ROS domains on one machine: parallel test workers, ``evaluate --jobs`` and the demo
each claim a domain id that nobody else holds while it is open, so their nodes never talk across
runs — a free discovery port alone is no reservation between two processes that look at once."""

from __future__ import annotations

import fcntl
import os
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from twinslam.hosts.loopback import (
    DomainClaim,
    LoopbackDomain,
    ProcessDomain,
    _claims_dir,
    _domain_ports_free,
)
from twinslam.hosts.native_stacks import FRAME_CHARS, compact_stacks, native_stacks
from twinslam.parent_watch import PARENT_ENV

#: the ids these tests claim among themselves, in claims of their own (tmp_path): 230..232,
#: beyond the machine's 100..229 that the suite's other tests claim on parallel workers
IDS = range(230, 233)


def _no_port_held(domain_id: int) -> bool:
    """The port check of claims that test the locks alone: any process on the machine may hold
    a port of an id's range for a moment (an ephemeral UDP port, where the machine's ephemeral
    range reaches that high), and such a claim would then skip an id that no lock holds — a
    red test that says nothing about the locks."""
    return True


def test_open_domains_hold_distinct_ids_until_they_close(tmp_path: Path) -> None:
    claims = [DomainClaim(ids=IDS, folder=tmp_path, ports_free=_no_port_held) for _ in IDS]
    try:
        assert sorted(c.domain_id for c in claims) == list(IDS)
        with pytest.raises(RuntimeError, match=r"no free DDS domain id in 230\.\.232"):
            DomainClaim(ids=IDS, folder=tmp_path, ports_free=_no_port_held)
        freed = claims.pop(1)
        freed.release()
        again = DomainClaim(random.Random(1), ids=IDS, folder=tmp_path, ports_free=_no_port_held)
        assert again.domain_id == freed.domain_id
        claims.append(again)
    finally:
        for c in claims:
            c.release()


#: a held domain and the user-data port of its participant 7 (RTPS: 7400 + 250 d + 11 + 2 i)
HELD = 231
PARTICIPANT_7_PORT = 7400 + 250 * HELD + 11 + 2 * 7


def test_an_id_a_participant_of_any_index_still_uses_is_not_handed_out(tmp_path: Path) -> None:
    """A participant that outlives its run's claim — an outside peer of a finished test, which
    the nodes had pushed to a later participant index — holds ports of its domain other than
    the first participant's: the claim skips the id all the same, so no later run hears what
    that participant still sends."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", PARTICIPANT_7_PORT))
        assert not _domain_ports_free(HELD)
        with pytest.raises(RuntimeError, match=r"no free DDS domain id in 231\.\.231"):
            DomainClaim(ids=range(HELD, HELD + 1), folder=tmp_path)


#: the claims of the test above, in a network namespace of their own, where no process but
#: the test's holds a port: held, the id is refused and another given; gone, the id is free
_CLAIMS_IN_A_QUIET_NETWORK = f"""
import socket, sys
from pathlib import Path
from twinslam.hosts.loopback import DomainClaim
folder = Path(sys.argv[1])
with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
    sock.bind(("127.0.0.1", {PARTICIPANT_7_PORT}))
    try:
        DomainClaim(ids=range({HELD}, {HELD + 1}), folder=folder)
        sys.exit("claimed {HELD} while participant 7's port was held")
    except RuntimeError:
        pass
    other = DomainClaim(ids=range({IDS.start}, {IDS.stop}), folder=folder)
    assert other.domain_id != {HELD}, other.domain_id
    other.release()
DomainClaim(ids=range({HELD}, {HELD + 1}), folder=folder).release()
print("given once gone")
"""


def test_an_id_whose_participant_is_gone_is_handed_out_again(tmp_path: Path) -> None:
    """The port check refuses an id only while something holds its ports: once the outliving
    participant is gone the id is claimed again. Run in a network namespace of its own
    (``unshare --net``), since on the test's machine any process may hold a port of the id's
    range for a moment: in a clean clone's suite (CI, 2026-12-07) something held one of 231's
    ports just after the test had let its own go, and the claim of 231 was refused."""
    if shutil.which("unshare") is None:
        pytest.skip("util-linux's unshare is not installed")
    private = ["unshare", "--net"] if os.geteuid() == 0 else ["unshare", "--net",
                                                              "--map-root-user"]
    probe = subprocess.run([*private, "true"], capture_output=True, text=True, timeout=30)
    if probe.returncode != 0:
        pytest.skip(f"no network namespace of its own here: {probe.stderr.strip()}")
    run = subprocess.run([*private, sys.executable, "-c", _CLAIMS_IN_A_QUIET_NETWORK,
                          str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "given once gone"


def test_an_id_held_by_another_process_is_never_handed_out_and_comes_back_when_it_exits(
        tmp_path: Path) -> None:
    """The same candidate order in both processes: the child takes the first, this process
    must skip it while the child lives and may have it once the child is gone (killed: the
    kernel drops its lock)."""
    first = DomainClaim(random.Random(3), ids=IDS, folder=tmp_path, ports_free=_no_port_held)
    wanted = first.domain_id
    first.release()
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import random, sys, time\n"
         "from pathlib import Path\n"
         "from twinslam.hosts.loopback import DomainClaim\n"
         f"c = DomainClaim(random.Random(3), ids=range({IDS.start}, {IDS.stop}), "
         f"folder=Path({str(tmp_path)!r}), ports_free=lambda d: True)\n"
         "print(c.domain_id, flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        assert int(child.stdout.readline()) == wanted
        beside = DomainClaim(random.Random(3), ids=IDS, folder=tmp_path,
                             ports_free=_no_port_held)
        assert beside.domain_id != wanted
        beside.release()
    finally:
        child.kill()
        child.wait(timeout=10)
    again = DomainClaim(random.Random(3), ids=IDS, folder=tmp_path, ports_free=_no_port_held)
    assert again.domain_id == wanted
    again.release()


def test_a_loopback_domain_holds_its_id_while_open_and_gives_it_back_when_it_closes() -> None:
    def lockable(domain_id: int) -> bool:
        fd = os.open(_claims_dir() / f"{domain_id}.lock", os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return False
        finally:
            os.close(fd)
        return True

    with LoopbackDomain() as domain:
        held = domain.domain_id
        assert domain.env["ROS_DOMAIN_ID"] == str(held)
        assert not lockable(held)
    assert lockable(held)


@pytest.mark.skipif(shutil.which("gdb") is None, reason="no gdb on this host")
def test_a_stuck_process_shows_where_it_waits_in_native_code() -> None:
    """A process blocked inside C (here ``time.sleep``: the interpreter's own C call) is shown
    down to the system call it waits in — what a node stuck in a C extension's teardown
    gives a test that waited in vain for it to end."""
    stuck = subprocess.Popen([sys.executable, "-c", "import time; print('in', flush=True); "
                              "time.sleep(120)"], stdout=subprocess.PIPE, text=True)
    try:
        assert stuck.stdout is not None and stuck.stdout.readline() == "in\n"
        stacks = native_stacks(stuck.pid)
    finally:
        stuck.kill()
        stuck.wait()
    if stacks is None:
        pytest.skip("gdb may not attach to a process here (ptrace)")
    assert stacks.startswith("Thread ") and "#0 " in stacks
    assert re.search(r"nanosleep|clock_nanosleep|select", stacks), stacks
    assert native_stacks(stuck.pid) is None              # gone: nothing to attach to


#: gdb's ``thread apply all bt`` of a node stuck in its teardown, in gdb's order (the main
#: thread last), shortened from the one a CI run printed
GDB_OUTPUT = "\n".join([
    "[Thread debugging using libthread_db enabled]",
    'Thread 3 (Thread 0x7f9219ffb6c0 (LWP 25957) "dds.udp.7009"):',
    "#0  0x00007f9248128a3a in __libc_recvfrom (fd=22, len=65500) at recvfrom.c:27",
    "#1  0x00007f92282eb7f7 in eprosima::fastdds::rtps::UDPChannelResource::Receive("
    "unsigned char*, unsigned int, unsigned int&, eprosima::fastrtps::rtps::Locator_t&) () "
    "from libfastrtps.so.2.14",
    "#2  0x00007f92480a71f5 in start_thread (arg=<optimized out>) at pthread_create.c:442",
    "#3  0x00007f92481278ec in clone3 () at ../sysdeps/unix/sysv/linux/x86_64/clone3.S:81",
    'Thread 1 (Thread 0x7f9248815600 (LWP 25900) "python"):',
    "#0  0x00007f92480a3f16 in __futex_abstimed_wait_common () from libc.so.6",
    "#1  0x00007f92282aa001 in eprosima::fastrtps::rtps::ResourceEvent::unregister_timer("
    "eprosima::fastrtps::rtps::TimedEventImpl*) () from libfastrtps.so.2.14",
    "#2  0x00007f9248358ba3 in _PyObject_VectorcallTstate (kwnames=0x0) at pycore_call.h:92",
    "#3  0x00007f92482fd9c3 in _PyEval_EvalFrameDefault (tstate=<optimized out>) at ceval.c:4769",
    "#4  0x00007f92484b91cc in pymain_run_module (modname=<optimized out>) at main.c:300",
    "#5  0x00005561a58a9081 in _start ()"])


def test_a_hangs_native_stacks_show_the_main_thread_first_and_short() -> None:
    # a CI log keeps a failure's start and end: gdb lists the main thread last, and the
    # frames that said where it waited fell in the part cut out
    report = compact_stacks(GDB_OUTPUT)
    assert report is not None
    lines = report.splitlines()
    assert lines[0].startswith("Thread 1 ")
    assert lines[1] == "#0 __futex_abstimed_wait_common () from libc.so.6"
    assert lines[2].startswith("#1 eprosima::fastrtps::rtps::ResourceEvent::unregister_timer")
    assert lines[3] == "   (4 frames of the interpreter or a thread's start left out)"
    assert lines[4].startswith("Thread 3 ")
    assert all(len(line) <= FRAME_CHARS for line in lines)
    assert "_PyEval" not in report and "clone3" not in report and "libthread_db" not in report
    assert compact_stacks("warning: ptrace: Operation not permitted") is None


def _running(pid: int) -> bool:
    """Whether process ``pid`` still runs (a zombie waiting for its new parent counts as
    ended)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False
    return state != "Z"


def test_a_node_ends_with_the_process_that_started_it_even_killed_outright() -> None:
    """A test runner killed with SIGKILL closes no domain: its nodes must not run on in a
    domain id the next run may claim. The node a killed starter left stops by itself."""
    script = ("import time\n"
              "from twinslam.hosts.loopback import LoopbackDomain\n"
              "with LoopbackDomain() as domain:\n"
              "    proc = domain.spawn(['-m', 'udt_node.node'])\n"
              "    print(proc.pid, flush=True)\n"
              "    up = domain.wait_for_log(proc, 'listening on', 120.0)\n"
              "    print('up' if up else domain.log(proc)[-2000:].replace(chr(10), ' '),\n"
              "          flush=True)\n"
              "    time.sleep(300)\n")
    starter = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE,
                               text=True)
    assert starter.stdout is not None
    try:
        node = int(starter.stdout.readline())
        up = starter.stdout.readline().strip()
        assert up == "up", up
        assert _running(node)
    finally:
        starter.kill()
        starter.wait(timeout=10)
    deadline = time.monotonic() + 30.0
    while _running(node) and time.monotonic() < deadline:
        time.sleep(0.1)
    still = _running(node)
    if still:
        os.kill(node, signal.SIGKILL)
    assert not still, "the node ran on after the process that started it was killed"


def test_a_domain_does_not_pass_on_the_process_its_own_starter_watches(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A process that a domain started (its nodes' starter named in the environment) starts
    nodes of its own: they end with it, not with its starter — and a node forked from a fork
    server, whose parent is that server, must not take the starter's pid for its parent."""
    monkeypatch.setenv(PARENT_ENV, "12345")
    domain = ProcessDomain(123)
    assert PARENT_ENV not in domain.base_env()


def test_a_node_not_started_by_the_process_it_names_stops_and_passes_the_name_on_to_none(
        ) -> None:
    """In a process of its own (the request stays with that process): named by its parent,
    it goes on (False); named by another pid — a starter that died before the request, its
    child handed to another process — it stops (True); either way the name leaves the
    environment its own children inherit."""
    probe = ("import os, sys\n"
             "from twinslam.parent_watch import PARENT_ENV, stop_with_parent\n"
             "env = {PARENT_ENV: sys.argv[1], 'OTHER': 'kept'}\n"
             "print(stop_with_parent(env), sorted(env))\n")
    answers = []
    for named in (str(os.getpid()), "1"):
        done = subprocess.run([sys.executable, "-c", probe, named], capture_output=True,
                              text=True, timeout=60)
        assert done.returncode == 0, done.stderr
        answers.append(done.stdout.strip())
    assert answers == ["False ['OTHER']", "True ['OTHER']"]
