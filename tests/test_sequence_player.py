"""sequence_player as its own process on a loopback domain, received by this process."""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import CameraInfo, Image

from msg_schemas import qos, topics
from twinslam.hosts.forked import NodeProcess
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.live.launcher import preloaded_nodes
from twinslam.node_runtime.session import RosSession
from twinslam.sequence_player.messages import depth_message, skipped_frames
from twinslam.sequences.decoded_frames import CACHE_ENV, SUFFIX
from twinslam.sequences.frame import RgbdFrame
from twinslam.sequences.synthetic import SyntheticSequence

K = np.array([[200.0, 0, 80], [0, 200.0, 60], [0, 0, 1]])

#: node processes forked as the launchers fork theirs (twinslam.live.node_fork_server)
FORKS = preloaded_nodes()


def _seven_scenes_fixture(root: Path, frames: int, corrupt: int) -> Path:
    root.mkdir()
    np.savetxt(root / "camera-intrinsics.txt", K)
    rng = np.random.default_rng(0)
    for i in range(frames):
        cv2.imwrite(str(root / f"frame-{i:06d}.color.jpg"),
                    rng.integers(0, 255, (120, 160, 3), dtype=np.uint8))
        cv2.imwrite(str(root / f"frame-{i:06d}.depth.png"),
                    np.full((120, 160), 1000 + i, np.uint16))
        pose = np.eye(4)
        pose[0, 3] = 0.01 * i
        np.savetxt(root / f"frame-{i:06d}.pose.txt", pose)
    (root / f"frame-{corrupt:06d}.color.jpg").write_bytes(b"\xff\xd8\xff broken")
    return root


def _play(domain: LoopbackDomain, *params: str) -> NodeProcess:
    """The player as its own process (forked as the launchers fork it), holding its first
    frame until this test's reader matched; ``params``: more ``name:=value``."""
    args = ["-m", "twinslam.sequence_player.node", "--ros-args", "-p", "wait_for_subscribers:=1"]
    for param in params:
        args += ["-p", param]
    return domain.spawn(args, forks=FORKS)


def _statuses(ros: RosSession) -> list[DiagnosticArray]:
    """What the player says of its playback on /diagnostics, as it comes."""
    statuses: list[DiagnosticArray] = []
    ros.node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, statuses.append,
                                 qos.PROTOCOL)
    return statuses


def _stamp(msg: object) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9  # type: ignore[attr-defined]


