"""A live run recorded as a rosbag2 (MCAP) a ROS user opens in Foxglove, RViz (via ros2 bag
play) or rosbags — and refused before the run when it could not be written (issue #31)."""

from __future__ import annotations

import csv
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import msg_schemas
from twinslam.cli.main import main
from twinslam.live import run_recording
from twinslam.live.run_recording import check_destination


@pytest.mark.slow
def test_launch_records_every_topic_and_the_camera_decimated_and_draws_the_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag, pictures = tmp_path / "bag", tmp_path / "pictures"
    code = main(["launch", "--sequence", "synthetic:150", "--frames", "150", "--loopback",
                 "--policy", "lff", "--record", str(bag), "--record-camera-every", "5",
                 "--out", str(pictures)])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "lff: 150 frames of synthetic:150 at 1.0x on loopback domain" in out
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
    assert counts["/device/pose"] == 150                     # every pose
    # the TF tree: the device's pose at its tracked frames, the map's anchor once, latched
    # in the bag's metadata so that `ros2 bag play` offers it to a late viewer again
    assert 0 < counts["/tf"] <= 150 and counts["/tf_static"] == 1
    assert offered["/tf_static"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert offered["/edge/map_points"][0].durability == QosDurability.TRANSIENT_LOCAL
    assert offered["/tf"][0].durability == QosDurability.VOLATILE
    anchor = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(static[0], "tf2_msgs/msg/TFMessage")
    assert [(t.header.frame_id, t.child_frame_id) for t in anchor.transforms] == [("world", "map")]
    assert counts["/camera/image_raw"] == 30                 # one in five of 150 frames
    assert counts["/camera/camera_info"] == counts["/camera/depth/image_raw"] == 30
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
    monkeypatch.setattr(run_recording.shutil, "disk_usage", lambda _path: full)
    with pytest.raises(ValueError, match="only 50 MiB free"):
        check_destination(tmp_path / "bag")
