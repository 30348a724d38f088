"""``twinslam launch --devices N``: one edge and N devices as processes, a table per device,
their mean and Jain's index, and the settings that cannot run refused before anything starts
."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from twinslam_msgs.msg import FrameSummaries, FrameSummary

from twinslam.cli.commands.launch_fleet import fleet_settings, fleet_starts, places_of
from twinslam.cli.main import build_parser, main
from twinslam.hosts.forked import process_name
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.fleet import (
    LATE_SHARE,
    FleetConfig,
    FleetLauncher,
    FleetReport,
    cross_device_errors,
    device_sequence,
    edge_blocks,
    joined_at,
    merge_lines,
    merged_across_places,
    merged_in_place,
    shared_images,
)
from twinslam.live.launcher import (
    DEFAULT_PARAMS,
    PAPER_PARAMS,
    LaunchConfig,
    namespaced_params,
    renamed_params,
)
from twinslam.live.run_log import RunLog
from twinslam.node_runtime.parameters import rclpy_own


def test_every_device_plays_its_own_walk() -> None:
    assert [device_sequence("synthetic:300", i, 3, 300, 0, 0, None) for i in range(3)] == [
        ("synthetic:300:0", 0), ("synthetic:300:1", 0), ("synthetic:300:2", 0)]
    assert [device_sequence("/data/7scenes", i, 4, 200, 0, 0, 1000)[1] for i in range(4)] == [
        0, 250, 500, 750]
    assert [device_sequence("/data/7scenes", i, 3, 200, 900, 100, 1000)[1]
            for i in range(3)] == [900, 0, 100]


def _walk(frames: list[tuple[float, int]], map_frames: dict[int, str], off: np.ndarray
          ) -> RunLog:
    """A device's record: (x along the walk, the map version it was tracked on) a frame, a
    frame a second, each published ``off`` (its map's frame) from its true pose, and the map
    frame each version's update was in."""
    record = RunLog()
    record.summaries[0] = FrameSummaries(frames=[
        FrameSummary(frame_id=i, stamp=Time(sec=i), tracked=True, map_version=v)
        for i, (_, v) in enumerate(frames)])
    for i, (x, _) in enumerate(frames):
        truth = np.eye(4)
        truth[0, 3] = x
        record.ground_truth[i * 10**9], record.poses[i * 10**9] = truth, off @ truth
    for slot, (version, frame) in enumerate(sorted(map_frames.items())):
        record.maps[slot] = SimpleNamespace(version=version, frame_id=frame)  # type: ignore[assignment]
    return record


def test_cross_device_pairs_count_only_frames_tracked_in_one_map_frame() -> None:
    """The second device walks the first one's line in its own frame (1 m away), then, on
    map version 2, in the first one's frame, 2 cm off: only those frames pair with the first
    device's, and they are 2 cm off. A device never merged pairs with nothing."""
    here, apart = np.eye(4), np.eye(4)
    apart[0, 3] = 1.0
    near = np.eye(4)
    near[1, 3] = 0.02
    first = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar1/map"}, here)
    merged = _walk([(0.05 * i, 1) for i in range(5)] + [(0.05 * i, 2) for i in range(5)],
                   {1: "ar2/map", 2: "ar1/map"}, near)
    for i in range(5):                   # before the merge: its own frame, a metre off
        merged.poses[i * 10**9] = apart @ merged.ground_truth[i * 10**9]
    errors = cross_device_errors({"ar1": first, "ar2": merged})
    error = errors[("ar1", "ar2")]
    assert error.pairs == 5 * 5 and abs(error.rms_m - 0.02) < 1e-9
    alone = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar3/map"}, apart)
    assert cross_device_errors({"ar1": first, "ar3": alone})[("ar1", "ar3")].pairs == 0
    assert merged_in_place({"ar1": first, "ar2": merged, "ar3": alone}) == [("ar1", "ar2")]


def test_the_late_cross_device_figure_scores_only_the_last_third_of_each_devices_frames(
        ) -> None:
    """Two settings whose merges come at different times have different frames in one map
    frame; the late figure compares them on the same ones. The second device is 5 cm off the
    first's frame over its first six frames and 1 cm over its last three: the whole figure
    mixes both, the late one is 1 cm over the 3 × 3 pairs of the two devices' last thirds —
    and the fleet's table gives both."""
    line = [(0.05 * i, 1) for i in range(9)]
    first = _walk(line, {1: "ar1/map"}, np.eye(4))
    near, far = np.eye(4), np.eye(4)
    near[1, 3], far[1, 3] = 0.01, 0.05
    second = _walk(line, {1: "ar1/map"}, near)
    for i in range(6):
        second.poses[i * 10**9] = far @ second.ground_truth[i * 10**9]
    records = {"ar1": first, "ar2": second}
    whole = cross_device_errors(records)[("ar1", "ar2")]
    late = cross_device_errors(records, last_share=LATE_SHARE)[("ar1", "ar2")]
    assert whole.pairs > 3 * 3 and whole.rms_m > 0.03
    assert late.pairs == 3 * 3 and abs(late.rms_m - 0.01) < 1e-9
    fleet = FleetReport("equal", list(records), [], [], [], {("ar1", "ar2"): whole}, [],
                        [("ar1", "ar2")], {("ar1", "ar2"): late})
    assert "over the last third of each one's frames RMS 1.0 cm (9 pairs)" in \
        "\n".join(merge_lines(fleet))


def test_the_fleet_says_at_which_slot_each_devices_map_joined_another_frame() -> None:
    """The second device's map updates came in its own frame for two slots, then in the first
    device's: it joined at its slot 2, and the fleet's table says so; the first device
    (the place's own frame throughout) and a device alone joined nothing."""
    first = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar1/map", 2: "ar1/map"}, np.eye(4))
    second = _walk([(0.05 * i, 1) for i in range(5)],
                   {1: "ar2/map", 2: "ar2/map", 3: "ar1/map", 4: "ar1/map"}, np.eye(4))
    alone = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar3/map"}, np.eye(4))
    records = {"ar1": first, "ar2": second, "ar3": alone}
    assert joined_at(records) == {"ar2": (2, "ar1/map")}
    fleet = FleetReport("equal", list(records), [], [], [], cross_device_errors(records), [],
                        merged_in_place(records), joined=joined_at(records))
    assert "ar2's map joined ar1/map at its slot 2" in merge_lines(fleet)
    assert sum("joined" in line for line in merge_lines(fleet)) == 1


def test_merged_devices_that_never_saw_one_view_are_told_from_devices_never_merged() -> None:
    """Two devices walking a corridor towards each other: merged into one frame, but each
    looks the other way, so no frame of one is within 20° of one of the other's and the
    cross-device error has no pair. The fleet's table says so, not that they never shared
    a frame; a device in a frame of its own is still 'never in one map frame'."""
    here = np.eye(4)
    first = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar1/map"}, here)
    towards = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar1/map"}, here)
    turned = np.diag([-1.0, 1.0, -1.0, 1.0])           # 180° about the vertical
    for key in towards.ground_truth:
        towards.ground_truth[key] = towards.ground_truth[key] @ turned
        towards.poses[key] = towards.ground_truth[key]
    alone = _walk([(0.05 * i, 1) for i in range(5)], {1: "ar3/map"}, here)
    records = {"ar1": first, "ar2": towards, "ar3": alone}
    errors = cross_device_errors(records)
    assert errors[("ar1", "ar2")].pairs == 0 and errors[("ar1", "ar3")].pairs == 0
    fleet = FleetReport("equal", list(records), [], [], [], errors, [],
                        merged_in_place(records))
    out = "\n".join(merge_lines(fleet))
    assert "ar1-ar2: no pair: in one map frame, but no frame of one within 0.3 m and 20°" in out
    assert "ar1-ar3: never in one map frame" in out


def test_two_devices_in_one_frame_then_in_another_pair_only_within_each() -> None:
    """Two devices that shared a place's frame (ar2/map), then both moved into a third
    device's (ar1/map, a metre away): each frame of one pairs only with the other's in the
    same map frame — 1 cm off in both — never across the two frames (a metre off)."""
    here, moved, near = np.eye(4), np.eye(4), np.eye(4)
    moved[0, 3] = 1.0
    near[1, 3] = 0.01
    line = [(0.05 * i, 1) for i in range(5)] + [(0.05 * i, 2) for i in range(5)]
    frames = {1: "ar2/map", 2: "ar1/map"}
    second, third = _walk(line, frames, here), _walk(line, frames, near)
    for record in (second, third):        # after the move: a metre along, in ar1's frame
        for i in range(5, 10):
            record.poses[i * 10**9] = moved @ record.poses[i * 10**9]
    error = cross_device_errors({"ar2": second, "ar3": third})[("ar2", "ar3")]
    assert error.pairs == 2 * 5 * 5 and abs(error.rms_m - 0.01) < 1e-9


def test_devices_of_two_places_are_no_pair_and_a_false_merge_is_named() -> None:
    """Devices walking two places have their true poses in two worlds: never a pair of the
    cross-device error; tracked on maps in one frame they are named as a false merge."""
    line = [(0.05 * i, 1) for i in range(5)]
    here = np.eye(4)
    room, room2 = _walk(line, {1: "ar1/map"}, here), _walk(line, {1: "ar1/map"}, here)
    corridor = _walk(line, {1: "ar3/map"}, here)
    records = {"ar1": room, "ar2": room2, "ar3": corridor}
    places = {"ar1": 0, "ar2": 0, "ar3": 1}
    assert set(cross_device_errors(records, places)) == {("ar1", "ar2")}
    assert merged_across_places(records, places) == []
    misplaced = _walk(line, {1: "ar1/map"}, here)       # merged into the room's map
    assert merged_across_places({**records, "ar3": misplaced}, places) == [
        ("ar1", "ar3"), ("ar2", "ar3")]


def test_one_walk_gives_every_device_of_a_synthetic_place_the_same_walk() -> None:
    """``--one-walk``: two devices from a corridor's two ends walk one route (its seed from
    ``--seed``), each from where its order starts it, while their uplinks keep seeds of their
    own; without it each device walks its own."""
    base = ["launch", "--devices", "2", "--sequence", "synthetic-corridor:120", "--frames", "120",
            "--seed", "3", "--orders", "forward,backward"]
    alone, together = (fleet_settings(build_parser().parse_args(base + extra))[0]
                       for extra in ([], ["--one-walk"]))
    args = SimpleNamespace(sequence="synthetic-corridor:120", frames=120, start=0)
    assert fleet_starts(args, alone) == [                      # type: ignore[arg-type]
        ("synthetic-corridor:120:300", 0), ("synthetic-corridor:120:301", 0)]
    assert fleet_starts(args, together) == [                   # type: ignore[arg-type]
        ("synthetic-corridor:120:300", 0), ("synthetic-corridor:120:300", 0)]
    assert [together.device_seed(i) for i in range(2)] == [300, 301]     # the uplinks
    assert together.orders == ("forward", "backward")


def test_focals_give_each_device_of_a_synthetic_place_a_camera_of_its_own() -> None:
    """``--focals 525,450``: device k's walk is seen by the k-th focal length (mod their
    count), a focal the sequence named replaced; a dataset's place refuses them (its camera
    recorded it), as does a focal length that is no number."""
    base = ["launch", "--devices", "3", "--sequence", "synthetic-corridor:120", "--frames", "120",
            "--seed", "3", "--focals", "525,450"]
    parsed = build_parser().parse_args(base)
    fleet = fleet_settings(parsed)[0]
    args = SimpleNamespace(sequence="synthetic-corridor:120", frames=120, start=0,
                           focals="525,450")
    assert fleet_starts(args, fleet) == [                      # type: ignore[arg-type]
        ("synthetic-corridor:120:300:525", 0), ("synthetic-corridor:120:301:450", 0),
        ("synthetic-corridor:120:302:525", 0)]
    args.sequence = "synthetic-corridor:120:0:600"
    assert fleet_starts(args, fleet)[1] == (                   # type: ignore[arg-type]
        "synthetic-corridor:120:301:450", 0)
    with pytest.raises(ValueError, match="--focals: a camera of each device's own needs a "
                                         "synthetic place"):
        fleet_settings(build_parser().parse_args(
            ["launch", "--devices", "2", "--sequence", "/data/7scenes", "--focals", "450"]))
    with pytest.raises(ValueError, match="focal lengths in pixels"):
        fleet_settings(build_parser().parse_args([*base[:-1], "525,wide"]))


def test_a_fleet_over_two_places_splits_its_devices_and_edges_by_place(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``--sequence A,B``: the devices split among the places in runs of neighbours, each
    place's devices spread over it as a fleet is, each edge serving whole places (a place's
    maps merge within one edge process) — and the settings that cannot run refused."""
    fleet = FleetConfig(5, 50, "equal", 5, edges=2, places=("synthetic:90", "/data/7scenes"))
    fleet.check()
    assert [fleet.place_of(i) for i in range(5)] == [0, 0, 1, 1, 1]
    assert fleet.blocks() == [["ar1", "ar2"], ["ar3", "ar4", "ar5"]]
    assert fleet.edge_shares() == [20, 30]
    three = FleetConfig(5, edges=2, places=("a", "b", "c"))
    assert [three.place_of(i) for i in range(5)] == [0, 0, 1, 2, 2]
    assert three.blocks() == [["ar1", "ar2", "ar3"], ["ar4", "ar5"]]     # places 1-2, 3
    assert FleetConfig(4, edges=3).blocks() == [["ar1"], ["ar2", "ar3"], ["ar4"]]
    assert places_of("synthetic:90, synthetic-corridor:90") == (
        "synthetic:90", "synthetic-corridor:90")
    assert places_of("synthetic:90") == ()
    args = SimpleNamespace(sequence="synthetic:90,synthetic-corridor:90", frames=90, start=0)
    two = FleetConfig(3, places=places_of(args.sequence))
    assert fleet_starts(args, two) == [                        # type: ignore[arg-type]
        ("synthetic:90:0", 0), ("synthetic:90:1", 0), ("synthetic-corridor:90:2", 0)]
    with pytest.raises(ValueError, match="3 edges for 2 places: each edge serves whole"):
        FleetConfig(4, edges=3, places=("a", "b")).check()
    with pytest.raises(ValueError, match="3 places for 2 devices"):
        FleetConfig(2, places=("a", "b", "c")).check()
    assert main(["launch", "--sequence", "synthetic:90,synthetic-corridor:90",
                 "--loopback"]) == 2
    assert "2 places (synthetic:90,synthetic-corridor:90) need --devices" in \
        capsys.readouterr().err
    assert main(["launch", "--devices", "2", "--sequence", "synthetic:90,/no/such/place",
                 "--loopback"]) == 2
    assert "--sequence:" in capsys.readouterr().err


def test_settings_that_cannot_run_are_refused_before_any_node_starts(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ValueError, match="V_total 8 is below 2 devices x 5 keyframes"):
        FleetConfig(2, 8, "equal", 5).check()
    with pytest.raises(ValueError, match="1 orders for 2 devices"):
        FleetConfig(2, orders=("backward",)).check()
    with pytest.raises(ValueError, match="order 'sideways'"):
        FleetConfig(2, orders=("forward", "sideways")).check()
    with pytest.raises(ValueError, match="1 delays for 2 devices"):
        FleetConfig(2, delays=(20.0,)).check()
    with pytest.raises(ValueError, match="delay -1 s"):
        FleetConfig(2, delays=(0.0, -1.0)).check()
    assert main(["launch", "--devices", "2", "--delays", "0,soon", "--loopback"]) == 2
    assert "--delays '0,soon': seconds, one a device" in capsys.readouterr().err
    assert main(["launch", "--devices", "2", "--allocator", "fifo", "--loopback"]) == 2
    assert "unknown allocator 'fifo'" in capsys.readouterr().err
    assert main(["launch", "--devices", "2", "--record", "bag", "--loopback"]) == 2
    assert "without --record" in capsys.readouterr().err
    assert main(["launch", "--every", "2", "--loopback"]) == 2
    assert "--every 2: a fleet's option" in capsys.readouterr().err


def test_every_second_frame_gives_two_devices_alternate_frames_and_halves_their_slots(
        tmp_path: Path, domain: LoopbackDomain) -> None:
    """``--every 2``: device k's camera plays the sequence's frames numbered k mod 2 — its
    player's phase counted from where its walk starts —, and its device is told a slot of
    half the frames at half the rate: a slot lasts as long, and the report counts a slot's
    frames as the device gets them (none dropped where all came)."""
    params = tmp_path / "params.yaml"
    params.write_text("device_tracker:\n  ros__parameters:\n    slot_frames: 30\n"
                      "    frame_rate_hz: 30.0\n", encoding="utf-8")
    config = LaunchConfig("synthetic:150", "lff", 150, 0.5, params_file=params)
    fleet = FleetConfig(3, every=2)
    launcher = FleetLauncher(domain, config, fleet, [("7scenes", 0), ("7scenes", 0),
                                                     ("7scenes", 501)], echo=None)

    def given(args: list[str]) -> dict[str, str]:
        return dict(a.split(":=", 1) for a in args if ":=" in a)

    players = [given(launcher.device_args("sequence_player", i)) for i in range(3)]
    # the third starts at the odd frame 501: its even frames are its walk's odd ones
    assert [(p["every"], p["phase"]) for p in players] == [("2", "0"), ("2", "1"), ("2", "1")]
    device = given(launcher.device_args("device_tracker", 1))
    assert (device["slot_frames"], float(device["frame_rate_hz"])) == ("15", 7.5)
    # told once: the run's rate (0.5) and the one camera frame in two in one figure
    told = [a for a in launcher.device_args("device_tracker", 1)
            if a.startswith("frame_rate_hz:=")]
    assert told == ["frame_rate_hz:=7.5"]
    assert launcher.device_slot_frames() == 15
    assert launcher.slot_period_s() == pytest.approx(2.0)     # 30 frames at half speed
    assert "every" not in given(FleetLauncher(domain, config, FleetConfig(2),
                                              [("synthetic:150", 0)] * 2, echo=None)
                                .device_args("sequence_player", 1))
    with pytest.raises(ValueError, match="slot of 30 frames does not split"):
        FleetLauncher(domain, config, FleetConfig(2, every=4), [], echo=None)
    with pytest.raises(ValueError, match="every 0"):
        FleetConfig(2, every=0).check()


def test_devices_replaying_the_same_images_are_named_and_alternate_frames_part_them() -> None:
    """Which devices' cameras both show some image — one dataset, overlapping frames, the
    same frames at ``every`` — whichever orders they walk: the launch names them (a merge
    between them may pair an image with itself)."""
    kitchen, lengths = "/data/7scenes", {"/data/7scenes": 1000}
    two = [(kitchen, 0), (kitchen, 0)]                   # --stride 1000: both from frame 0
    assert shared_images(FleetConfig(2), two, 1000, lengths) == [("ar1", "ar2")]
    assert shared_images(FleetConfig(2, orders=("forward", "backward")), two, 1000,
                         lengths) == [("ar1", "ar2")]
    assert shared_images(FleetConfig(2, every=2), two, 1000, lengths) == []
    three = [(kitchen, 0), (kitchen, 300), (kitchen, 600)]
    assert shared_images(FleetConfig(3), three, 700, lengths) == [
        ("ar1", "ar2"), ("ar1", "ar3"), ("ar2", "ar3")]
    assert shared_images(FleetConfig(3, every=2), three, 700, lengths) == [("ar1", "ar3")]
    assert shared_images(FleetConfig(3), three, 300, lengths) == []    # windows apart
    walks = [("synthetic:90:0", 0), ("synthetic:90:1", 0)]            # each its own walk
    assert shared_images(FleetConfig(2), walks, 90, {}) == []
    assert shared_images(FleetConfig(2, one_walk=True), [("synthetic:90:0", 0)] * 2, 90,
                         {}) == [("ar1", "ar2")]


def test_devices_are_split_among_edges_as_runs_of_neighbours_each_with_its_budget() -> None:
    names = [f"ar{i}" for i in range(1, 6)]
    assert edge_blocks(names, 2) == [["ar1", "ar2"], ["ar3", "ar4", "ar5"]]
    assert edge_blocks(names, 5) == [[n] for n in names]
    fleet = FleetConfig(5, 52, "equal", 5, edges=2)
    fleet.check()
    assert fleet.edge_names() == ["edge_mapper", "edge_mapper_2"]
    assert fleet.edge_hosts() == ["edge", "edge2"]
    assert fleet.edge_shares() == [21, 31] and sum(fleet.edge_shares()) == 52
    with pytest.raises(ValueError, match="3 edges for 2 devices"):
        FleetConfig(2, edges=3).check()
    assert FleetConfig(5, 25, "equal", 5, edges=2).edge_shares() == [10, 15]


def test_a_map_is_late_only_after_its_slot_has_played_at_the_runs_speed(
        domain: LoopbackDomain) -> None:
    """A fleet's late maps count against the slot's wall time: the default device's 30
    frames take 1 s at the recorded speed and 4 s at a quarter of it (``--rate 0.25``), and a
    map 2 s after its summaries is late only in the first."""
    def period(rate: float) -> float:
        config = LaunchConfig("synthetic:150", "lff", 150, rate)
        return FleetLauncher(domain, config, FleetConfig(2), [], echo=None).slot_period_s()

    assert period(1.0) == pytest.approx(1.0)
    assert period(0.25) == pytest.approx(4.0)
    assert period(0.25) * 1000 > 2000 > period(1.0) * 1000


def _read(params: Path, node: str, domain: LoopbackDomain, *remaps: str) -> dict[str, object]:
    """What node ``node`` started with ``params`` and ``remaps`` (``__node:=…``,
    ``__ns:=…``) reads from the file: rclpy's own parameter overrides, as the node sees them."""
    import rclpy
    from rclpy.node import Node

    args = ["node", "--ros-args", *(a for r in remaps for a in ("-r", r)),
            "--params-file", str(params)]
    context = rclpy.Context()
    rclpy.init(args=args, context=context, domain_id=domain.domain_id)
    try:
        n = Node(node, context=context, automatically_declare_parameters_from_overrides=True)
        values = {name: p.value for name, p in n.get_parameters_by_prefix("").items()
                  if not rclpy_own(name)}
        n.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    return values


def test_a_renamed_edge_reads_the_parameter_files_edge_section(
        tmp_path: Path, domain: LoopbackDomain) -> None:
    """ROS 2 gives a node only its own name's section of a parameter file (no wildcard within
    a name): the second edge, ``edge_mapper_2``, reads a copy under its name."""
    source = tmp_path / "params.yaml"
    source.write_text("edge_mapper:\n  ros__parameters:\n    vmax: 17\n"
                      "device_tracker:\n  ros__parameters:\n    vmax: 3\n", encoding="utf-8")
    (tmp_path / "fleet").mkdir()
    copy = renamed_params(source, "edge_mapper", "edge_mapper_2", tmp_path / "fleet")
    values = {params.name: _read(params, "edge_mapper", domain, "__node:=edge_mapper_2").get("vmax")
              for params in (source, copy)}
    assert values == {"params.yaml": None, "edge_mapper_2.yaml": 17}


def test_a_device_in_its_namespace_reads_the_parameter_files_device_section(
        tmp_path: Path, domain: LoopbackDomain) -> None:
    """A fleet runs each device and player under its device's namespace (``/ar1``), and rcl
    gives a namespaced node no section keyed by its plain name: with a user's file keyed
    ``device_tracker:`` the fleet's devices started on their defaults. The copy the fleet
    passes them keys it ``/**/device_tracker``; what a wildcard section held stays unless
    the plain one says otherwise."""
    source = tmp_path / "params.yaml"
    source.write_text("/**/device_tracker:\n  ros__parameters:\n    keep_slots: 4\n"
                      "    slot_frames: 45\n"
                      "device_tracker:\n  ros__parameters:\n    slot_frames: 60\n"
                      "edge_mapper:\n  ros__parameters:\n    vmax: 17\n", encoding="utf-8")
    (tmp_path / "fleet").mkdir()
    copy = namespaced_params(source, tmp_path / "fleet")
    assert _read(source, "device_tracker", domain) == {"keep_slots": 4, "slot_frames": 60}
    assert _read(source, "device_tracker", domain, "__ns:=/ar1") == {"keep_slots": 4,
                                                                     "slot_frames": 45}
    for remaps in ((), ("__ns:=/ar1",), ("__ns:=/site/ar2",)):
        assert _read(copy, "device_tracker", domain, *remaps) == {"keep_slots": 4,
                                                                  "slot_frames": 60}
        assert _read(copy, "edge_mapper", domain, *remaps) == {"vmax": 17}


@pytest.mark.parametrize("params", [DEFAULT_PARAMS, PAPER_PARAMS], ids=["default", "paper"])
def test_the_bundled_parameter_files_reach_their_nodes_in_any_namespace(
        params: Path, domain: LoopbackDomain) -> None:
    """Every node of a bundled parameter file reads every value of its section in the root
    namespace and in a device's (the fleet's ``/ar1``, ``ros2 launch … namespace:=/ar1``):
    the paper's preset reached a fleet's edge and not its devices before its sections were
    keyed ``/**/NODE``."""
    doc = yaml.safe_load(params.read_text(encoding="utf-8"))
    for key, body in doc.items():
        node = key.removeprefix("/**/")
        wanted = body["ros__parameters"]
        for remaps in ((), ("__ns:=/ar1",)):
            read = _read(params, node, domain, *remaps)
            assert read == pytest.approx(wanted), (node, remaps)


@dataclass(frozen=True)
class FleetRun:
    """One fleet launch's printout, its folder, and its edge processes seen while it played."""

    out: str
    folder: Path
    edges: list[int]


@pytest.fixture(scope="module")
def two_places_three_devices(tmp_path_factory: pytest.TempPathFactory) -> FleetRun:
    """``twinslam launch --devices 3 --edges 2`` over two places (``--sequence`` the room and
    the corridor): ar1 and ar2 walk the room, served by one edge, ar3 the corridor, served by
    the second; the motion allocator, a parameter file keyed by the plain node names whose
    device section sets 45-frame slots (2 over the 90 frames, where the node's default of 30
    makes 3), and ``--pace``. The edge processes are listed once every device has planned
    its first slot. One launch for the tests of one edge serving several devices and of the
    devices split among edges."""
    folder = tmp_path_factory.mktemp("fleet")
    params = folder / "params.yaml"
    params.write_text("device_tracker:\n  ros__parameters:\n    slot_frames: 45\n",
                      encoding="utf-8")
    cli = subprocess.Popen([sys.executable, "-m", "twinslam.cli.main", "launch", "--loopback",
                            "--devices", "3", "--edges", "2", "--vmax-total", "18",
                            "--allocator", "motion",
                            "--sequence", "synthetic:90,synthetic-corridor:90",
                            "--frames", "90", "--policy", "lff", "--params", str(params),
                            "--pace", "30", "--out", str(folder)], text=True,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           cwd=Path(__file__).resolve().parents[1])
    assert cli.stdout is not None
    seen, deadline = "", time.monotonic() + 180
    while not all(f"[lff {d}] slot   0" in seen for d in ("ar1", "ar2", "ar3")) and \
            time.monotonic() < deadline and cli.poll() is None:
        seen += cli.stdout.readline()
    pids = [int(pid) for pid in os.listdir("/proc") if pid.isdigit()]
    servers = [pid for pid in pids if _parent(pid) == cli.pid]
    edges = [pid for pid in pids if _parent(pid) in (cli.pid, *servers)
             and _name(pid) == "edge_mapper"]
    rest, err = cli.communicate(timeout=300)
    out = seen + rest
    assert cli.returncode == 0, (out[-3000:], err[-3000:])
    return FleetRun(out, folder, edges)


def _node_sections(log: str) -> dict[str, str]:
    """Each node's section of a fleet's log (``===== NAME =====`` heads them)."""
    parts = log.split("===== ")[1:]
    return {part.split(" =====", 1)[0]: part for part in parts}


@pytest.mark.slow
@pytest.mark.xdist_group("fleet-two-places")
def test_launch_splits_the_devices_among_two_edge_processes(
        two_places_three_devices: FleetRun) -> None:
    """``--edges 2`` over two places: two edge processes while the devices play, each
    serving the devices of its place, each device answered, each edge's devices within its
    share of V_total (12 for the room's two devices, 6 for the corridor's one)."""
    run = two_places_three_devices
    assert len(run.edges) == 2, (run.edges, run.out[-2000:])
    assert "3 devices, 2 edges (V_total 18 split motion)" in run.out
    assert "place 1: synthetic:90, walked by ar1, ar2, served by edge_mapper\n" in run.out
    assert "place 2: synthetic-corridor:90, walked by ar3, served by edge_mapper_2" in run.out
    assert "a false merge" not in run.out
    logs = (run.folder / "lff_motion.log").read_text(encoding="utf-8")
    for device, sequence in (("ar1", "synthetic "), ("ar2", "synthetic "),
                             ("ar3", "synthetic-corridor")):
        assert f"[{device}.sequence_player]: playing 90 frames of synthetic sequence " \
            f"{sequence}" in logs
    sections = _node_sections(logs)
    assert all(f"listening on /{d}/device/frame_summaries" in sections["edge_mapper"]
               for d in ("ar1", "ar2"))
    assert "/ar3/" not in sections["edge_mapper"]
    assert "listening on /ar3/device/frame_summaries" in sections["edge_mapper_2"]
    assert "/ar1/" not in sections["edge_mapper_2"] and "/ar2/" not in sections["edge_mapper_2"]
    budgets = {line.split()[0]: float(line.split()[-2]) for line in run.out.splitlines()
               if line.split() and line.split()[0] in ("ar1", "ar2", "ar3")}
    assert set(budgets) == {"ar1", "ar2", "ar3"} and all(b > 0 for b in budgets.values())
    assert budgets["ar1"] + budgets["ar2"] <= 12 + 1e-9 and budgets["ar3"] <= 6 + 1e-9


@pytest.mark.slow
@pytest.mark.xdist_group("fleet-two-places")
def test_launch_serves_two_devices_from_one_edge_and_reports_each(
        two_places_three_devices: FleetRun) -> None:
    """One edge serving the room's two devices, every device reported: its row, its picture,
    its node logs, its slots; the devices run in their namespaces with the parameter file's
    device section though it is keyed by the plain node name (45-frame slots: 2 over the 90
    frames); ``--pace``: the cameras wait together for their devices (one recording clock),
    and no device drops a frame however loaded the machine."""
    run, folder = two_places_three_devices, two_places_three_devices.folder
    assert "lff, allocator motion: 3 devices" in run.out and "Jain's index" in run.out
    assert "the cameras waiting together for any device beyond 30 unposed frames" in run.out
    rows = {line.split()[0] for line in run.out.splitlines()
            if line.split() and line.split()[0] in ("ar1", "ar2", "ar3", "mean")}
    assert rows == {"ar1", "ar2", "ar3", "mean"}
    assert sorted(p.name for p in folder.glob("*.png")) == [
        "lff_motion_ar1.png", "lff_motion_ar2.png", "lff_motion_ar3.png"]
    # every node's log kept with the run: what the edges said of each device's slots
    logs = (folder / "lff_motion.log").read_text(encoding="utf-8")
    assert all(f"===== {node} =====" in logs for node in (
        "edge_mapper", "edge_mapper_2", "device_tracker:ar1", "device_tracker:ar2",
        "device_tracker:ar3"))
    assert "[edge_mapper]" in logs and "slot" in logs
    assert logs.count("held for the device and its group fleet") == 3
    with (folder / "fleet_runs.csv").open(encoding="utf-8") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["device"], r["allocator"], r["seed"]) for r in table] == [
        ("ar1", "motion", "0"), ("ar2", "motion", "0"), ("ar3", "motion", "0")]
    assert [int(r["frames_dropped"]) for r in table] == [0, 0, 0]
    assert all(int(r["frames"]) > 0 and float(r["latency_ms_median"]) > 0
               and int(r["frames_uploaded"]) > 0 for r in table)
    assert [int(r["slots"]) for r in table] == [2, 2, 2]


