"""Private ROS domains on one machine: parallel test workers, ``evaluate --jobs`` and the demo
each claim a domain id that nobody else holds while it is open, so their nodes never talk across
runs — a free discovery port alone is no reservation between two processes that look at once."""

from __future__ import annotations

import random
import subprocess
import sys

from twinslam.node_hosts.loopback import DomainClaim, LoopbackDomain

#: every id a claim may hand out
IDS = 130


def test_open_domains_hold_distinct_ids_until_they_close() -> None:
    claims = [DomainClaim() for _ in range(IDS)]
    try:
        assert len({c.domain_id for c in claims}) == IDS
        try:
            DomainClaim()
        except RuntimeError as exc:
            assert "no free DDS domain id" in str(exc)
        else:
            raise AssertionError("a claim was handed out while every id was held")
        freed = claims.pop(7)
        freed.release()
        assert DomainClaim(random.Random(1)).domain_id == freed.domain_id
    finally:
        for c in claims:
            c.release()


def test_an_id_held_by_another_process_is_never_handed_out_and_comes_back_when_it_exits() -> None:
    """The same candidate order in both processes: the child takes the first, this process
    must skip it while the child lives and may have it once the child is gone (killed: the
    kernel drops its lock)."""
    first = DomainClaim(random.Random(3))
    wanted = first.domain_id
    first.release()
    child = subprocess.Popen(
        [sys.executable, "-c",
         "import random, sys, time\n"
         "from twinslam.node_hosts.loopback import DomainClaim\n"
         "c = DomainClaim(random.Random(3)); print(c.domain_id, flush=True); time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None
        assert int(child.stdout.readline()) == wanted
        with LoopbackDomain() as other:
            assert other.domain_id != wanted
        beside = DomainClaim(random.Random(3))
        assert beside.domain_id != wanted
        beside.release()
    finally:
        child.kill()
        child.wait(timeout=10)
    again = DomainClaim(random.Random(3))
    assert again.domain_id == wanted
    again.release()
