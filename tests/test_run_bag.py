"""A live run recorded as a rosbag2 (MCAP) a ROS user opens in Foxglove, RViz (via ros2 bag
play) or rosbags, its camera compressed where a user asks — and refused before the run when
it could not be written."""

from __future__ import annotations

import csv
import os
import shutil
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from sensor_msgs.msg import Image

import msg_schemas
from msg_schemas import qos, topics
from twinslam.cli.main import main
from twinslam.live import run_bag
from twinslam.live.run_bag import RecordingOptions, RunRecorder, check_destination
from twinslam.node_runtime.session import RosSession
from twinslam.sequence_player.messages import color_message, depth_message
from twinslam.sequences.synthetic import SyntheticSequence


@pytest.mark.slow
def test_launch_records_every_topic_and_the_camera_decimated_and_draws_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, pictures = tmp_path / "bag", tmp_path / "pictures"
    code = main(["launch", "--sequence", "synthetic:90", "--frames", "90", "--loopback",
                 "--policy", "lff", "--record", str(bag), "--record-camera-every", "5",
                 "--out", str(pictures)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "lff: 90 frames of synthetic:90 at 1.0x on loopback domain" in out
    assert "MB a minute of run" in out
    with Reader(bag) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        offered = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        stats = [raw for c, _, raw in reader.messages()
                 if c.topic == "/edge/map_stats"]
        static = [raw for c, _, raw in reader.messages() if c.topic == "/tf_static"]
    for topic in ("/device/frame_summaries", "/device/keyframes", "/edge/upload_request",
                  "/edge/map_stats",
                  "/edge/map_update", "/edge/map_points", "/edge/keyframes", "/edge/decisions",
                  "/device/pose", "/device/path", "/camera/ground_truth_path"):
        assert counts[topic] > 0, topic
    assert counts["/device/pose"] == 90                      # every pose
    # the TF tree: the device's pose at its tracked frames, the map's anchor once, latched
    # in the bag's metadata so that `ros2 bag play` offers it to a late viewer again
    assert 0 < counts["/tf"] <= 90 and counts["/tf_static"] == 1
    assert offered["/tf_static"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert offered["/edge/map_points"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert offered["/tf"][0].durability == QosDurability.VOLATILE
    anchor = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(static[0], "tf2_msgs/msg/TFMessage")
    assert [(t.header.frame_id, t.child_frame_id) for t in anchor.transforms] == [("world", "map")]
    assert counts["/camera/image_raw"] == 18                 # one in five of 90 frames
    assert counts["/camera/camera_info"] == counts["/camera/depth/image_raw"] == 18
    # a reader without twinslam decodes its own messages from the .msg definitions
    store = get_typestore(Stores.ROS2_JAZZY)
    msg_dir = Path(msg_schemas.__file__).parent / "msg"
    for path in msg_dir.glob("*.msg"):
        store.register(get_types_from_msg(path.read_text(), f"twinslam_msgs/msg/{path.stem}"))
    last = store.deserialize_cdr(stats[-1], "twinslam_msgs/msg/MapStats")
    assert last.map_size > 0 and np.isfinite(last.uncertainty)
    assert (pictures / "lff.png").stat().st_size > 30_000
    with (pictures / "lff.slots.csv").open() as fh:       # the run slot by slot
        slots = list(csv.DictReader(fh))
    assert len(slots) >= 2 and {s["policy"] for s in slots} == {"lff"}
    logs = (pictures / "lff.log").read_text(encoding="utf-8")   # every node's, kept
    assert "===== edge_mapper =====" in logs and "===== device_tracker =====" in logs
    same = next(s for s in slots if int(s["slot"]) == last.slot)   # as the bag has it
    assert int(same["map_size"]) == last.map_size and int(same["uploads"]) == last.uploads


def test_a_recording_that_cannot_be_written_is_refused_before_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "taken").mkdir()
    with pytest.raises(ValueError, match="exists"):
        check_destination(tmp_path / "taken")
    with pytest.raises(ValueError, match="does not exist"):
        check_destination(tmp_path / "no" / "such" / "bag")
    if os.geteuid() != 0:                       # root writes anywhere: nothing to refuse
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        with pytest.raises(ValueError, match="not writable"):
            check_destination(locked / "bag")
        locked.chmod(0o700)
    code = main(["launch", "--sequence", "synthetic:30", "--loopback", "--record",
                 str(tmp_path / "taken")])
    assert code == 2 and "exists" in capsys.readouterr().err
    full = shutil.disk_usage(tmp_path)._replace(free=50 * 2**20)
    monkeypatch.setattr(run_bag.shutil, "disk_usage", lambda _path: full)
    with pytest.raises(ValueError, match="only 50 MiB free"):
        check_destination(tmp_path / "bag")


def test_camera_images_recorded_compressed_decode_back_to_what_was_published(
        ros: RosSession, tmp_path: Path) -> None:
    """``--record-images compressed``: colour as JPEG (close to the published image), 16-bit
    depth as PNG (exactly it), on image_transport's .../compressed topics, in zstd chunks that
    the bag's reader opens; 32FC1 depth, which the compressed transport cannot carry, stays
    raw on the raw topic; the bag is smaller than the raw recording of the same images."""
    frame = SyntheticSequence(1, seed=0).read(0)
    published = [color_message(frame, 1.0, "camera"), depth_message(frame, 1.0, "camera"),
                 depth_message(frame, 1.0, "camera", "32FC1")]
    sizes = {}
    for images in ("raw", "compressed"):
        bag = tmp_path / images
        recorder = RunRecorder(ros.node, bag, RecordingOptions(1, images, "zstd"))
        color = ros.node.create_publisher(Image, topics.CAMERA_IMAGE, qos.CAMERA)
        depth = ros.node.create_publisher(Image, topics.CAMERA_DEPTH, qos.CAMERA)
        for msg, pub in zip(published, (color, depth, depth), strict=True):
            # the camera's topics are volatile: sent again until the recorder heard it
            before, deadline = recorder.messages, time.monotonic() + 20.0
            while recorder.messages == before and time.monotonic() < deadline:
                pub.publish(msg)
                ros.spin_until(lambda r=recorder, b=before: r.messages > b, 0.2)
            assert recorder.messages > before, f"{images}: {msg.encoding} never recorded"
        summary = recorder.close()
        sizes[images] = summary.bytes
        ros.node.destroy_publisher(color)
        ros.node.destroy_publisher(depth)
    with Reader(tmp_path / "compressed") as reader:
        got = {c.topic: c.msgtype for c in reader.connections if c.msgcount}
        raws = {c.topic: raw for c, _, raw in reader.messages()}
    assert got == {"/camera/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
                   "/camera/depth/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
                   "/camera/depth/image_raw": "sensor_msgs/msg/Image"}
    store = get_typestore(Stores.ROS2_JAZZY)
    jpeg = store.deserialize_cdr(raws["/camera/image_raw/compressed"],
                                 "sensor_msgs/msg/CompressedImage")
    png = store.deserialize_cdr(raws["/camera/depth/image_raw/compressed"],
                                "sensor_msgs/msg/CompressedImage")
    assert jpeg.format == "rgb8; jpeg compressed bgr8" and png.format == "16UC1; png compressed"
    rgb = cv2.cvtColor(cv2.imdecode(jpeg.data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
    assert np.abs(rgb.astype(int) - frame.color.astype(int)).mean() < 8
    mm = cv2.imdecode(png.data, cv2.IMREAD_UNCHANGED)
    assert mm.dtype == np.uint16
    np.testing.assert_array_equal(mm, np.frombuffer(bytes(published[1].data), np.uint16)
                                  .reshape(mm.shape))
    raw_bytes = len(published[0].data) + len(published[1].data)
    assert len(jpeg.data) + len(png.data) < 0.35 * raw_bytes
    assert sizes["compressed"] < sizes["raw"]
