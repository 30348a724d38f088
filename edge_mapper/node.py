"""edge_mapper: the edge's side of the per-slot protocol as a ROS 2 node (DESIGN.md §1).

* ``device/frame_summaries`` (``FrameSummaries``) → the policy's U_k and C_k on
  ``edge/upload_request`` (``UploadRequest``);
* ``device/keyframes`` (``Keyframe``) → integrated when the slot's plan asked for them; once
  every requested keyframe is in (or ``slot_timeout_s`` passed), C_k is evicted, the newest
  keyframes are bundle-adjusted (GTSAM), the map is checkpointed, and the new map goes out on
  ``edge/map_update`` (``MapUpdate``, transient local: a device that joins or restarts gets the
  latest) with ``edge/map_stats`` (``MapStats``: u(G), υ, lost share, uploads, timings).

Topic names are relative: run a device and its edge with ``-r __ns:=/ar1`` and they talk on
``/ar1/...``, beside another pair under ``/ar2``.

A policy driven by the user digital twin (``policy:=mbrl`` with a twin checkpoint) takes its
latent features from ``udt/rate_latent`` (:mod:`edge_mapper.twin_feed`); a slot with no latent
at most ``latent_max_age`` slots old is decided by ``fallback_policy``, and the node logs when
it falls back and when the twin's latents flow again. Each ``UploadRequest`` and ``MapStats``
names the policy that decided its slot.

``policy``, ``policy_checkpoint``, ``fallback_policy``, ``latent_max_age`` and ``vmax`` change
live (``ros2 param set /edge_mapper policy lff``): a value is checked when set (an unknown
policy is refused with the reason) and takes effect at the next slot. The others are read-only.

With ``checkpoint`` set the node resumes from that file after a restart. A keyframe whose
content is inconsistent is dropped with a logged error
(:class:`~node_hosts.checked_subscription.CheckedSubscription`); an unrequested or repeated one
is logged and ignored; the run goes on. The work itself is
:class:`~edge_mapper.edge_core.EdgeMapperCore`'s; this file only moves messages.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node
from twinslam_msgs.msg import (
    FrameSummaries,
    Keyframe,
    MapStats,
    MapUpdate,
    RateLatent,
    UplinkThroughput,
    UploadRequest,
)

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
from msg_schemas import qos, topics
from node_hosts.checked_subscription import CheckedSubscription
from node_hosts.node_main import NodeStartError, run_node
from node_hosts.parameters import ParamSpec, declare


def _policy_refused(name: str) -> str | None:
    """Why ``name`` is not a policy the edge can run (None: it is)."""
    if name == "mbrl":                 # its checkpoint comes from policy_checkpoint
        return None
    try:
        make_policy(name)
    except ValueError as exc:
        return str(exc)
    return None


def _fallback_refused(name: str) -> str | None:
    reason = _policy_refused(name)
    if reason is None and name == "mbrl":
        reason = "the fallback must be a rule policy (lff, pu, adapt, ...)"
    return reason


def _checkpoint_refused(path: str) -> str | None:
    return None if not path or Path(path).is_file() else f"{path}: no such policy checkpoint"


PARAMETERS = (
    ParamSpec("policy", "adapt", "map-management policy: lff | pu | adapt | random | "
              "mbrl (with policy_checkpoint) | mbrl:CHECKPOINT", live=True,
              check=_policy_refused),
    ParamSpec("policy_checkpoint", "", "the trained policy of policy:=mbrl "
              "(`twinslam train -o FILE`)", live=True, check=_checkpoint_refused),
    ParamSpec("vmax", 45, "V_max, keyframes the edge map holds at most", low=2, high=10_000,
              live=True),
    ParamSpec("alpha_mbit", 5.0, "alpha, uplink Mbit one uploaded frame occupies", low=1e-6,
              high=1e6),
    ParamSpec("d_req_s", 0.5, "D_req, seconds a slot's uploads may take", low=1e-3, high=1e3),
    ParamSpec("checkpoint", "", "map file written every slot and resumed from after a "
              "restart; empty: none"),
    ParamSpec("states", 2, "N uplink channel states (the rate history's alphabet)", low=1,
              high=64),
    ParamSpec("ba_window", 5, "newest keyframes bundle-adjusted each slot", low=1, high=1000),
    ParamSpec("slot_timeout_s", 10.0, "finish a slot without keyframes that never came after "
              "this many seconds", low=0.1, high=3600.0),
    ParamSpec("image_width", 640, "camera image width in pixels", low=1, high=100_000),
    ParamSpec("image_height", 480, "camera image height in pixels", low=1, high=100_000),
    ParamSpec("fallback_policy", "adapt", "decides when a twin-driven policy has no fresh "
              "udt/rate_latent", live=True, check=_fallback_refused),
    ParamSpec("latent_max_age", 2, "slots a twin latent stays fresh", low=0, high=1_000_000,
              live=True),
)
LIVE = tuple(s.name for s in PARAMETERS if s.live)


class EdgeMapperNode(Node):
    def __init__(self) -> None:
        super().__init__("edge_mapper")
        p = declare(self, PARAMETERS)
        config = EdgeConfig(slot=SlotConfig(vmax=int(p["vmax"]), alpha_mbit=float(p["alpha_mbit"]),
                                            d_req_s=float(p["d_req_s"])),
                            ba_window=int(p["ba_window"]),
                            image_shape=(int(p["image_height"]), int(p["image_width"])))
        #: the twin node feeds a twin-driven learned policy; None for every other policy
        self.feed: TwinFedPolicy | None = None
        self._live = self._live_values()
        #: live values whose policy could not be made (logged once, kept until they change)
        self._refused: dict[str, Any] | None = None
        try:
            policy, self.feed = self._make_policies(self._live)
            self.core = EdgeMapperCore(policy, None, config, p["checkpoint"] or None,
                                       int(p["states"]))
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None
        self._decided_by = self.policy_name
        self.timeout = float(p["slot_timeout_s"])
        #: slot → keyframes the device says it sent (its UplinkThroughput), while open
        self._sent: dict[int, int] = {}
        #: slot → (opened at, compute seconds so far, υ of its frames, policy that decided)
        self._opened: dict[int, tuple[float, float, SlotUncertainty | None, str]] = {}
        self.pub_request = self.create_publisher(UploadRequest, topics.UPLOAD_REQUEST,
                                                 qos.PROTOCOL)
        self.pub_map = self.create_publisher(MapUpdate, topics.MAP_UPDATE, qos.MAP)
        self.pub_stats = self.create_publisher(MapStats, topics.MAP_STATS, qos.PROTOCOL)
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
        self.create_timer(0.2, self._check_timeouts)
        log = self.get_logger()
        if self.core.restored:
            log.info(f"restored map version {self.core.version} (slot {self.core.last_slot}, "
                     f"{len(self.core.map.keyframes)} keyframes, {len(self.core.map.points)} "
                     f"points) from {self.core.checkpoint}")
            self.pub_map.publish(map_update_message(self.core.map, self.core.last_slot,
                                                    self.core.version, self._now()))

    # -- parameters that change live ------------------------------------------------------

    def _live_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in LIVE}

    @staticmethod
    def _policy_name(live: dict[str, Any]) -> str:
        name = str(live["policy"])
        if name == "mbrl" and live["policy_checkpoint"]:
            # ROS style: policy:=mbrl policy_checkpoint:=PATH (or policy:=mbrl:PATH)
            name = f"mbrl:{live['policy_checkpoint']}"
        return name

    @property
    def policy_name(self) -> str:
        return self._policy_name(self._live)

    def _make_policies(self, live: dict[str, Any]) -> tuple[object, TwinFedPolicy | None]:
        """The policy the live values name, warmed up, and its twin feed: a twin-driven policy
        comes wrapped with its fallback (the wrapper is both), any other with no feed.
        ValueError when it cannot be made."""
        policy = make_policy(self._policy_name(live))
        EdgeMapperCore.warm_up(policy)
        feed = None
        if getattr(policy, "uses_twin", False):
            fallback = make_policy(str(live["fallback_policy"]))
            if getattr(fallback, "uses_twin", False):
                raise ValueError("fallback_policy must not need the twin itself")
            EdgeMapperCore.warm_up(fallback)
            policy = feed = TwinFedPolicy(policy, fallback, int(live["latent_max_age"]))
        return policy, feed

    def _apply_live_parameters(self, slot: int) -> None:
        """Parameters set since the last slot take effect now, before it is planned."""
        live = self._live_values()
        if live == self._live or live == self._refused:
            return
        log = self.get_logger()
        changed = {k: v for k, v in live.items() if self._live[k] != v}
        if changed.keys() - {"vmax"}:
            try:
                policy, feed = self._make_policies(live)
            except ValueError as exc:
                log.error(f"slot {slot}: cannot switch to {changed} ({exc}); "
                          f"{self.policy_name} goes on deciding")
                self._refused = dict(live)        # not tried again until a parameter changes
                live = {**live, **{k: self._live[k] for k in changed if k != "vmax"}}
            else:
                self.core.planner.policy, self.feed = policy, feed
        if live["vmax"] != self._live["vmax"]:
            slot_config = dataclasses.replace(self.core.config.slot, vmax=int(live["vmax"]))
            self.core.config = dataclasses.replace(self.core.config, slot=slot_config)
            self.core.planner.config = slot_config
        if live != self._live:
            self._live = live
            log.info(f"slot {slot}: parameters now {changed}; policy {self.policy_name}, "
                     f"V_max {self.core.config.slot.vmax}")

    # -- the protocol ---------------------------------------------------------------------

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_summaries(self, msg: FrameSummaries) -> None:
        slot = int(msg.slot)
        self._apply_live_parameters(slot)
        frames = [FrameSet(int(f.frame_id), frozenset(int(i) for i in f.map_point_ids),
                           frozenset(int(i) for i in f.local_track_ids)) for f in msg.frames]
        started = time.perf_counter()
        try:
            plan = self.core.plan(slot, frames, float(msg.rate_mbps), int(msg.rate_state))
        except ValueError as exc:
            self.get_logger().error(f"slot {slot}: cannot plan: {exc}")
            return
        decided_by = self._note_decider(slot)
        self.pub_request.publish(upload_request_message(slot, decided_by,
                                                        float(msg.rate_mbps), plan.action,
                                                        self._now()))
        self._opened[slot] = (time.monotonic(), time.perf_counter() - started,
                              plan.uncertainty, decided_by)
        if not plan.action.upload:
            self._finish(slot)

    def _on_latent(self, msg: RateLatent) -> None:
        if self.feed is None:
            return
        try:
            self.feed.offer(int(msg.slot), np.asarray(msg.mu), np.asarray(msg.sigma),
                            int(msg.model_version))
        except ValueError as exc:
            self.get_logger().error(f"rate latent of slot {msg.slot} refused: {exc}")

    def _note_decider(self, slot: int) -> str:
        """Which policy decided ``slot``; a change between the learned one and the fallback
        is logged."""
        if self.feed is None:
            self._decided_by = self.policy_name
            return self.policy_name
        used = self.policy_name if self.feed.used == self.feed.name \
            else f"{self.feed.fallback_name} (fallback)"
        if used != self._decided_by:
            log = self.get_logger()
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

    def _on_keyframe(self, msg: Keyframe) -> None:
        started = time.perf_counter()
        data = read_keyframe(msg)
        report = self.core.add_keyframe(data)
        if data.slot in self._opened:
            opened, spent, upsilon, by = self._opened[data.slot]
            self._opened[data.slot] = (opened, spent + time.perf_counter() - started, upsilon,
                                       by)
        if report is None:
            self.get_logger().warning(
                f"keyframe {data.frame_id} of slot {data.slot} was not asked for (or came "
                "twice): ignored")
            return
        self._finish_if_complete(data.slot)

    def _on_throughput(self, msg: UplinkThroughput) -> None:
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
            self.get_logger().warning(
                f"slot {slot}: the device sent {self._sent[slot]} of {len(action.upload)} "
                "requested keyframes (the rest were no longer held); finishing without them")
            self._finish(slot)

    def _check_timeouts(self) -> None:
        now = time.monotonic()
        for slot, (opened, *_) in list(self._opened.items()):
            if now - opened > self.timeout and slot in self.core.pending:
                action, received = self.core.pending[slot]
                self.get_logger().warning(
                    f"slot {slot}: {len(set(action.upload) - received)} requested keyframe(s) "
                    f"did not arrive within {self.timeout:g} s; finishing without them")
                self._finish(slot)

    def _finish(self, slot: int) -> None:
        started = time.perf_counter()
        _, spent, upsilon, decided_by = self._opened.pop(slot, (0.0, 0.0, None,
                                                                self.policy_name))
        self._sent.pop(slot, None)
        out: SlotOutcome = self.core.finish_slot(slot)
        now = self._now()
        self.pub_map.publish(map_update_message(self.core.map, slot, out.version, now,
                                                tracks=out.tracks))
        ba_ms = out.bundle_adjustment.milliseconds if out.bundle_adjustment else 0.0
        self.pub_stats.publish(map_stats_message(
            slot, decided_by, self.core.map, out.map_uncertainty,
            upsilon.mean_tracked if upsilon else math.nan,
            upsilon.lost_ratio if upsilon else 0.0, len(out.integrated), ba_ms,
            (spent + time.perf_counter() - started) * 1000, now))
        self.get_logger().info(
            f"slot {slot}: +{len(out.integrated)} keyframes, -{len(out.evicted)}, map "
            f"{len(self.core.map.keyframes)} keyframes / {len(self.core.map.points)} points, "
            f"u(G) {out.map_uncertainty:.1f}, BA {ba_ms:.0f} ms, version {out.version}")


def main(args: list[str] | None = None) -> int:
    def started(edge: EdgeMapperNode) -> None:
        cfg = edge.core.config.slot
        log = edge.get_logger()
        log.info(f"policy {edge.policy_name}, V_max {cfg.vmax}, alpha {cfg.alpha_mbit} Mbit, "
                 f"D_req {cfg.d_req_s} s; listening on "
                 f"{edge.resolve_topic_name(topics.FRAME_SUMMARIES)}")
        if edge.feed is not None:
            log.info(f"{edge.feed.name} is fed by {edge.resolve_topic_name(topics.RATE_LATENT)};"
                     f" fallback policy {edge.feed.fallback_name} when no latent is at most "
                     f"{edge.feed.max_age} slots old")

    return run_node("edge_mapper", EdgeMapperNode, args, started=started)


if __name__ == "__main__":
    sys.exit(main())