def test_player_delivers_every_frame_at_30_hz_and_skips_a_corrupt_jpeg(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession,
        monkeypatch: pytest.MonkeyPatch) -> None:
    seq = _seven_scenes_fixture(tmp_path / "seq", frames=100, corrupt=40)
    monkeypatch.setenv(CACHE_ENV, str(tmp_path / "decoded"))   # the player keeps its frames
    got: dict[str, list] = {"color": [], "depth": [], "info": [], "pose": []}
    for key, topic, kind in [("color", topics.CAMERA_IMAGE, Image),
                             ("depth", topics.CAMERA_DEPTH, Image),
                             ("info", topics.CAMERA_INFO, CameraInfo),
                             ("pose", topics.GROUND_TRUTH_POSE, PoseStamped)]:
        ros.node.create_subscription(kind, topic, lambda m, k=key: got[k].append(m),
                                     qos.CAMERA)
    paths: list[PathMsg] = []
    ros.node.create_subscription(PathMsg, topics.GROUND_TRUTH_PATH, paths.append, qos.MAP)
    statuses = _statuses(ros)
    player = _play(domain, f"sequence:={seq}", "path_window:=50")
    start = time.monotonic()
    # 99 frames at 30 Hz take 3.3 s; generous bound for a loaded CI machine
    ros.spin_until(lambda: player.poll() is not None and len(got["color"]) >= 99, 40.0)
    ros.spin_until(lambda: len(got["info"]) >= 99 and len(got["pose"]) >= 99
                   and bool(paths) and len(paths[-1].poses) == 50
                   and _stamp(paths[-1]) == _stamp(got["pose"][-1])
                   and any(skipped_frames(s) == 1 for s in statuses), 5.0)
    code, _, err = domain.stop(player)
    assert code == 0, err
    assert len(got["color"]) == 99, f"received {len(got['color'])} of 99 frames"
    assert len(got["depth"]) == len(got["info"]) == len(got["pose"]) == 99
    stamps = np.array([_stamp(m) for m in got["color"]])
    gaps = np.diff(stamps)
    assert np.all(gaps > 0)
    np.testing.assert_allclose(np.median(gaps), 1 / 30, rtol=1e-6)   # recorded 30 Hz spacing
    across_skip = np.flatnonzero(np.abs(gaps - 2 / 30) < 1e-6)
    assert across_skip.tolist() == [39]                  # frames 39 → 41: one gap of two periods
    assert [_stamp(m) for m in got["info"]] == stamps.tolist()
    assert [_stamp(m) for m in got["depth"]] == stamps.tolist()
    info = got["info"][0]
    np.testing.assert_allclose(np.asarray(info.k).reshape(3, 3), K)
    assert (info.width, info.height) == (160, 120) and got["color"][0].encoding == "rgb8"
    depth0 = np.frombuffer(bytes(got["depth"][0].data), np.uint16)
    assert got["depth"][0].encoding == "16UC1" and np.all(depth0 == 1000)
    assert abs(got["pose"][40].pose.position.x - 0.41) < 1e-12   # 40th received: frame 41
    assert "frame-000040.color.jpg" in err and "1 skipped" in err
    # and on /diagnostics, where a run's monitor counts it apart from frames a device dropped
    (done,) = statuses[-1].status
    values = {kv.key: kv.value for kv in done.values}
    assert done.level == DiagnosticStatus.WARN and skipped_frames(statuses[-1]) == 1
    assert values["published"] == "99" and values["finished"] == "true"
    assert "frame-000040.color.jpg" in values["skipped_files"]
    # the ground-truth path: once a second and at the end, the newest path_window poses
    assert len(paths) >= 3 and paths[-1].header.frame_id == "world"
    assert [_stamp(p) for p in paths[-1].poses] == [_stamp(m) for m in got["pose"][-50:]]
    assert 3.0 < time.monotonic() - start
    # every frame it decoded is in the cache the environment named, the corrupt one not
    assert len(list((tmp_path / "decoded").glob(f"*{SUFFIX}"))) == 99


def test_depth_message_encodings_round_trip() -> None:
    depth = np.array([[0.0, 1.5], [2.25, 0.0]], np.float32)
    frame = RgbdFrame(0, 0.0, np.zeros((2, 2, 3), np.uint8), depth, K, None, "f")
    mm = depth_message(frame, 1.25, "camera", "16UC1")
    assert mm.step == 4 and mm.header.stamp.sec == 1 and mm.header.stamp.nanosec == 250_000_000
    assert np.frombuffer(bytes(mm.data), np.uint16).tolist() == [0, 1500, 2250, 0]
    metres = depth_message(frame, 0.0, "camera", "32FC1")
    values = np.frombuffer(bytes(metres.data), np.float32)
    assert np.isnan(values[0]) and values[1:3].tolist() == [1.5, 2.25]


