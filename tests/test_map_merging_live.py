"""One edge serving two devices in one room (``merge_maps:=true``), every node its own process
on a loopback domain: the first device walks the synthetic room forward, the second the same
walk backward from its last frame (and on again), each starting a map in its own first
camera's frame — the first camera playing the walk's even frames, the second its odd ones
(``every:=2``), so that no image of one is an image of the other, as with two real cameras;
the edge finds the second device's keyframes in the first device's map and
moves the second map into the first's frame — the second device's map updates then carry the
motion between the two frames, as the truth has it, the second device's poses are in the
first one's frame, and it tracks on keyframes only the first device uploaded, where content
the first device anchored appears to the second within the shared map's 3 cm, and frames
whose views the other device's keyframes cover are not asked for."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from twinslam_msgs.msg import FrameSummaries, FrameSummary, MapUpdate

from msg_schemas import qos, topics
from msg_schemas.headers import stamp_key, time_key
from msg_schemas.poses import pose_matrix
from tests.paced_runs import PACE_FRAMES, assert_kept_up
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.live.tracking_quality import RevisitError, cross_device_revisit_error
from twinslam.node_runtime.session import RosSession
from twinslam.rotations import rotation_angle_deg
from twinslam.sequences.opening import open_sequence
from twinslam.slam.back_end.foreign_keyframes import is_foreign
from twinslam.slot_protocol.default_device import SLOT_FRAMES

#: frames of the room walked: the second device starts where the first ends
FRAMES = 300
#: the cameras play at half speed: each device's tracking, rendering and the edge's looks
#: share two cores with the other device's
RATE, FRAME_RATE_HZ = 0.5, 30.0
#: each device's order of the frames: the second walks on past the first one's start, over
#: the ground the first mapped — a merge that comes late (a loaded machine's edge falls slots
#: behind) still has frames of the second device to track on it
ORDER = {"ar1": "forward", "ar2": "backward_forward"}
#: each camera plays one frame in two — ar1 the walk's even frames, ar2 its odd ones — and
#: its device is told so: half the frame rate, slots of half the frames (still a second)
EVERY, PHASE = 2, {"ar1": 0, "ar2": 1}

#: the cameras wait for their devices, together (the player's pace_group): on a loaded machine
#: a device that fell behind its camera dropped frames (3–68 of a walk, unpaced), and a camera
#: paced alone would change when the two walks meet
PACED = ["-p", f"pace_frames:={PACE_FRAMES}", "-p", "pace_group:=fleet"]

#: the nodes are forked from the launchers' fork server (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


@pytest.mark.slow(seconds=40)
def test_the_edge_merges_the_second_devices_map_into_the_first_ones_frame(
        domain: LoopbackDomain, ros: RosSession, tmp_path: Path) -> None:
    """The merge and what follows from it (the module's text); then the edge is killed and
    started again from its checkpoints: it serves the second device in the first one's place
    at once, with no look and no merge found anew."""
    maps: dict[str, list[MapUpdate]] = {d: [] for d in ORDER}
    summaries: list[FrameSummaries] = []
    first_summaries: list[FrameSummaries] = []
    for d, got in maps.items():
        ros.node.create_subscription(MapUpdate, f"/{d}/edge/map_update", got.append, qos.MAP)
    ros.node.create_subscription(FrameSummaries, "/ar2/device/frame_summaries",
                                 summaries.append, qos.PROTOCOL)
    ros.node.create_subscription(FrameSummaries, "/ar1/device/frame_summaries",
                                 first_summaries.append, qos.PROTOCOL)
    # the frames the second device's poses go out in, as a viewer reads them
    pose_frames: list[str] = []
    ros.node.create_subscription(PoseStamped, f"/ar2/{topics.DEVICE_POSE}",
                                 lambda msg: pose_frames.append(msg.header.frame_id),
                                 qos.PROTOCOL)
    # each device's true poses by stamp, as its player publishes them: a device under load
    # skips a frame whose colour image never came, and its frame ids then run behind the
    # played frames — only the stamp tells which frame a summary is of
    truths: dict[str, dict[int, np.ndarray]] = {d: {} for d in ORDER}
    for d, truth_of in truths.items():
        ros.node.create_subscription(
            PoseStamped, f"/{d}/{topics.GROUND_TRUTH_POSE}",
            lambda msg, got=truth_of: got.__setitem__(stamp_key(msg.header),
                                                      pose_matrix(msg.pose)), qos.CAMERA)

    def with_truth(device: str, frames: list[FrameSummary]
                   ) -> list[tuple[np.ndarray, np.ndarray]]:
        """(pose, true pose) of each of ``frames`` whose truth came."""
        return [(pose_matrix(f.pose), truth) for f in frames
                if (truth := truths[device].get(time_key(f.stamp))) is not None]

    edge_args = ["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=lff",
                 "-p", "devices:=[ar1, ar2]", "-p", "merge_maps:=true",
                 "-p", "visualisation:=false", "-p", f"checkpoint:={tmp_path / 'edge.npz'}"]
    edge = domain.spawn(edge_args, forks=FORKS)
    assert domain.wait_for_log(edge, "listening on /ar2/device/frame_summaries", 90), \
        domain.log(edge)[-2000:]
    trackers = {}
    for d, order in ORDER.items():
        trackers[d] = domain.spawn(["-m", "device_tracker.node", "--ros-args",
                                    "-r", f"__ns:=/{d}",
                                    "-p", f"frame_rate_hz:={FRAME_RATE_HZ * RATE / EVERY}",
                                    "-p", f"slot_frames:={SLOT_FRAMES // EVERY}",
                                    "-p", f"map_frame:={d}/map"], forks=FORKS)
        domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args", "-r", f"__ns:=/{d}",
                      "-p", f"sequence:=synthetic:{FRAMES}", "-p", f"order:={order}",
                      "-p", f"every:={EVERY}", "-p", f"phase:={PHASE[d]}",
                      "-p", "wait_for_subscribers:=1", "-p", f"rate:={RATE}",
                      "-p", f"frame_id:={d}/camera", "-p", f"map_frame:={d}/map", *PACED],
                     forks=FORKS)

    def moved(update: MapUpdate) -> bool:
        return not np.allclose(pose_matrix(update.frame_correction), np.eye(4), atol=1e-9)

    assert ros.spin_until(lambda: any(moved(u) for u in maps["ar2"]), 150.0), (
        f"no merge moved ar2's map; the edge's log:\n{domain.log(edge)[-3000:]}\n"
        f"ar2's device's log:\n{domain.log(trackers['ar2'])[-2000:]}")
    merged_version = next(int(u.map_version) for u in maps["ar2"] if moved(u))
    # the second device tracks on in the first one's frame: a slot of its frames on it
    def last() -> list[tuple[int, list[tuple[int, bool]]]]:
        return [(int(s.slot), [(int(f.map_version), bool(f.tracked)) for f in s.frames][-3:])
                for s in summaries[-4:]]

    assert ros.spin_until(lambda: any(f.map_version >= merged_version and f.tracked
                                      for s in summaries for f in s.frames), 60.0), (
        f"ar2 tracked no frame on map version {merged_version} or later; its last "
        f"summaries (slot, [(map version, tracked)]): {last()}\n"
        f"its device's log:\n{domain.log(trackers['ar2'])[-3000:]}\n"
        f"the edge's log:\n{domain.log_with_stacks(edge)}")
    assert domain.wait_for_log(edge, "[ar2] slot", 10.0)
    log = domain.log(edge)
    assert "map merged into ar1's" in log, log[-3000:]
    merged = next(u for u in maps["ar2"] if moved(u))
    # the second device's map frame is its first camera (the walk's last frame), the first
    # device's the walk's first frame: the merge moved the one into the other
    room = open_sequence(f"synthetic:{FRAMES}")
    truth = np.linalg.inv(room.read(0).pose) @ room.read(FRAMES - 1).pose  # type: ignore[attr-defined]
    off = np.linalg.inv(truth) @ pose_matrix(merged.frame_correction)
    assert np.linalg.norm(off[:3, 3]) < 0.05 and rotation_angle_deg(off[:3, :3]) < 2.0, off
    # every later update of the second device stays in the first one's frame; the first
    # device's map never moved
    later = maps["ar2"][maps["ar2"].index(merged):]
    assert all(np.allclose(pose_matrix(u.frame_correction),
                           pose_matrix(merged.frame_correction)) for u in later)
    assert maps["ar1"] and not any(moved(u) for u in maps["ar1"])
    # what the edge publishes of the second device is in the first one's frame from then on
    assert all(u.header.frame_id == "ar1/map" for u in later + maps["ar1"])
    assert all(u.header.frame_id == "ar2/map" for u in maps["ar2"][:maps["ar2"].index(merged)])
    # and so are the second device's own poses: a viewer shows them where the place has them
    assert ros.spin_until(lambda: "ar1/map" in pose_frames, 30.0), \
        (sorted(set(pose_frames)), domain.log(trackers["ar2"])[-2000:])
    switched = pose_frames.index("ar1/map")      # in the order the device tracked them
    assert set(pose_frames[:switched]) <= {"ar2/map"}
    assert "ar2/map" not in pose_frames[switched:]
    assert "poses in ar1/map from map version" in domain.log(trackers["ar2"])
    # the second device's poses on the merged map are where the first device's frame has
    # those places
    first_camera = np.linalg.inv(room.read(0).pose)          # type: ignore[attr-defined]

    def merged_frames() -> list[FrameSummary]:
        return [f for s in summaries for f in s.frames
                if f.tracked and f.map_version >= merged_version]

    errors = [np.linalg.norm(pose[:3, 3] - (first_camera @ truth)[:3, 3])
              for pose, truth in with_truth("ar2", merged_frames())]
    assert errors and float(np.median(errors)) < 0.05, errors
    # the second device tracks on keyframes only the first uploaded, adopted into its map
    assert ros.spin_until(lambda: any(is_foreign(int(k)) for u in maps["ar2"]
                                      for k in u.keyframe_ids), 60.0), \
        domain.log(edge)[-3000:]
    assert ros.spin_until(lambda: any(is_foreign(int(p)) for s in summaries for f in s.frames
                                      if f.tracked for p in f.map_point_ids), 30.0)
    # an anchor the first device placed, as the second sees it: for every pair of a frame of
    # each within 0.3 m and 20° of each other in truth, their relative pose against the
    # truth's (the cross-device revisit error) within the shared-map bound of 3 cm. The walk's
    # two ends are 23° apart: the pairs come once the second device reaches where the first was

    def anchors() -> RevisitError:
        return cross_device_revisit_error(
            with_truth("ar1", [f for s in first_summaries for f in s.frames if f.tracked]),
            with_truth("ar2", merged_frames()))

    assert ros.spin_until(lambda: anchors().pairs >= 50, 90.0), anchors()
    seen = anchors()
    print(f"\ncross-device revisit error after the merge: {seen.rms_m * 100:.1f} cm RMS, "
          f"{seen.p95_m * 100:.1f} cm p95, over {seen.pairs} pairs")
    assert seen.rms_m <= 0.03, seen
    for d, tracker in trackers.items():
        assert_kept_up(domain.log(tracker), d)
    # where the other device's lent keyframes stand, a device's frames are not asked for
    assert domain.wait_for_log(edge, "the map covers their views", 60.0), \
        domain.log(edge)[-3000:]
    # the edge dies (no goodbye) and starts again from the checkpoints it wrote every slot
    edge.send_signal(signal.SIGKILL)
    edge.wait(timeout=10)
    again = domain.spawn(edge_args, forks=FORKS)
    assert domain.wait_for_log(again, "device ar2's map restored: back in ar1's place", 90), \
        domain.log(again)[-3000:]


@pytest.mark.slow(seconds=40)
def test_two_places_that_share_posters_are_not_merged(domain: LoopbackDomain,
                                                      ros: RosSession) -> None:
    """One edge, two devices in two places — the synthetic room and the corridor, whose walls
    show some of the same photographs (the astronaut, the cat, the coffee): the second
    device's keyframes are looked for in the first's map after each of its slots, and no
    merge comes of it in eight slots; each map stays in its own frame."""
    maps: dict[str, list[MapUpdate]] = {d: [] for d in ORDER}
    for d, got in maps.items():
        ros.node.create_subscription(MapUpdate, f"/{d}/edge/map_update", got.append, qos.MAP)
    edge = domain.spawn(["-m", "edge_mapper.node", "--ros-args", "-p", "policy:=lff",
                         "-p", "devices:=[ar1, ar2]", "-p", "merge_maps:=true",
                         "-p", "visualisation:=false"], forks=FORKS)
    assert domain.wait_for_log(edge, "listening on /ar2/device/frame_summaries", 90), \
        domain.log(edge)[-2000:]
    trackers = {}
    for d, sequence in (("ar1", f"synthetic:{FRAMES}"), ("ar2", f"synthetic-corridor:{FRAMES}")):
        trackers[d] = domain.spawn(["-m", "device_tracker.node", "--ros-args",
                                    "-r", f"__ns:=/{d}",
                                    "-p", f"frame_rate_hz:={FRAME_RATE_HZ * RATE}",
                                    "-p", f"map_frame:={d}/map"], forks=FORKS)
        domain.spawn(["-m", "twinslam.sequence_player.node", "--ros-args", "-r", f"__ns:=/{d}",
                      "-p", f"sequence:={sequence}", "-p", "wait_for_subscribers:=1",
                      "-p", f"rate:={RATE}", "-p", f"frame_id:={d}/camera",
                      "-p", f"map_frame:={d}/map", *PACED], forks=FORKS)
    assert ros.spin_until(lambda: all(len(m) >= 8 for m in maps.values()), 150.0), \
        ({d: len(m) for d, m in maps.items()}, domain.log(edge)[-3000:])
    log = domain.log(edge)
    assert "map merged into" not in log, log[-3000:]
    # the second device's place was looked for in the first's map (not merely never looked)
    assert "[ar2] slot" in log and "no other map's place found yet" in log, log[-3000:]
    for d, got in maps.items():
        assert all(u.header.frame_id == f"{d}/map" for u in got)
        assert all(np.allclose(pose_matrix(u.frame_correction), np.eye(4)) for u in got)
        assert_kept_up(domain.log(trackers[d]), d)
