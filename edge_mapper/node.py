"""edge_mapper: the edge's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``/device/frame_summaries`` (``FrameSummaries``) → the policy's U_k and C_k on
  ``/edge/upload_request`` (``UploadRequest``);
* ``/device/keyframes`` (``Keyframe``) → integrated when the slot's plan asked for them; once
  every requested keyframe is in (or ``slot_timeout_s`` passed), C_k is evicted, the newest
  keyframes are bundle-adjusted (GTSAM), the map is checkpointed, and the new map goes out on
  ``/edge/map_update`` (``MapUpdate``, latched: a device that joins or restarts gets the latest)
  with ``/edge/map_stats`` (``MapStats``: u(G), υ, lost share, uploads, timings).

A policy driven by the user digital twin (``policy:=mbrl`` with a twin checkpoint) takes its
latent features from ``/udt/rate_latent`` (:mod:`edge_mapper.twin_feed`); a slot with no latent
at most ``latent_max_age`` slots old is decided by ``fallback_policy``, and the node logs when
it falls back and when the twin's latents flow again. Each ``UploadRequest`` and ``MapStats``
names the policy that decided its slot.

With ``checkpoint`` set the node resumes from that file after a restart. A keyframe that fails
decoding or validation is dropped with a logged error by the runtime; an unrequested or repeated
one is logged and ignored; the run goes on. The work itself is
:class:`~edge_mapper.edge_core.EdgeMapperCore`'s; this file only moves messages.
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

import numpy as np

import node_runtime
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, SlotOutcome
from edge_mapper.messages import (
    map_stats_message,
    map_update_message,
    read_keyframe,
    upload_request_message,
)
from edge_mapper.policies import make_policy
from edge_mapper.slot_planner import FrameSet, SlotConfig
from edge_mapper.twin_feed import TwinFedPolicy
from edge_mapper.uncertainty import SlotUncertainty
from node_runtime import PROTOCOL

PARAMETERS = {"policy": "adapt", "policy_checkpoint": "", "vmax": 45, "alpha_mbit": 5.0,
              "d_req_s": 0.5, "checkpoint": "", "states": 2, "ba_window": 5, "slot_timeout_s": 10.0,
              "image_width": 640, "image_height": 480, "fallback_policy": "adapt",
              "latent_max_age": 2}


class EdgeMapperNode:
    def __init__(self, node: node_runtime.Node) -> None:
        self.node = node
        p = {k: node.get_parameter(k).value for k in PARAMETERS}
        self.policy_name = str(p["policy"])
        if self.policy_name == "mbrl" and p["policy_checkpoint"]:
            # ROS style: policy:=mbrl policy_checkpoint:=PATH (or policy:=mbrl:PATH)
            self.policy_name = f"mbrl:{p['policy_checkpoint']}"
        config = EdgeConfig(slot=SlotConfig(vmax=int(p["vmax"]), alpha_mbit=float(p["alpha_mbit"]),
                                            d_req_s=float(p["d_req_s"])),
                            ba_window=int(p["ba_window"]),
                            image_shape=(int(p["image_height"]), int(p["image_width"])))
        policy = make_policy(self.policy_name)
        EdgeMapperCore.warm_up(policy)
        #: the twin node feeds a twin-driven learned policy; None for every other policy
        self.feed: TwinFedPolicy | None = None
        if getattr(policy, "uses_twin", False):
            fallback = make_policy(str(p["fallback_policy"]))
            if getattr(fallback, "uses_twin", False):
                raise ValueError("fallback_policy must not need the twin itself")
            EdgeMapperCore.warm_up(fallback)
            policy = self.feed = TwinFedPolicy(policy, fallback, int(p["latent_max_age"]))
        self._decided_by = self.policy_name
        self.core = EdgeMapperCore(policy, None, config, p["checkpoint"] or None,
                                   int(p["states"]))
        self.timeout = float(p["slot_timeout_s"])
        #: slot → keyframes the device says it sent (its UplinkThroughput), while open
        self._sent: dict[int, int] = {}
        #: slot → (opened at, compute seconds so far, υ of its frames, policy that decided)
        self._opened: dict[int, tuple[float, float, SlotUncertainty | None, str]] = {}
        self.pub_request = node.create_publisher("twinslam_msgs/msg/UploadRequest",
                                                 "/edge/upload_request", PROTOCOL)
        self.pub_map = node.create_publisher("twinslam_msgs/msg/MapUpdate", "/edge/map_update",
                                             node_runtime.LATCHED)
        self.pub_stats = node.create_publisher("twinslam_msgs/msg/MapStats", "/edge/map_stats",
                                               PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/FrameSummaries", "/device/frame_summaries",
                                 self._on_summaries, PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/Keyframe", "/device/keyframes",
                                 self._on_keyframe, PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/UplinkThroughput",
                                 "/device/uplink_throughput", self._on_throughput, PROTOCOL)
        node.create_subscription("twinslam_msgs/msg/RateLatent", "/udt/rate_latent",
                                 self._on_latent, PROTOCOL)
        node.create_timer(0.2, self._check_timeouts)
        log = node.get_logger()
        if self.core.restored:
            log.info(f"restored map version {self.core.version} (slot {self.core.last_slot}, "
                     f"{len(self.core.map.keyframes)} keyframes, {len(self.core.map.points)} "
                     f"points) from {self.core.checkpoint}")
            self.pub_map.publish(map_update_message(self.core.map, self.core.last_slot,
                                                    self.core.version, time.time()))

    def _on_summaries(self, msg: Any) -> None:
        slot = int(msg.slot)
        frames = [FrameSet(int(f.frame_id), frozenset(int(i) for i in f.map_point_ids),
                           frozenset(int(i) for i in f.local_track_ids)) for f in msg.frames]
        started = time.perf_counter()
        try:
            plan = self.core.plan(slot, frames, float(msg.rate_mbps), int(msg.rate_state))
        except ValueError as exc:
            self.node.get_logger().error(f"slot {slot}: cannot plan: {exc}")
            return
        decided_by = self._note_decider(slot)
        self.pub_request.publish(upload_request_message(slot, decided_by,
                                                        float(msg.rate_mbps), plan.action,
                                                        time.time()))
        self._opened[slot] = (time.monotonic(), time.perf_counter() - started,
                              plan.uncertainty, decided_by)
        if not plan.action.upload:
            self._finish(slot)

    def _on_latent(self, msg: Any) -> None:
        if self.feed is None:
            return
        try:
            self.feed.offer(int(msg.slot), np.asarray(msg.mu), np.asarray(msg.sigma),
                            int(msg.model_version))
        except ValueError as exc:
            self.node.get_logger().error(f"rate latent of slot {msg.slot} refused: {exc}")

    def _note_decider(self, slot: int) -> str:
        """Which policy decided ``slot``; a change between the learned one and the fallback
        is logged."""
        if self.feed is None:
            return self.policy_name
        used = self.policy_name if self.feed.used == self.feed.name \
            else f"{self.feed.fallback_name} (fallback)"
        if used != self._decided_by:
            log = self.node.get_logger()
            latent = self.feed.latent
            if used == self.policy_name and latent is not None:
                log.info(f"slot {slot}: rate latents from the twin again (slot {latent.slot}, "
                         f"model version {latent.model_version}); {self.feed.name} decides")
            else:
                last = f"slot {latent.slot}" if latent is not None else "none yet"
                log.warning(f"slot {slot}: no rate latent from the twin within "
                            f"{self.feed.max_age} slots (last: {last}); deciding with the "
                            f"fallback policy {self.feed.fallback_name}")
            self._decided_by = used
        return used

    def _on_keyframe(self, msg: Any) -> None:
        started = time.perf_counter()
        data = read_keyframe(msg)
        report = self.core.add_keyframe(data)
        if data.slot in self._opened:
            opened, spent, upsilon, by = self._opened[data.slot]
            self._opened[data.slot] = (opened, spent + time.perf_counter() - started, upsilon,
                                       by)
        if report is None:
            self.node.get_logger().warning(
                f"keyframe {data.frame_id} of slot {data.slot} was not asked for (or came "
                "twice): ignored")
            return
        self._finish_if_complete(data.slot)

    def _on_throughput(self, msg: Any) -> None:
        """The device's account of a slot: once what it sent is in, nothing more will come
        (a frame it no longer held, after a link outage, is not waited for)."""
        slot = int(msg.slot)
        if slot in self.core.pending:
            self._sent[slot] = int(msg.frames_sent)
            self._finish_if_complete(slot)

    def _finish_if_complete(self, slot: int) -> None:
        action, received = self.core.pending[slot]
        if set(action.upload) <= received:
            self._finish(slot)
        elif slot in self._sent and len(received) >= self._sent[slot]:
            self.node.get_logger().warning(
                f"slot {slot}: the device sent {self._sent[slot]} of {len(action.upload)} "
                "requested keyframes (the rest were no longer held); finishing without them")
            self._finish(slot)

    def _check_timeouts(self) -> None:
        now = time.monotonic()
        for slot, (opened, *_) in list(self._opened.items()):
            if now - opened > self.timeout and slot in self.core.pending:
                action, received = self.core.pending[slot]
                self.node.get_logger().warning(
                    f"slot {slot}: {len(set(action.upload) - received)} requested keyframe(s) "
                    f"did not arrive within {self.timeout:g} s; finishing without them")
                self._finish(slot)

    def _finish(self, slot: int) -> None:
        started = time.perf_counter()
        _, spent, upsilon, decided_by = self._opened.pop(slot, (0.0, 0.0, None,
                                                                self.policy_name))
        self._sent.pop(slot, None)
        out: SlotOutcome = self.core.finish_slot(slot)
        now = time.time()
        self.pub_map.publish(map_update_message(self.core.map, slot, out.version, now,
                                                tracks=out.tracks))
        ba_ms = out.bundle_adjustment.milliseconds if out.bundle_adjustment else 0.0
        self.pub_stats.publish(map_stats_message(
            slot, decided_by, self.core.map, out.map_uncertainty,
            upsilon.mean_tracked if upsilon else math.nan,
            upsilon.lost_ratio if upsilon else 0.0, len(out.integrated), ba_ms,
            (spent + time.perf_counter() - started) * 1000, now))
        self.node.get_logger().info(
            f"slot {slot}: +{len(out.integrated)} keyframes, -{len(out.evicted)}, map "
            f"{len(self.core.map.keyframes)} keyframes / {len(self.core.map.points)} points, "
            f"u(G) {out.map_uncertainty:.1f}, BA {ba_ms:.0f} ms, version {out.version}")


def main(args: list[str] | None = None) -> int:
    node = node_runtime.start_node("edge_mapper", PARAMETERS, args)
    try:
        edge = EdgeMapperNode(node)
    except ValueError as exc:
        return node_runtime.fail(node, str(exc))
    cfg = edge.core.config.slot
    node.get_logger().info(f"policy {edge.policy_name}, V_max {cfg.vmax}, alpha {cfg.alpha_mbit} "
                           f"Mbit, D_req {cfg.d_req_s} s; listening on /device/frame_summaries")
    if edge.feed is not None:
        node.get_logger().info(f"{edge.feed.name} is fed by /udt/rate_latent; fallback policy "
                               f"{edge.feed.fallback_name} when no latent is at most "
                               f"{edge.feed.max_age} slots old")
    node_runtime.run(node)
    return 0


if __name__ == "__main__":
    sys.exit(main())