def test_the_device_reads_back_the_images_the_player_publishes() -> None:
    """Colour to the byte and depth to the millimetre, through the messages and their wire
    form: readings past 16UC1's range clipped to it, rows padded beyond the width skipped."""
    from rclpy.serialization import deserialize_message, serialize_message

    from device_tracker.camera_input import depth_array, image_array
    from twinslam.sequence_player.messages import color_message

    rng = np.random.default_rng(0)
    colour = rng.integers(0, 256, (3, 5, 3), dtype=np.uint8)
    depth = rng.uniform(0.0, 8.0, (3, 5)).astype(np.float32)
    depth[0, :3] = [0.0, 70.0, 0.0015]         # no reading, past 65.535 m, 1.5 mm (to 2)
    frame = RgbdFrame(0, 0.0, colour, depth, K, None, "f")
    wire = [deserialize_message(serialize_message(m), Image)
            for m in (color_message(frame, 0.0, "camera"), depth_message(frame, 0.0, "camera"))]
    assert np.array_equal(image_array(wire[0]), colour)
    read = depth_array(wire[1])
    assert read.dtype == np.float32
    millimetres = np.round(read.astype(np.float64) * 1000.0)
    assert np.array_equal(millimetres, np.clip(np.round(depth * 1000.0), 0, 65535))
    assert millimetres[0, :3].tolist() == [0.0, 65535.0, 2.0]
    padded = Image(height=3, width=5, encoding="16UC1", step=12,   # 2 bytes of padding a row
                   data=np.pad(np.frombuffer(bytes(wire[1].data), np.uint8).reshape(3, 10),
                               ((0, 0), (0, 2)), constant_values=255).reshape(-1).tobytes())
    assert np.array_equal(depth_array(padded), depth_array(wire[1]))


def _messages_equal(a: dict, b: dict) -> None:
    from tests.nodes.digest import content_digest

    assert a.keys() == b.keys()
    for key in a:
        if key == "pose":   # rotation → quaternion → rotation: equal to rounding
            pa, pb = a[key].pose, b[key].pose
            np.testing.assert_allclose(
                [pa.position.x, pa.position.y, pa.position.z, pa.orientation.w],
                [pb.position.x, pb.position.y, pb.position.z, pb.orientation.w], atol=1e-12)
            continue
        assert content_digest(a[key]) == content_digest(b[key]), key


