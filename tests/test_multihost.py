"""The pipeline across three hosts: device, edge and twin each in its own network
namespace with its own address, the device's uplink a veth shaped by ``tc``, and faults
injected while the 7-Scenes sample plays (the synthetic room without it).

Needs root and iproute2 (``twinslam.hosts.netns``); without them every test here is
skipped with the reason. The namespaces of a test are removed when it ends, failed or not.

These tests run in a process of their own (``tests/test_multihost_process.py`` starts it):
Fast DDS keeps what it learnt of the network interfaces from the first participant of a process,
so a monitor made inside a namespace after a participant in the root namespace announces the
root namespace's addresses, and no node on the hosts can reach it (measured: the edge's monitor
then discovered nothing in 120 s; as the first participant of its process it works at once).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.data_paths import seven_or_synthetic
from tests.paced_runs import PACE_FRAMES, assert_kept_up
from twinslam.hosts.netns import HOSTS, NetnsError, NetnsHosts, address_of, unavailable_reason
from twinslam.live.launcher import NODE_HOSTS, LaunchConfig, Launcher, tc_uplink_params
from twinslam.live.report import RunReport
from twinslam.live.run_log import RunLog

SEQUENCE = seven_or_synthetic()
VMAX = 45
#: the keyframe as it crosses the link with upload_image:=true: a 640×480 rgb8 frame
FRAME_MBIT = 640 * 480 * 3 * 8 / 1e6

_why_not = unavailable_reason()
#: set by tests/test_multihost_process.py in the fresh process that runs this module
FRESH_PROCESS = os.environ.get("TWINSLAM_MULTIHOST_PROCESS") == "1"
pytestmark = [
    pytest.mark.skipif(not FRESH_PROCESS, reason="runs in a process of its own "
                       "(tests/test_multihost_process.py)"),
    pytest.mark.skipif(_why_not is not None, reason=f"multi-host tests: {_why_not}"),
]


#: how long the edge waits for a requested keyframe before closing its slot without it: past
#: any lag of a loaded machine, within the runs' 240 s limit (a keyframe lost for good still
#: fails the slot check, a minute later)
KEYFRAME_WAIT_S = 60.0


def _remove_stale_namespaces() -> None:
    """Namespaces of an earlier test process that was killed before it could clean up."""
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    for line in listed.splitlines():
        match = re.match(r"(t[sc](\d+)-\w+)", line)
        if match and not Path(f"/proc/{match.group(2)}").exists():
            subprocess.run(["ip", "netns", "delete", match.group(1)], capture_output=True)


@pytest.fixture
def hosts() -> Iterator[NetnsHosts]:
    _remove_stale_namespaces()
    with NetnsHosts(prefix=f"ts{os.getpid()}-") as made:
        yield made
    assert not made.exists(), "namespaces left behind"


def _tc_uplink(**device: str) -> dict[str, list[str]]:
    """Node parameters of a run whose device uploads real frames through tc (``device``: more
    device parameters)."""
    return tc_uplink_params(FRAME_MBIT, **device)


def _run(hosts: NetnsHosts, frames: int, extra: dict[str, list[str]],
         on_stats: Callable[[Any, RunLog, Launcher], None] | None = None,
         **config: Any) -> tuple[RunReport, RunLog, Launcher]:
    config.setdefault("policy", "adapt")
    config.setdefault("pace_frames", PACE_FRAMES)
    # the Edge-SLAM style device unless a test names the map source: the faults tested here
    # need a device that tracks on where the paper's device is lost with the map's lag
    device = extra.get("device_tracker", [])
    if not any(a.startswith("map_source:=") for a in device):
        extra = {**extra, "device_tracker": [*device, "map_source:=edge+local"]}
    # the slots are checked in full (_assert_slots_consistent): the edge waits for every
    # keyframe the device sent. Its default 10 s wait for a keyframe is what a healthy uplink
    # needs; a loaded slower machine's device fell 10-14 s behind after the outage once, and
    # the edge closed six slots without keyframes already on their way
    edge = extra.get("edge_mapper", [])
    if not any(a.startswith("slot_timeout_s:=") for a in edge):
        extra = {**extra, "edge_mapper": [*edge, f"slot_timeout_s:={KEYFRAME_WAIT_S:.1f}"]}
    launcher = Launcher(hosts, LaunchConfig(SEQUENCE, frames=frames, timeout_s=240.0,
                                            extra=extra, **config), echo=print)
    try:
        report = launcher.run(lambda msg, record: on_stats(msg, record, launcher)
                              if on_stats else None)
    finally:                          # the nodes' logs, shown by pytest when a test fails
        for name, log in launcher.logs.items():
            print(f"--- {name} (last lines) ---\n" + "\n".join(log.splitlines()[-25:]))
    assert launcher.record is not None and launcher.record.stats, \
        "the edge published no MapStats"
    assert_kept_up(launcher.logs["device_tracker"])
    return report, launcher.record, launcher


def _namespace_of(pid: int) -> str:
    return subprocess.run(["ip", "netns", "identify", str(pid)], capture_output=True,
                          text=True).stdout.strip()


def _assert_slots_consistent(record: RunLog, slots: int) -> None:
    """Every slot answered once, in full: what the edge asked for is what the device sent and
    what the edge integrated or its keyframe gate refused (counted in MapStats), and the map
    stays within V_max."""
    assert sorted(record.stats) == list(range(slots)), sorted(record.stats)
    versions = [record.maps[s].version for s in sorted(record.maps)]
    assert versions == sorted(versions)
    for slot in range(slots):
        asked = len(record.requests[slot].upload_frame_ids)
        sent = record.throughput[slot]
        assert sent.frames_sent == asked, f"slot {slot}: {sent.frames_sent} sent of {asked}"
        stats = record.stats[slot]
        assert stats.uploads + stats.refused_keyframes + stats.missing_keyframes == asked
        assert stats.uploads + stats.refused_keyframes == asked, f"slot {slot}: integrated " \
            f"{stats.uploads}, refused {stats.refused_keyframes}, not in when the slot closed " \
            f"{stats.missing_keyframes} of {asked}"
        assert record.stats[slot].map_size <= VMAX


def test_hosts_have_their_own_address_and_nothing_else(hosts: NetnsHosts) -> None:
    for host in HOSTS:
        links = hosts.run_in(host, "ip", "-o", "link", "show")
        names = sorted(line.split(":")[1].strip().split("@")[0] for line in links.splitlines())
        assert names == ["eth0", "lo"]
        addrs = hosts.run_in(host, "ip", "-o", "-4", "addr", "show", "dev", "eth0")
        assert f"inet {address_of(host)}/24" in addrs
        assert "default" not in hosts.run_in(host, "ip", "route", "show")
    assert _udp_reaches(hosts, "device", "edge")
    hosts.set_link("device", False)              # the cable pulled at the switch
    assert not _udp_reaches(hosts, "device", "edge")
    hosts.set_link("device", True)
    assert _udp_reaches(hosts, "device", "twin")


def _udp_reaches(hosts: NetnsHosts, src: str, dst: str) -> bool:
    """Whether a UDP datagram from ``src`` arrives at ``dst``'s address (2 s at most)."""
    listen = ("import socket; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); "
              f"s.bind(('{address_of(dst)}', 7777)); s.settimeout(2.0); print(s.recv(16))")
    send = ("import socket, time; s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n"
            "for _ in range(8):\n"
            f"    s.sendto(b'probe', ('{address_of(dst)}', 7777)); time.sleep(0.1)")
    receiver = subprocess.Popen(hosts.command(dst, [sys.executable, "-c", listen]),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(0.3)
    hosts.run_in(src, sys.executable, "-c", send, check=False)
    out, _ = receiver.communicate(timeout=10)
    return "probe" in out


def test_device_uplink_through_tc_follows_the_configured_rate(hosts: NetnsHosts) -> None:
    where: dict[str, str] = {}

    def note_hosts(msg: Any, record: RunLog, launcher: Launcher) -> None:
        if not where:
            where.update({n: _namespace_of(p.pid) for n, p in launcher.procs.items()})

    before = hosts.port_bytes("device")
    # six slots of 30 frames played at half speed: slots of 2 s as at full speed, each with
    # Theorem 1's uploads, on half the frames
    report, record, _ = _run(hosts, 180, _tc_uplink(slot_frames="30"), note_hosts, rate=0.5)
    crossed = hosts.port_bytes("device") - before
    assert where == {n: hosts.namespaces[NODE_HOSTS[n]] for n in where} and len(where) == 3
    _assert_slots_consistent(record, 6)
    measured: dict[float, list[float]] = {}
    for slot, t in sorted(record.throughput.items()):
        if t.frames_sent:
            ratio = t.achieved_mbps / t.configured_rate_mbps
            print(f"slot {slot}: {t.frames_sent} frames, {t.bytes_sent / 1e6:.2f} MB at "
                  f"{t.configured_rate_mbps:.0f} Mbit/s configured: {t.achieved_mbps:.1f} "
                  f"measured ({ratio:.0%})")
            measured.setdefault(round(t.configured_rate_mbps), []).append(ratio)
            assert 0.85 <= ratio <= 1.15, f"slot {slot}"
    assert set(measured) == {40, 80}, "both rates should occur in six slots of seed 0"
    # the bytes really crossed the device's cable
    assert crossed >= sum(t.bytes_sent for t in record.throughput.values())
    assert report.frames_uploaded * FRAME_MBIT * 1e6 / 8 <= crossed


#: the longest a test's cable stays down waiting for the device to say it noticed
NOTICE_WAIT_S = 60.0


def test_link_down_for_5_s_device_tracks_on_and_uploads_resume(hosts: NetnsHosts) -> None:
    """The device's cable is pulled at slot 1 for at least 5 s, and plugged back once the
    device said it tracks on its local map (a device lagging its camera on a loaded machine
    notices the silence later); the playback goes on until uploads resumed for three slots."""
    outage: dict[str, float] = {}
    resumed: list[int] = []

    def pull_cable(msg: Any, record: RunLog, launcher: Launcher) -> None:
        slot = int(msg.slot)
        if slot == 1 and "down" not in outage:
            outage["down"] = time.monotonic()
            outage["slot"] = slot
            hosts.set_link("device", False)

            def plug() -> None:
                time.sleep(5.0)
                hosts.wait_for_log(launcher.procs["device_tracker"],
                                   "tracking on the local map", NOTICE_WAIT_S)
                hosts.set_link("device", True)
                outage["up"] = time.monotonic()

            threading.Thread(target=plug, daemon=True).start()
        elif "up" in outage:
            # the device's throughput reports cross its cable and may come after the edge's
            # MapStats of the same slot: every report heard so far counts
            resumed[:] = sorted(k for k, t in record.throughput.items()
                                if k > outage["slot"] + 1 and t.frames_sent)
            if len(resumed) >= 3:
                launcher.end_playback()

    # after the cable is back the edge answers the slots it missed one by one, on a loaded
    # machine seconds late: the device keeps 6 slots' frames uploadable (12 s; the default 4
    # rides out the outage itself, but a request came after its frames had gone under load).
    # Slots of 2 s: 30 frames each, played at half speed, until uploads resumed (at most 30
    # slots). The device calls the edge silent after 1.5 s without an answer (3 s by default).
    # The Edge-SLAM style device: it tracks on its own points while no map comes (the
    # paper's device, tracked only against the edge's map, is lost where the map ends)
    device = _tc_uplink(keep_slots="6", slot_frames="30", edge_timeout_s="1.5",
                        map_source="edge+local")
    report, record, launcher = _run(hosts, 900, device, pull_cable, rate=0.5)
    assert outage["up"] - outage["down"] >= 5.0
    device_log = launcher.logs["device_tracker"]
    assert "tracking on the local map" in device_log
    assert "the edge answers again" in device_log and "uploads resume" in device_log
    expected = launcher.expected_slots()
    assert expected is not None
    _assert_slots_consistent(record, expected)
    # the device tracked through the outage (its summaries arrived once the link was back)
    for slot in (2, 3, 4):
        frames = record.summaries[slot].frames
        assert sum(f.tracked for f in frames) >= 0.9 * len(frames), f"slot {slot}"
    assert len(resumed) >= 3, f"uploads did not resume: slots with uploads after {resumed}"
    assert report.ate_m < 0.15


def test_edge_host_node_killed_and_restarted_restores_its_map(hosts: NetnsHosts,
                                                              tmp_path: Path) -> None:
    state: dict[str, Any] = {}

    def kill_edge(msg: Any, record: RunLog, launcher: Launcher) -> None:
        slot = int(msg.slot)
        # the newest map the monitor holds (a slot's MapUpdate may arrive after its MapStats)
        acked = max(record.maps, default=-1)
        if "killed" not in state and slot >= 2 and acked >= 2:
            state["killed"] = (acked, set(record.maps[acked].keyframe_ids.tolist()))
            launcher.kill("edge_mapper")
            state["restarted"] = launcher.start("edge_mapper")
        elif "killed" in state and "after" not in state:
            state["after"] = slot                        # answered: in its host by now
            state["restarted_in"] = _namespace_of(state["restarted"].pid)
            launcher.end_playback()

    # slots of 4 s (30 frames at a quarter speed) until the restarted edge answered one: it
    # warms up for 5-15 s on 2 cores, more on a loaded machine, and summaries the device sends
    # while no edge listens are not kept for it (volatile); at most 20 slots (what is tested is
    # the restore, not real-time tracking). The Edge-SLAM style device tracks on its own points
    # while the edge is down, so the ATE below measures the restore, not the outage
    frames, slot_frames = 600, 30
    report, record, launcher = _run(hosts, frames,
                                    _tc_uplink(slot_frames=str(slot_frames),
                                               map_source="edge+local"),
                                    kill_edge, checkpoint=tmp_path / "edge.npz", rate=0.25)
    killed_slot, kept = state["killed"]
    after = record.maps[state["after"]]
    # kept unless a decision after that map evicted it
    evicted = {int(f) for k in range(killed_slot + 1, state["after"] + 1) if k in record.requests
               for f in record.requests[k].evict_frame_ids}
    assert state["after"] > killed_slot
    assert kept - evicted <= set(after.keyframe_ids.tolist()), "acknowledged keyframes lost"
    assert "restored map version" in launcher.logs["edge_mapper"]
    assert state["restarted_in"] == hosts.namespaces["edge"]
    # the run completes: the paced device tracked every frame while the edge restarted, so its
    # frame-count slot clock closed the last slot too
    expected = launcher.expected_slots()
    assert expected is not None and max(record.stats) >= expected - 1, "the run did not complete"
    assert report.ate_m < 0.15


@pytest.fixture(scope="module")
def twin_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A twin-driven AMM policy, trained for a few slots (its quality is not the point)."""
    from twinslam.covisibility.dataset import load_covisibility
    from twinslam.training.trainer import AmmTrainer, TrainConfig

    covis = Path(__file__).resolve().parents[1] / "data" / "7scenes-redkitchen-1000.covis.npz"
    trainer = AmmTrainer(TrainConfig(slots=20, episode_slots=10, warmup_slots=10,
                                     batch_size=4, rate_model="variational", artificial_per_real=1,
                                     replay_capacity=50, log_every=10, validate_every=20,
                                     validation_seeds=1, validation_slots=4),
                         load_covisibility(covis))
    trainer.train()
    path = tmp_path_factory.mktemp("amm") / "amm-variational.pt"
    trainer.save(path)
    return path


def test_twin_absent_edge_falls_back_and_returns_when_latents_flow(
        hosts: NetnsHosts, twin_policy: Path) -> None:
    """No twin at first: the fallback decides. The twin host's node starts after slot 1: the
    learned policy takes over once its latents arrive. The twin dies once the learned policy
    decided two slots: fallback again once the last latent is more than latent_max_age slots
    old. The playback goes on until that fallback decided two slots, however long the twin's
    start took."""
    learned = f"mbrl:{twin_policy}"
    twin: dict[str, Any] = {}

    def start_then_kill_twin(msg: Any, record: RunLog, launcher: Launcher) -> None:
        slot = int(msg.slot)
        decided = [record.requests[s].policy for s in sorted(record.requests) if s <= slot]
        if slot == 1 and "proc" not in twin:
            twin["proc"] = launcher.start("udt_node")
        elif "proc" in twin and "in" not in twin:            # its `ip netns exec` is done
            twin["in"] = _namespace_of(twin["proc"].pid)
        if decided.count(learned) >= 2 and "killed" not in twin:
            twin["killed"] = slot
            launcher.kill("udt_node")
        # the last latent is 2 slots old two slots after the kill: two slots decided after
        # that show the fallback (or that it never came)
        if "killed" in twin and len(decided) >= twin["killed"] + 4:
            launcher.end_playback()

    slot_frames = 15
    extra = _tc_uplink(slot_frames=str(slot_frames))
    extra["edge_mapper"] += ["fallback_policy:=adapt", "latent_max_age:=1"]
    extra["udt_node"] = [f"policy_checkpoint:={twin_policy}"]
    # slots of 5.7 s (15 frames played at 0.0875x): the device keeps up while the twin starts
    # beside it (what is tested is who decides, not real-time tracking). The twin's start
    # (torch, the policy's checkpoint) takes 5-15 s on 2 cores and ~50 s beside a loaded suite
    # on a slower machine: the run plays until the fallback showed, at most 30 slots
    _, record, launcher = _run(hosts, 30 * slot_frames, extra, start_then_kill_twin,
                               policy=learned, rate=0.0875)
    deciders = [record.requests[s].policy for s in sorted(record.requests)]
    print(f"\ndecided by: {deciders}")
    assert deciders[0] == deciders[1] == "adapt (fallback)"
    assert "killed" in twin, "the learned policy never took over"
    after = deciders[twin["killed"] + 2:]            # the last latent is 2 slots old by then
    assert after and all(d == "adapt (fallback)" for d in after), "no fallback without twin"
    edge_log = launcher.logs["edge_mapper"]
    assert edge_log.count("deciding with the fallback policy adapt") == 2
    assert "rate latents from the twin again" in edge_log
    assert twin["in"] == hosts.namespaces["twin"]
    # every slot answered, and consistent: the paced device tracked every frame under the load
    # of the twin's start, so its frame-count slot clock closed the run's last slot too
    expected = launcher.expected_slots()
    assert expected is not None
    _assert_slots_consistent(record, expected)


def test_5_percent_loss_reliable_topics_deliver_best_effort_images_degrade(
        hosts: NetnsHosts) -> None:
    """The link loses 5 % of the device's packets from slot 1 on; a viewer on the edge host
    watches the camera best effort. A 0.9 MB image is ~700 packets: nearly none survives."""
    try:                                  # 0 %: can this machine lose packets at all?
        how = hosts.lose_packets("device", 0.0)
    except NetnsError as exc:
        pytest.skip(f"no way to lose packets here: {exc}")
    seen: dict[str, int] = {}

    def start_losing(msg: Any, record: RunLog, launcher: Launcher) -> None:
        if not seen:
            seen["before"] = record.images_received
            hosts.lose_packets("device", 5.0)

    # five slots of 2 s: 30 frames each, played at half speed
    frames, slot_frames = 150, 30
    report, record, _ = _run(hosts, frames, {"device_tracker": [f"slot_frames:={slot_frames}"]},
                             start_losing, watch_images=True, rate=0.5)
    after = record.images_received - seen["before"]
    print(f"\nbest-effort images seen by the viewer: {seen['before']} before the loss, "
          f"{after} after (of ~{frames - seen['before']} played)")
    assert seen["before"] >= 20, "the viewer saw no images even without loss"
    assert after < 0.5 * (frames - seen["before"])
    _assert_slots_consistent(record, 5)          # every reliable sample of every slot came
    assert all(len(s.frames) == slot_frames for s in record.summaries.values())
    qdiscs = hosts.run_in("device", "tc", "qdisc", "show", "dev", "eth0")
    assert ("netem" if how == "netem" else "clsact") in qdiscs
    assert report.ate_m < 0.15


def test_hosts_command_builds_and_removes_the_three_hosts() -> None:
    prefix = f"tc{os.getpid()}-"
    cli = [sys.executable, "-m", "twinslam.cli.main", "hosts"]
    try:
        up = subprocess.run([*cli, "up", "--prefix", prefix], capture_output=True, text=True,
                            timeout=60)
        assert up.returncode == 0, up.stderr
        assert f"edge    netns {prefix}edge" in up.stdout
        again = subprocess.run([*cli, "up", "--prefix", prefix], capture_output=True,
                               text=True, timeout=60)
        assert again.returncode == 1 and "exist already" in again.stderr
        with pytest.raises(NetnsError, match="exist already"):   # never reused or removed
            NetnsHosts(prefix=prefix).up()
        assert len(NetnsHosts(prefix=prefix).exists()) == 4
    finally:
        down = subprocess.run([*cli, "down", "--prefix", prefix], capture_output=True,
                              text=True, timeout=60)
    assert down.returncode == 0 and "removed" in down.stdout
    assert not NetnsHosts(prefix=prefix).exists()


def test_two_devices_on_hosts_of_their_own_share_one_edge_each_uplink_its_own_cable() -> None:
    """The many-devices test bed: two device hosts (each a camera and a device tracker) and one
    edge host; each device's keyframes cross its own cable, shaped by tc at its own d_k, and
    the one edge answers both within one keyframe budget."""
    from twinslam.live.fleet import FleetConfig, FleetLauncher, device_sequence

    _remove_stale_namespaces()
    fleet = FleetConfig(2, 30, "equal", 5)
    names = fleet.names()
    with NetnsHosts(prefix=f"tc{os.getpid()}-", hosts=(*names, "edge")) as made:
        starts = [device_sequence("synthetic:150", i, 2, 150, 0, 0, None) for i in range(2)]
        # the cameras wait for their devices, together (the players' pace_group)
        launcher = FleetLauncher(made, LaunchConfig("synthetic:150", "lff", 150,
                                                    timeout_s=240.0, extra=_tc_uplink(),
                                                    pace_frames=PACE_FRAMES),
                                 fleet, starts, echo=print)
        result = launcher.run_fleet()
        carried = {d: made.port_bytes(d) for d in names}    # what crossed each cable
    assert not made.exists(), "namespaces left behind"
    for d, report in zip(result.devices, result.reports, strict=True):
        record = launcher.records[d].record
        sent = sum(int(t.bytes_sent) for t in record.throughput.values())
        # the paper's device fails a frame its edge's map does not cover yet: on a loaded
        # machine a map can come a frame late (measured: 1 of 60 frames on a clean clone's
        # suite); what this test bed must show is two devices tracked through their cables
        assert report.slots >= 2 and report.failed_share <= 0.05, (d, report.row())
        assert report.frames_dropped == 0, (d, report.row())
        assert sent > 0 and carried[d] >= sent, f"{d}: {carried[d]} bytes on its cable, {sent} sent"
        for t in record.throughput.values():
            if t.frames_sent:      # tc paced the keyframes at d_k (not faster)
                assert t.duration_s >= 0.9 * t.bytes_sent * 8 / (t.configured_rate_mbps * 1e6)
        assert all(s.map_size <= s.keyframe_budget for s in record.stats.values()), d