@pytest.mark.slow
def test_a_terminated_launch_stops_the_nodes_it_started(tmp_path: Path) -> None:
    """SIGTERM (``kill``, a scheduler) ends ``twinslam launch`` as Ctrl-C does: exit 130 and
    none of its node processes left running."""
    import signal

    cli = subprocess.Popen([sys.executable, "-m", "twinslam.cli.main", "launch", "--loopback",
                            "--sequence", "synthetic:900", "--frames", "900", "--policy", "lff",
                            "--out", str(tmp_path)], text=True, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, cwd=Path(__file__).resolve().parents[1])
    assert cli.stdout is not None
    seen, deadline = "", time.monotonic() + 120
    while "slot   0" not in seen and time.monotonic() < deadline and cli.poll() is None:
        seen += cli.stdout.readline()
    # the nodes: the launcher's children, or its fork server's (twinslam.live.node_fork_server)
    pids = [int(pid) for pid in os.listdir("/proc") if pid.isdigit()]
    servers = [pid for pid in pids if _parent(pid) == cli.pid]
    children = [pid for pid in pids if _parent(pid) in (cli.pid, *servers)]
    names = {_name(pid) for pid in children}
    assert "slot   0" in seen and {"edge_mapper", "device_tracker", "sequence_player"} <= names, \
        (seen[-2000:], names)
    cli.send_signal(signal.SIGTERM)
    _, err = cli.communicate(timeout=60)
    assert cli.returncode == 130 and "interrupted: nodes stopped" in err, err[-2000:]
    assert not [pid for pid in children if _alive(pid)], "nodes left running"


