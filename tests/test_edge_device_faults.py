"""An edge serving several devices goes on serving the others when one device's work raises:
that device is no longer served (its last checkpoint left for a standby edge), and is not
taken back in by the edge that dropped it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from twinslam_msgs.msg import FrameSummaries, Keyframe, MapUpdate, UploadRequest

from edge_mapper.node import EdgeMapperNode
from msg_schemas import qos, topics
from tests.test_edge_node import TrackIdDevice, _keyframe, _summaries
from twinslam.hosts.loopback import LoopbackDomain
from twinslam.node_runtime.session import RosSession

DEVICES = ("ar1", "ar2")


def test_a_device_whose_slot_work_fails_is_dropped_and_the_other_is_served_on(
        tmp_path: Path, domain: LoopbackDomain, ros: RosSession,
        monkeypatch: pytest.MonkeyPatch) -> None:
    edge = EdgeMapperNode(context=ros.context, parameter_overrides=[
        Parameter("devices", value=list(DEVICES)), Parameter("policy", value="lff"),
        Parameter("vmax", value=10), Parameter("d_req_s", value=0.5),
        Parameter("restore_keyframes", value=0),
        Parameter("checkpoint", value=str(tmp_path / "edge.npz"))])
    ros.executor.add_node(edge)
    try:
        def broken(*_args: Any, **_kwargs: Any) -> None:
            raise RuntimeError("a bug in ar2's map")

        monkeypatch.setattr(edge.links["ar2"].core, "finish_slot", broken)
        node = ros.node
        walks = {d: TrackIdDevice(np.random.default_rng(i)) for i, d in enumerate(DEVICES)}
        pubs = {d: (node.create_publisher(FrameSummaries, f"{d}/{topics.FRAME_SUMMARIES}",
                                          qos.PROTOCOL),
                    node.create_publisher(Keyframe, f"{d}/{topics.KEYFRAMES}", qos.PROTOCOL))
                for d in DEVICES}
        got: dict[str, dict[str, list[Any]]] = {d: {"request": [], "map": []} for d in DEVICES}
        for d in DEVICES:
            node.create_subscription(UploadRequest, f"{d}/{topics.UPLOAD_REQUEST}",
                                     got[d]["request"].append, qos.PROTOCOL)
            node.create_subscription(MapUpdate, f"{d}/{topics.MAP_UPDATE}",
                                     got[d]["map"].append, qos.MAP)
        assert ros.spin_until(lambda: all(p.get_subscription_count() > 0
                                          for pair in pubs.values() for p in pair), 30.0)

        def play(device: str, slot: int) -> bool:
            """One slot of ``device``; whether the edge asked for its uploads."""
            before = len(got[device]["request"])
            pubs[device][0].publish(_summaries(walks[device], slot, 40.0))
            if not ros.spin_until(lambda: len(got[device]["request"]) > before, 5.0):
                return False
            for frame in got[device]["request"][-1].upload_frame_ids:
                pubs[device][1].publish(_keyframe(walks[device], int(frame), slot))
            return True

        assert play("ar2", 0)                  # asked for; finishing its slot raises
        assert ros.spin_until(lambda: "ar2" not in edge.links, 10.0)
        assert edge.failed == {"ar2"} and got["ar2"]["map"] == []
        for slot in range(3):
            assert play("ar1", slot)
            assert ros.spin_until(lambda s=slot: any(m.slot == s for m in got["ar1"]["map"]),
                                  30.0), f"ar1's slot {slot} got no map"
        # no longer served here: the edge reads ar2's topics no more
        assert ros.spin_until(lambda: pubs["ar2"][0].get_subscription_count() == 0, 30.0)
        assert edge.failed == {"ar2"} and "ar2" not in edge.links
    finally:
        ros.executor.remove_node(edge)
        for link in edge.links.values():
            link.close(keep_checkpoint=True)
        edge.destroy_node()