def test_record_to_mcap_and_replay_gives_the_same_messages(tmp_path: Path) -> None:
    import subprocess
    import sys

    from twinslam.sequence_player.sequence_bag import frame_messages
    from twinslam.sequences.opening import open_sequence

    seq = _seven_scenes_fixture(tmp_path / "seq", frames=12, corrupt=5)
    bag = tmp_path / "run"
    run = subprocess.run([sys.executable, "-m", "twinslam.cli.main", "record", str(seq),
                          "-o", str(bag)], capture_output=True, text=True, timeout=120,
                         cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 0, run.stderr
    assert "wrote 11 frames, 1 skipped" in run.stdout and "frame-000005" in run.stdout
    assert list(bag.glob("*.mcap")), "rosbag2 with the MCAP storage plugin"
    folder, replay = open_sequence(seq), open_sequence(bag)
    assert replay.kind == "rosbag2" and len(replay) == 11
    pairs = list(zip(folder, replay, strict=True))
    for original, again in pairs:
        assert abs(again.stamp - original.stamp) < 1e-9     # ROS time: whole nanoseconds
        _messages_equal(frame_messages(original, original.stamp),
                        frame_messages(again, again.stamp))
    sub = open_sequence(bag, start=2, end=5)
    assert [round(f.stamp * 30) for f in sub] == [2, 3, 4]


def test_a_playback_ends_where_a_run_asks_while_it_plays(
        domain: LoopbackDomain, ros: RosSession) -> None:
    """``stop_after`` set while the player plays (as ``Launcher.end_playback`` sets it): a
    count already passed is refused with the count, the next slot boundary is asked, and the
    player publishes exactly that many frames, says so, and exits 0."""
    from twinslam.live.playback_end import PlaybackEnd

    colour: list[Image] = []
    ros.node.create_subscription(Image, topics.CAMERA_IMAGE, colour.append, qos.CAMERA)
    statuses = _statuses(ros)
    # 600 frames at 30 Hz would take 20 s: the run ends it after a few slots of 10 frames
    player = _play(domain, "sequence:=synthetic:600")
    end = PlaybackEnd(ros.node, slot_frames=10, most_frames=600)
    assert ros.spin_until(lambda: len(colour) >= 25, 60.0), domain.log(player)[-2000:]
    end.request()
    # a first guess behind the player (it published 25 or more): refused with its count, then
    # a boundary past that count
    assert ros.spin_until(lambda: (end.poll(0), end.frames is not None)[1], 20.0)
    assert end.refused >= 1 and end.frames is not None and end.frames % 10 == 0
    assert end.frames >= 30
    assert ros.spin_until(lambda: player.poll() is not None, 30.0), domain.log(player)[-2000:]
    code, _, err = domain.stop(player)
    assert code == 0, err
    assert f"done: {end.frames} frames published" in err
    assert ros.spin_until(lambda: len(colour) >= end.frames, 5.0)
    assert len(colour) == end.frames
    values = {kv.key: kv.value for kv in statuses[-1].status[0].values}
    assert values["published"] == str(end.frames) and values["finished"] == "true"


def test_a_playback_end_the_player_accepted_as_it_exited_is_taken_after_the_exit(
        ros: RosSession) -> None:
    """The player accepts an end and stops a few frames later: on a loaded machine it may
    exit before the run's monitor took its answer. The run then waits for the answer
    (``answer_awaited``) and knows the frames played — not the most the player might have
    played, which made it wait for and count slots that never came."""
    from rcl_interfaces.msg import SetParametersResult
    from rcl_interfaces.srv import SetParameters
    from rclpy.task import Future

    from twinslam.live.playback_end import PlaybackEnd

    end = PlaybackEnd(ros.node, slot_frames=30, most_frames=900)
    assert not end.answer_awaited()                    # nothing asked
    end.request()
    answer: Future = Future()
    end._asked, end._pending = 240, answer             # asked, the answer on its way
    assert end.answer_awaited() and end.frames is None
    answer.set_result(SetParameters.Response(results=[SetParametersResult(successful=True)]))
    assert not end.answer_awaited()
    assert end.frames == 240 and end.settled


def test_a_playback_end_before_what_was_played_is_refused(
        domain: LoopbackDomain, ros: RosSession) -> None:
    """What ``ros2 param set /sequence_player stop_after N`` answers for a count already
    passed: refused, with the count; the playback goes on."""
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    colour: list[Image] = []
    ros.node.create_subscription(Image, topics.CAMERA_IMAGE, colour.append, qos.CAMERA)
    player = _play(domain, "sequence:=synthetic:300")
    client = AsyncParameterClient(ros.node, "sequence_player")
    assert ros.spin_until(lambda: len(colour) >= 5 and client.services_are_ready(), 60.0)
    future = client.set_parameters([Parameter("stop_after", value=1)])
    assert ros.spin_until(future.done, 10.0)
    (result,) = future.result().results
    assert not result.successful and "frames are published already" in result.reason
    assert player.poll() is None, "a refused end ended the playback"
    domain.stop(player)


def test_a_player_given_a_start_delay_holds_its_first_frame_that_much_longer(
        domain: LoopbackDomain, ros: RosSession) -> None:
    """``start_delay_s`` (a user who comes to the place later): the first frame comes the
    delay after the player and this reader matched, on top of the discovery settle (1 s),
    and the frames then keep their recorded 30 Hz spacing."""
    colour: list[tuple[float, Image]] = []
    sub = ros.node.create_subscription(Image, topics.CAMERA_IMAGE,
                                       lambda m: colour.append((time.monotonic(), m)),
                                       qos.CAMERA)
    player = _play(domain, "sequence:=synthetic:20", "start_delay_s:=3.0")
    assert ros.spin_until(lambda: sub.get_publisher_count() >= 1, 60.0), \
        domain.log(player)[-2000:]
    matched = time.monotonic()
    assert ros.spin_until(lambda: len(colour) >= 20, 60.0), domain.log(player)[-2000:]
    # without the delay the first frame comes ~1 s after the match (the settle); discovery
    # may show this reader the player somewhat after the player saw it: half a second spare
    assert colour[0][0] - matched >= 3.5, colour[0][0] - matched
    stamps = np.array([_stamp(m) for _, m in colour])
    np.testing.assert_allclose(np.diff(stamps), 1 / 30, atol=1e-6)    # stamps are whole ns
    assert ros.spin_until(lambda: player.poll() is not None, 30.0)
    code, _, err = domain.stop(player)
    assert code == 0, err


def test_a_player_at_one_frame_in_two_plays_its_phase_at_the_walks_times(
        domain: LoopbackDomain, ros: RosSession) -> None:
    """``every:=2 phase:=1`` on a walk played backward: the sequence's odd frames, from its
    last (19, 17, …), each at its time in the walk (two periods apart) with its own ground
    truth — what a device walking from the other end sees beside one at phase 0, never one
    of that one's images."""
    colour: list[Image] = []
    truth: list[PoseStamped] = []
    ros.node.create_subscription(Image, topics.CAMERA_IMAGE, colour.append, qos.CAMERA)
    ros.node.create_subscription(PoseStamped, topics.GROUND_TRUTH_POSE, truth.append,
                                 qos.CAMERA)
    player = _play(domain, "sequence:=synthetic:20", "order:=backward", "every:=2",
                   "phase:=1")
    assert ros.spin_until(lambda: player.poll() is not None and len(truth) >= 10, 60.0), \
        domain.log(player)[-2000:]
    code, _, err = domain.stop(player)
    assert code == 0 and "one frame in 2 from 1" in err, err[-2000:]
    assert len(colour) == len(truth) == 10
    np.testing.assert_allclose(np.diff([_stamp(m) for m in colour]), 2 / 30, atol=1e-6)
    walk = SyntheticSequence(20)
    for pose, frame in zip(truth, range(19, 0, -2), strict=True):
        assert pose.pose.position.x == pytest.approx(walk.pose(frame)[0, 3], abs=1e-9)


def test_a_paced_player_holds_its_camera_until_the_device_poses_and_keeps_the_stamps(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession) -> None:
    """``pace_frames:=5``: with no pose from the device the player stops at five frames it
    has not posed; posed as they come, it plays the rest; the recording's clock stopped while
    it held, so the stamps keep their recorded 30 Hz spacing, and it says how long it held."""
    seq = _seven_scenes_fixture(tmp_path / "seq", frames=40, corrupt=39)
    colour: list[Image] = []
    posing = {"on": False}
    poses = ros.node.create_publisher(PoseStamped, topics.DEVICE_POSE, qos.PROTOCOL)

    def pose(msg: Image) -> None:
        reply = PoseStamped()
        reply.header = msg.header
        reply.pose.orientation.w = 1.0
        poses.publish(reply)

    def camera(msg: Image) -> None:
        colour.append(msg)
        if posing["on"]:
            pose(msg)

    ros.node.create_subscription(Image, topics.CAMERA_IMAGE, camera, qos.CAMERA)
    player = _play(domain, f"sequence:={seq}", "pace_frames:=5")
    assert ros.spin_until(lambda: len(colour) >= 5, 60.0), domain.log(player)[-2000:]
    # 30 frames' time at 30 Hz: unpaced, it would have published them all
    ros.spin_until(lambda: len(colour) > 5, 1.0)
    assert len(colour) == 5, "the player went on without the device's poses"
    posing["on"] = True
    for msg in colour:                       # the device catches up
        pose(msg)
    assert ros.spin_until(lambda: player.poll() is not None, 60.0), domain.log(player)[-2000:]
    code, _, err = domain.stop(player)
    assert code == 0, err
    assert len(colour) == 39
    gaps = np.diff([_stamp(m) for m in colour])
    np.testing.assert_allclose(gaps, 1 / 30, atol=1e-6)     # no hold in the stamps
    held = float(err.split(" s of it held for the device")[0].rsplit(" ", 1)[-1])
    assert held >= 1.0, err


def test_the_paced_cameras_of_a_group_wait_together_for_the_slowest_device(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession) -> None:
    """Two cameras of one ``pace_group`` (a fleet's, in namespaces of their own): /ar2's
    device poses nothing for a while, and /ar1's camera — its device posing every frame at
    once — stops with /ar2's instead of walking on alone; once /ar2's device catches up both
    go on, having held the same time, their stamps at the recorded 30 Hz."""
    frames = 150                          # 5 s at 30 Hz: far longer than the players' starts
    seq = _seven_scenes_fixture(tmp_path / "seq", frames=frames, corrupt=frames - 1)
    colour: dict[str, list[Image]] = {"ar1": [], "ar2": []}
    poses = {d: ros.node.create_publisher(PoseStamped, f"/{d}/{topics.DEVICE_POSE}",
                                          qos.PROTOCOL) for d in colour}
    posing = {"ar1": True, "ar2": False}

    def pose(device: str, msg: Image) -> None:
        reply = PoseStamped()
        reply.header = msg.header
        reply.pose.orientation.w = 1.0
        poses[device].publish(reply)

    def camera(device: str, msg: Image) -> None:
        colour[device].append(msg)
        if posing[device]:
            pose(device, msg)

    players = {}
    for d in colour:
        ros.node.create_subscription(Image, f"/{d}/{topics.CAMERA_IMAGE}",
                                     lambda msg, d=d: camera(d, msg), qos.CAMERA)
        players[d] = domain.spawn(
            ["-m", "twinslam.sequence_player.node", "--ros-args", "-r", f"__ns:=/{d}",
             "-p", "wait_for_subscribers:=1", "-p", f"sequence:={seq}",
             "-p", "pace_frames:=5", "-p", "pace_group:=room"], forks=FORKS)
    assert ros.spin_until(lambda: len(colour["ar2"]) >= 5, 60.0), domain.log(players["ar2"])
    # /ar1's camera stops too: a second without a frame of it, long before its walk's end
    # (alone it plays on at 30 Hz to its last frame)
    deadline = time.monotonic() + 30.0
    while True:
        stopped = len(colour["ar1"])
        if not ros.spin_until(lambda n=stopped: len(colour["ar1"]) > n, 1.0):
            break
        assert time.monotonic() < deadline, "/ar1's camera never stopped for a second"
    assert len(colour["ar2"]) == 5, "the camera went on without its device's poses"
    assert stopped < frames - 1 - 30, f"/ar1's camera walked on alone ({stopped} frames)"
    posing["ar2"] = True
    for msg in list(colour["ar2"]):                 # the device catches up
        pose("ar2", msg)
    held = {}
    for d, player in players.items():
        assert ros.spin_until(lambda p=player: p.poll() is not None, 60.0), domain.log(player)
        code, _, err = domain.stop(player)
        assert code == 0, err
        assert len(colour[d]) == frames - 1
        np.testing.assert_allclose(np.diff([_stamp(m) for m in colour[d]]), 1 / 30, atol=1e-6)
        held[d] = float(err.split(" s of it held for the device and its group room")[0]
                        .rsplit(" ", 1)[-1])
    # held alike to the frame; /ar2 held a second at least (the test's own wait)
    assert held["ar2"] >= 1.0 and held["ar1"] == pytest.approx(held["ar2"], abs=0.05), held


def test_settings_a_player_cannot_play_are_refused_at_start_with_the_reason(
        domain: LoopbackDomain) -> None:
    """``pace_group`` needs ``pace_frames`` (a camera that does not wait has no held time to
    share), and names a topic token; a ``phase`` is one of ``every``'s: each refused with its
    reason, exit 2."""
    for params, reason in ((["pace_group:=room"], "needs pace_frames"),
                           (["pace_frames:=5", "pace_group:=two rooms"], "a topic name's token"),
                           (["every:=2", "phase:=2"], "phase from 0 to every - 1")):
        player = _play(domain, *params)
        player.wait(timeout=60)
        code, _, err = domain.stop(player)
        assert code == 2 and reason in err, err[-2000:]