def _parent(pid: int) -> int:
    try:
        return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
    except (OSError, IndexError, ValueError):
        return -1


def _name(pid: int) -> str:
    """A node process's name: the one a forked node gives itself, or its ``-m`` module's."""
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")
    except OSError:
        return ""
    if not comm.startswith("python"):
        return comm
    return process_name(argv[argv.index("-m") + 1]) if "-m" in argv[:-1] else comm


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state != "Z"


@pytest.mark.slow
def test_a_fleet_whose_player_cannot_play_fails_and_names_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A device's camera that refuses its parameters plays nothing: the launch exits 1
    naming that player and its reason, and writes no table of devices that never played."""
    from twinslam.live.fleet import FleetLauncher

    plain = FleetLauncher.device_args

    def refused_by_ar2(self: FleetLauncher, name: str, index: int,
                       params_file: Path | None = None) -> list[str]:
        args = plain(self, name, index, params_file)
        return [*args, "-p", "path_window:=0"] if (name, index) == ("sequence_player", 1) \
            else args

    monkeypatch.setattr(FleetLauncher, "device_args", refused_by_ar2)
    code = main(["launch", "--loopback", "--devices", "2", "--sequence", "synthetic:60",
                 "--frames", "60", "--policy", "lff", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 1, err[-3000:]
    assert "sequence_player:ar2 exited with 2" in err and "path_window" in err, err[-3000:]
    assert not (tmp_path / "fleet_runs.csv").exists()
