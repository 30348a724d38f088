"""edge_mapper: the edge's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``device/frame_summaries`` → the policy's U_k and C_k on ``edge/upload_request``;
* ``device/keyframes`` → integrated when the slot's plan asked for them; when the slot closes
  (:mod:`edge_mapper.slot_lifecycle`: all in, all the device sent in, or ``slot_timeout_s``),
  C_k is evicted, the newest keyframes bundle-adjusted (GTSAM), the map checkpointed, and the
  new map goes out on ``edge/map_update`` (transient local: a device that joins or restarts
  gets the latest) with ``edge/map_stats`` (u(G), υ, lost share, uploads, timings) and, for a
  viewer, the map points, keyframes and the slot's decisions in standard messages
  (:mod:`edge_mapper.visual_messages`);
* ``udt/rate_latent`` → the twin's features for a twin-driven policy, which falls back to
  ``fallback_policy`` without fresh ones (:mod:`edge_mapper.twin_feed`).

Topic names are relative (``-r __ns:=/ar1``). ``policy``, ``policy_checkpoint``,
``fallback_policy``, ``latent_max_age`` and ``vmax`` change live from the next slot
(:mod:`edge_mapper.policy_control`); the others are read-only (:mod:`edge_mapper.parameters`).
With ``checkpoint`` set the node resumes from that file after a restart. An inconsistent
keyframe is dropped with a logged error, an unrequested or repeated one logged and ignored.
The work is :class:`~edge_mapper.edge_core.EdgeMapperCore`'s; this file only moves messages.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    MapUpdate,
    RateLatent,
    UplinkThroughput,
    UploadRequest,
)
from visualization_msgs.msg import MarkerArray

from edge_mapper.edge_core import EdgeMapperCore, SlotOutcome
from edge_mapper.messages import map_stats_message, map_update_message, upload_request_message
from edge_mapper.parameters import PARAMETERS, edge_config
from edge_mapper.policy_control import POLICY_KEYS, Note, PolicyControl
from edge_mapper.slot_lifecycle import Closing, SlotLifecycle
from edge_mapper.slot_planner import FrameObservations
from edge_mapper.visual_messages import decisions_message, keyframes_message, map_points_message
from msg_schemas import qos, topics
from twinslam.node_hosts.checked_subscription import CheckedSubscription
from twinslam.node_hosts.node_main import NodeStartError, run_node
from twinslam.node_hosts.parameters import declare
from twinslam.slam.keyframe import read_keyframe


class EdgeMapperNode(Node):
    def __init__(self) -> None:
        super().__init__("edge_mapper")
        p = declare(self, PARAMETERS)
        try:
            self.control = PolicyControl(self._live_values(), EdgeMapperCore.warm_up)
            self.core = EdgeMapperCore(self.control.policy, None, edge_config(p),
                                       p["checkpoint"] or None, int(p["states"]))
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None
        self.slots = SlotLifecycle(float(p["slot_timeout_s"]))
        self.map_frame = str(p["map_frame"])
        self.pub_request = self.create_publisher(UploadRequest, topics.UPLOAD_REQUEST,
                                                 qos.PROTOCOL)
        self.pub_map = self.create_publisher(MapUpdate, topics.MAP_UPDATE, qos.MAP)
        self.pub_stats = self.create_publisher(MapStats, topics.MAP_STATS, qos.PROTOCOL)
        self.pub_views = ((self.create_publisher(PointCloud2, topics.MAP_POINTS, qos.MAP),
                           self.create_publisher(PoseArray, topics.KEYFRAME_POSES, qos.MAP),
                           self.create_publisher(MarkerArray, topics.DECISIONS, qos.MAP))
                          if p["visualisation"] else None)
        self.subscriptions_checked = [
            CheckedSubscription(self, FrameSummaries, topics.FRAME_SUMMARIES,
                                self._on_summaries, qos.PROTOCOL),
            CheckedSubscription(self, Keyframe, topics.KEYFRAMES, self._on_keyframe,
                                qos.PROTOCOL),
            CheckedSubscription(self, UplinkThroughput, topics.UPLINK_THROUGHPUT,
                                self._on_throughput, qos.PROTOCOL),
            CheckedSubscription(self, RateLatent, topics.RATE_LATENT, self._on_latent,
                                qos.PROTOCOL),
        ]
        self.create_timer(0.2, self._finish_due)     # timeouts
        if self.core.restored:
            self.get_logger().info(self.core.restored_summary())
            # with the whole track table: the device may still hold tracks of before the stop
            self.pub_map.publish(map_update_message(self.core.map, self.core.last_slot,
                                                    self.core.version, self._now(),
                                                    self.map_frame,
                                                    tracks=self.core.local_mapping.track_points))

    def _live_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in POLICY_KEYS}

    def _log(self, notes: list[Note]) -> None:
        # one call site per severity: rclpy refuses a logging line whose severity changes
        log = self.get_logger()
        for note in notes:
            if note.level == "error":
                log.error(note.text)
            elif note.level == "warning":
                log.warning(note.text)
            else:
                log.info(note.text)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_summaries(self, msg: FrameSummaries) -> None:
        slot = int(msg.slot)
        self._log(self.control.apply(self._live_values(), slot))  # set since the last slot
        self.core.set_policy(self.control.policy)
        vmax = int(self.get_parameter("vmax").value)
        if vmax != self.core.slot_config.vmax:
            self.get_logger().info(f"slot {slot}: V_max {vmax} from this slot on (was "
                                   f"{self.core.slot_config.vmax})")
            self.core.set_vmax(vmax)
        frames = [FrameObservations(int(f.frame_id), frozenset(int(i) for i in f.map_point_ids),
                                    frozenset(int(i) for i in f.local_track_ids),
                                    bool(f.tracked))
                  for f in msg.frames]
        started = time.perf_counter()
        try:
            plan = self.core.plan(slot, frames, float(msg.rate_mbps), int(msg.rate_state))
        except ValueError as exc:
            self.get_logger().error(f"slot {slot}: cannot plan: {exc}")
            return
        decided_by, notes = self.control.decided(slot)
        self._log(notes)
        self.pub_request.publish(upload_request_message(slot, decided_by,
                                                        float(msg.rate_mbps), plan.action,
                                                        self._now()))
        self.slots.open(slot, time.perf_counter() - started, plan.uncertainty, decided_by)
        self._finish_due()                       # a slot that uploads nothing is due at once

    def _on_latent(self, msg: RateLatent) -> None:
        if self.control.feed is None:
            return
        try:
            self.control.feed.offer(int(msg.slot), np.asarray(msg.mu), np.asarray(msg.sigma),
                                    int(msg.model_version))
        except ValueError as exc:
            self.get_logger().error(f"rate latent of slot {msg.slot} refused: {exc}")

    def _on_keyframe(self, msg: Keyframe) -> None:
        started = time.perf_counter()
        data = read_keyframe(msg)
        report = self.core.add_keyframe(data)
        self.slots.charge(data.slot, time.perf_counter() - started)
        if report is None:
            self.get_logger().warning(
                f"keyframe {data.frame_id} of slot {data.slot} was not asked for, came twice "
                "or after its slot closed: ignored")
            return
        self._finish_due()

    def _on_throughput(self, msg: UplinkThroughput) -> None:
        """The device's account of a slot: once what it sent is in, nothing more will come."""
        slot = int(msg.slot)
        if slot in self.core.pending:
            self.slots.device_sent(slot, int(msg.frames_sent))
            self._finish_due()

    def _finish_due(self) -> None:
        """Finish open slots, oldest first, while the oldest is due (slots finish in order so
        that no map the edge publishes holds more than V_max keyframes)."""
        while (slot := self.core.oldest_open) is not None:
            action, received = self.core.pending[slot]
            closing = self.slots.closing(slot, action.upload, received)
            if closing is None:
                return
            if closing is Closing.SHORT:
                self.get_logger().warning(
                    f"slot {slot}: the device sent {self.slots.open_slots[slot].sent} of "
                    f"{len(action.upload)} requested keyframes (the rest were no longer "
                    "held); finishing without them")
            elif closing is Closing.TIMEOUT:
                self.get_logger().warning(
                    f"slot {slot}: {len(set(action.upload) - received)} requested keyframe(s) "
                    f"did not arrive within {self.slots.timeout_s:g} s; finishing without them")
            self._finish(slot)
            started = time.perf_counter()
            if self.core.integrate_held() and self.core.oldest_open is not None:
                self.slots.charge(self.core.oldest_open, time.perf_counter() - started)

    def _finish(self, slot: int) -> None:
        started = time.perf_counter()
        entry = self.slots.close(slot, self.control.policy_name)
        before = ({k: kf.pose for k, kf in self.core.map.keyframes.items()}  # evicted: where
                  if self.pub_views is not None else {})
        out: SlotOutcome = self.core.finish_slot(slot)
        now = self._now()
        self.pub_map.publish(map_update_message(self.core.map, slot, out.version, now,
                                                self.map_frame, tracks=out.tracks))
        ba_ms = out.bundle_adjustment.milliseconds if out.bundle_adjustment else 0.0
        self.pub_stats.publish(map_stats_message(
            slot, entry.decided_by, self.core.map, out.map_uncertainty, entry.uncertainty,
            len(out.integrated), ba_ms,
            (entry.compute_s + time.perf_counter() - started) * 1000, now))
        if self.pub_views is not None:         # after MapStats: not in its compute time
            m, (cloud, poses, marks) = self.core.map, self.pub_views
            cloud.publish(map_points_message(m, now, self.map_frame))
            poses.publish(keyframes_message(m, now, self.map_frame))
            marks.publish(decisions_message(m, out.integrated, out.evicted, before, now,
                                            self.map_frame))
        self.get_logger().info(
            f"slot {slot}: +{len(out.integrated)} keyframes, -{len(out.evicted)}, map "
            f"{len(self.core.map.keyframes)} keyframes / {len(self.core.map.points)} points, "
            f"u(G) {out.map_uncertainty:.1f}, BA {ba_ms:.0f} ms, version {out.version}")


def main(args: list[str] | None = None) -> int:
    def started(edge: EdgeMapperNode) -> None:
        cfg = edge.core.slot_config
        log = edge.get_logger()
        log.info(f"policy {edge.control.policy_name}, V_max {cfg.vmax}, alpha {cfg.alpha_mbit} "
                 f"Mbit, D_req {cfg.d_req_s} s; listening on "
                 f"{edge.resolve_topic_name(topics.FRAME_SUMMARIES)}")
        feed = edge.control.feed
        if feed is not None:
            log.info(f"{feed.name} is fed by {edge.resolve_topic_name(topics.RATE_LATENT)}; "
                     f"fallback policy {feed.fallback_name} when no latent is at most "
                     f"{feed.max_age} slots old")

    return run_node("edge_mapper", EdgeMapperNode, args, started=started)


if __name__ == "__main__":
    sys.exit(main())
