"""edge_mapper: the edge's side of the per-slot protocol as a ROS 2 node (docs/architecture.md §1).

Per device (:mod:`edge_mapper.device_link`):

* ``device/frame_summaries`` → the policy's U_k and C_k on ``edge/upload_request``;
* ``device/keyframes`` → integrated when the slot's plan asked for them; when the slot closes
  (:mod:`edge_mapper.slot_lifecycle`: all in, all the device sent in, or ``slot_timeout_s``),
  C_k is evicted, the newest keyframes bundle-adjusted (GTSAM), the map checkpointed, and the
  new map goes out on ``edge/map_update`` (transient local: a device that joins or restarts
  gets the latest) with ``edge/map_stats`` (u(G), υ, lost share, uploads, V_max, timings) and,
  for a viewer, the map points, keyframes and the slot's decisions in standard messages
  (:mod:`edge_mapper.visual_messages`);
* ``udt/rate_latent`` → the twin's features for a twin-driven policy, which falls back to
  ``fallback_policy`` without fresh ones (:mod:`edge_mapper.twin_feed`).

Topic names are relative (``-r __ns:=/ar1``). By default the node serves the one device of its
own namespace. With ``devices:=[ar1, ar2]`` (or ``discover_devices:=true``, which takes in every
``DEVICE/device/frame_summaries`` publisher that appears) it serves each device's topics under
``DEVICE/`` with a map of its own, and with ``vmax_total`` the maps share one keyframe budget
split by ``allocator`` slot by slot (:mod:`edge_mapper.keyframe_budget`, published on
``edge/keyframe_budget``); a device silent for ``device_silent_s`` leaves the split, and
``device_reclaim_s`` later its map and share are released.
With ``standby:=true`` the node serves a device namespace only once its slots go unanswered
(its edge died; :mod:`edge_mapper.edge_failover`). Serving several devices, the node stops
serving one whose work raised — logged with its traceback, its last checkpoint left for a
standby edge — and goes on with the others. With ``merge_maps:=true`` a device's map
joins the frame of a device served before it once its keyframes are found in that device's
map, or that device's in its own (:mod:`edge_mapper.place_merging`): their poses are then in
one frame.

Every ``diagnostics_period_s`` the node says on ``/diagnostics`` whether it keeps up
(:mod:`edge_mapper.load_diagnostics`: slots answered and late, latency, slot work against
``compute_budget``, each named thread's share of a core).

``policy``, ``policy_checkpoint``, ``fallback_policy``, ``latent_max_age`` and ``vmax`` change
live from the next slot (:mod:`edge_mapper.policy_control`); the others are read-only
(:mod:`edge_mapper.parameters`). With ``checkpoint`` set the node resumes from that file (one
file per device) after a restart. An inconsistent keyframe is dropped with a logged error, an
unrequested or repeated one logged and ignored.
"""

from __future__ import annotations

import dataclasses
import socket
import time
from typing import Any, NoReturn

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from twinslam_msgs.msg import FrameSummaries, RateLatent, UploadRequest
from twinslam_msgs.msg import KeyframeBudget as KeyframeBudgetMsg

from edge_mapper.checkpoint_writer import CheckpointWriter
from edge_mapper.compute_governor import ComputeGovernor, levels_within
from edge_mapper.device_link import DeviceLink
from edge_mapper.edge_core import EdgeMapperCore
from edge_mapper.edge_failover import UnansweredSlots
from edge_mapper.keyframe_budget import KeyframeBudget, device_demand, slot_uploads
from edge_mapper.load_diagnostics import EdgeLoad, load_status
from edge_mapper.messages import keyframe_budget_message
from edge_mapper.parameters import DEVICE_NAME, PARAMETERS, device_names, link_settings
from edge_mapper.place_merging import PlaceMerging
from edge_mapper.policy_control import POLICY_KEYS
from edge_mapper.slot_planner import FrameObservations
from msg_schemas import qos, topics
from twinslam.allocation.allocators import BudgetError, check_budget
from twinslam.node_runtime.node_main import NodeStartError, exit_process, run_node
from twinslam.node_runtime.parameters import declare
from twinslam.node_runtime.thread_cpu import ThreadLoad
from twinslam.slam.back_end.keyframe_map import MapError
from twinslam.slam.back_end.loop_closing import SHARED_WORKER
from twinslam.slam.back_end.map_merging import lent_view
from twinslam.slam.back_end.place_words import PlaceWords

#: seconds between looks at the graph for new devices, and at the devices' silence
DISCOVERY_PERIOD_S = 1.0
SUMMARIES_SUFFIX = "/" + topics.FRAME_SUMMARIES


class EdgeMapperNode(Node):
    def __init__(self, **options: Any) -> None:
        """``options``: rclpy's node options (a ``context``, ``parameter_overrides``) for a
        node made beside others in one process; the command line's apply otherwise."""
        super().__init__("edge_mapper", **options)
        p = declare(self, PARAMETERS)
        #: the edge's load on /diagnostics each diagnostics_period_s: the slots answered since
        #: the last status ((latency, slot period) each) and the threads' CPU
        self.answered: list[tuple[float, float]] = []
        #: the loop worker's overdue looks at the last /diagnostics status (a process count)
        self._overdue_before = SHARED_WORKER.overdue
        self.threads = ThreadLoad()
        #: the checkpoints of this edge's devices written on a thread of their own
        #: (``checkpoint_in_background``), not on the slot thread every device waits for
        self.checkpoints = (CheckpointWriter() if p["checkpoint"] and
                            bool(p["checkpoint_in_background"]) else None)
        #: one vocabulary of visual words for every device's archive (``shared_vocabulary``):
        #: learned once a process, not once a device
        self.settings = dataclasses.replace(
            link_settings(p), writer=self.checkpoints,
            words=PlaceWords() if bool(p["shared_vocabulary"]) else None)
        devices = device_names(p)
        self.discover = bool(p["discover_devices"])
        self.standby = bool(p["standby"])
        self.several = bool(devices) or self.discover or self.standby
        self.takeover_slots = int(p["takeover_slots"])
        #: devices a standby edge watches, unserved: their slots and whether some edge answers
        self.watches: dict[str, tuple[UnansweredSlots, list[Any]]] = {}
        #: devices this standby edge took over from an edge that stopped answering
        self.taken_over: set[str] = set()
        self.budget: KeyframeBudget | None = None
        self.links: dict[str, DeviceLink] = {}
        self.listed = devices                  #: served from the start, again after a reclaim
        self.refused: set[str] = set()         #: devices the budget had no room for (said once)
        #: devices whose work raised: no longer served here, not even after a reclaim
        self.failed: set[str] = set()
        #: the devices' maps merged where one walks into another's place (``merge_maps``)
        self.merging = (PlaceMerging(lambda: {d: link.core for d, link in self.links.items()},
                                     min_inliers=int(p["merge_min_inliers"]),
                                     lend_in_view=bool(p["lend_in_view"]),
                                     unseen_slots=int(p["lent_unseen_slots"]),
                                     lent_views=lent_view(float(p["lent_view_m"]),
                                                          float(p["lent_view_deg"])),
                                     look_backoff_slots=int(p["merge_look_backoff_slots"]),
                                     join=bool(p["merge_join"]))
                        if self.several and bool(p["merge_maps"]) else None)
        if self.merging is not None and self.merging.join and p["checkpoint"]:
            raise NodeStartError("merge_join makes one map of a place, which no checkpoint "
                                 "holds yet: set checkpoint empty, or merge_join false (each "
                                 "map borrows the others' keyframes, checkpointed)")
        config = self.settings.config
        # the process's loop worker (every device's loop jobs), at or below the slots' priority
        SHARED_WORKER.lower_priority(int(p["loop_worker_niceness"]))
        SHARED_WORKER.limit_share(float(p["loop_worker_share"]))
        SHARED_WORKER.yield_to_slots(bool(p["loop_worker_yields"]))
        if SHARED_WORKER.share < 1:
            self.get_logger().info(f"the loop closer's worker takes at most "
                                   f"{SHARED_WORKER.share:.0%} of a core: the loops wait, "
                                   "the slots keep the rest")
        if SHARED_WORKER.niceness:
            self.get_logger().info(f"the loop closer's worker runs {SHARED_WORKER.niceness} "
                                   "nice steps below the slots: where the cores run short, "
                                   "loops wait and the slots keep their deadline")
        self.governor = ComputeGovernor(float(p["compute_budget"]),
                                        levels=levels_within(
                                            config.back_end.ba_window,
                                            config.back_end.ba_points,
                                            config.back_end.loop_closing
                                            or self.merging is not None))
        try:
            if self.several and int(p["vmax_total"]) > 0:
                self.budget = KeyframeBudget(
                    int(p["vmax_total"]), str(p["allocator"]), int(p["min_keyframes"]),
                    float(p["fairness"]), float(p["device_silent_s"]),
                    float(p["device_reclaim_s"]))
                check_budget(self.budget.total, len(devices), self.budget.minimum)
            self.pub_budget = (self.create_publisher(KeyframeBudgetMsg, topics.KEYFRAME_BUDGET,
                                                     qos.PROTOCOL)
                               if self.budget is not None else None)
            for device in devices if self.several else [""]:
                self._serve(device)
        except ValueError as exc:
            raise NodeStartError(str(exc)) from None
        if self.several:
            self.create_timer(DISCOVERY_PERIOD_S, self._look_around)
        self.create_timer(0.2, self._finish_due)     # timeouts
        self.pub_diagnostics = self.create_publisher(DiagnosticArray, topics.DIAGNOSTICS,
                                                     qos.PROTOCOL)
        if float(p["diagnostics_period_s"]) > 0:
            self.create_timer(float(p["diagnostics_period_s"]), self.publish_load)

    def publish_load(self) -> DiagnosticArray:
        """The edge's load since the last status, on /diagnostics (and returned)."""
        level = self.governor.levels[self.governor.level]
        overdue = SHARED_WORKER.overdue
        load = EdgeLoad(devices=len(self.links), answered=self.answered,
                        load=self.governor.load(time.monotonic()), budget=self.governor.budget,
                        level=level.describe() if self.governor.budget > 0 else "no budget",
                        trimmed=self.governor.level > 0,
                        threads=self.threads.cores(), worker_waiting=SHARED_WORKER.waiting(),
                        looks_overdue=overdue - self._overdue_before)
        self.answered = []
        self._overdue_before = overdue
        msg = load_status(self.get_fully_qualified_name(), socket.gethostname(), load,
                          self._now())
        self.pub_diagnostics.publish(msg)
        return msg

    def _answered(self, latency_s: float, period_s: float) -> None:
        self.answered.append((latency_s, period_s))

    def _live_values(self) -> dict[str, Any]:
        return {name: self.get_parameter(name).value for name in (*POLICY_KEYS, "vmax")}

    def _serve(self, device: str) -> None:
        """A link for ``device``, with a map of its own; it joins the budget's split when its
        first summaries come (a device that never speaks holds no share)."""
        grant = self._grant if self.budget is not None else None
        finished = self.budget.finished if self.budget is not None else None
        try:
            link = DeviceLink(self, device, self.settings, self._live_values, grant, finished,
                              self._spent, self.merging,
                              self._device_failed if self.several else None,
                              answered=self._answered)
        except MapError as exc:
            if not self.several:                 # the node's one device: it cannot start
                raise
            self._unreadable(device, exc)
            return
        level = self.governor.levels[self.governor.level]
        if self.governor.level:                # a device that joins gets today's level
            link.core.set_bundle_adjustment(level.window, level.points)
            link.core.set_loop_search(level.searches)
        self.links[device] = link
        if device:
            self.get_logger().info(f"serving device {device} (its "
                                   f"{self.resolve_topic_name(device + SUMMARIES_SUFFIX)})")
        if self.merging is not None:
            try:
                restored = self.merging.serve(device)
            except MapError as exc:             # the place its checkpoint records
                self._drop_failed(device, link)
                self._unreadable(device, exc)
                return
            if restored:
                self.get_logger().info(f"device {device}'s map restored: {restored}")

    def _unreadable(self, device: str, exc: MapError) -> None:
        """``device`` not served: its checkpoint cannot be read. One device's file must not
        keep the others unserved, nor be overwritten by a new map: the device waits until
        someone looks at it."""
        self.failed.add(device)
        self.get_logger().error(
            f"device {device}: not served, its checkpoint cannot be read ({exc}); the file is "
            "left as it is — move it aside and restart this edge to serve the device with a "
            "new map")

    def _grant(self, device: str, slot: int, frames: list[FrameObservations], rate_mbps: float,
               latent: RateLatent | None, core: EdgeMapperCore) -> int:
        """The V_max of ``device``'s ``slot`` (0, said once, when the budget has no room for
        one more device: it then uploads nothing and keeps nothing)."""
        assert self.budget is not None
        budget, now = self.budget, time.monotonic()
        if device not in budget.accounts:
            try:
                budget.join(device, now)
            except BudgetError as exc:
                if device not in self.refused:
                    self.refused.add(device)
                    self.get_logger().error(f"device {device} not served: {exc}")
                return 0
            self.refused.discard(device)
            self.get_logger().info(f"device {device} joins the keyframe budget at its slot "
                                   f"{slot}")
        demand = device_demand(device, core, frames, rate_mbps, budget.total,
                               budget.allocator == "twin",
                               list(latent.next_state_probs) if latent is not None else [],
                               list(latent.state_rates_mbps) if latent is not None else [],
                               with_novelty=budget.allocator == "motion")
        granted = budget.grant(device, slot, demand, now,
                               slot_uploads(core, rate_mbps, len(frames)))
        if self.pub_budget is not None:
            self.pub_budget.publish(keyframe_budget_message(budget, self._now()))
        return granted

    def _spent(self, seconds: float) -> None:
        """A slot's compute, against the edge's compute budget."""
        now, before = time.monotonic(), self.governor.level
        self.governor.charge(seconds, now)
        level = self.governor.step(now)
        if level is None:
            return
        for link in self.links.values():
            link.core.set_bundle_adjustment(level.window, level.points)
            link.core.set_loop_search(level.searches)
        if self.merging is not None:
            self.merging.looking = level.searches
        line = (f"compute: slot work takes {self.governor.load(now):.0%} of a core (budget "
                f"{self.governor.budget:.0%}); {level.describe()} from the next slots on")
        if self.governor.level > before:
            self.get_logger().warning(line)
        else:
            self.get_logger().info(line)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _finish_due(self) -> None:
        for device, link in list(self.links.items()):
            if link.fault:
                self._drop_failed(device, link)
            elif link.restarts.restart is not None:
                restart = link.restarts.restart
                self._serve_afresh(device, link, restart.slot, restart.newest_planned)
            else:
                link.tick()

    def _device_failed(self, device: str, trace: str) -> None:
        """One device's work raised: the edge stops serving it — its last checkpoint stays,
        for a standby edge to take it over from — and goes on with the others."""
        self.failed.add(device)
        self.get_logger().error(
            f"device {device}: its slot work failed; this edge stops serving it (its last "
            f"checkpoint stays for a standby edge, which takes it over once its slots go "
            f"unanswered) and goes on with the other devices:\n{trace.rstrip()}")

    def _drop_failed(self, device: str, link: DeviceLink) -> None:
        """A failed device's link closed (from the timer, not from inside its callback) and
        its map left out of the place's merging."""
        del self.links[device]
        try:
            link.close(keep_checkpoint=True)
        except Exception as exc:        # a half-done slot's state: closing must not fail
            self.get_logger().error(f"device {device}: closing its link failed too: {exc}")
        if self.merging is not None:
            self.merging.forget(device)

    def _set_aside(self, device: str, keep_checkpoint: bool = False) -> None:
        """``device``'s link closed, if it has one, and its map left out of the place's
        merging: its checkpoint moved aside (``FILE.reclaimed``: a reclaimed device, one that
        started again) or kept where it is (``keep_checkpoint``: a device given back to its
        own edge)."""
        link = self.links.pop(device, None)
        if link is not None:
            link.close(keep_checkpoint=keep_checkpoint)
        if self.merging is not None:
            self.merging.forget(device)

    def _serve_afresh(self, device: str, link: DeviceLink, slot: int, newest: int) -> None:
        """The device started again (its slot ``slot`` came after the edge had planned
        ``newest``): its old map set aside as a reclaimed device's (``FILE.reclaimed``, its
        merges undone) and a map of its own started for the new run, from its next slot."""
        name = f"device {device}" if device else "the device"
        checkpoint = link.core.checkpoint
        self.get_logger().warning(
            f"{name} started again: its slot {slot} came after this edge had planned slot "
            f"{newest}; its map of "
            f"{len(link.core.slice.keyframes)} keyframes is set aside"
            + (f" ({checkpoint}.reclaimed)" if checkpoint is not None else "")
            + " and it is served with a new map from its next slot")
        self._set_aside(device)
        self._serve(device)

    def _look_around(self) -> None:
        """New devices on the graph (``discover_devices``), devices a standby edge takes over
        or gives back, and the silence of known ones."""
        if self.standby:
            self._stand_by()
        elif self.discover:
            for device in self._announced():
                if device not in self.links and device not in self.failed:
                    self._serve(device)
        if self.budget is None:
            return
        for event in self.budget.sweep(time.monotonic()):
            if event.event == "silent":
                self.get_logger().warning(
                    f"device {event.device}: no frame summaries for {event.seconds:.1f} s; its "
                    f"map is kept, its share goes to the others")
            elif event.event == "active":
                self.get_logger().info(f"device {event.device}: heard again after "
                                       f"{event.seconds:.1f} s")
            else:
                self.get_logger().warning(
                    f"device {event.device}: silent for {event.seconds:.1f} s; its map and "
                    "its share of the keyframe budget are reclaimed")
                self._set_aside(event.device)
                if event.device in self.listed and event.device not in self.failed:
                    self._serve(event.device)     # listening again, with a fresh map
            if self.pub_budget is not None:
                self.pub_budget.publish(keyframe_budget_message(self.budget, self._now()))

    def _stand_by(self) -> None:
        """Watch the devices no edge of ours serves; take over those whose slots went
        unanswered ``takeover_slots`` times; give back the ones another edge answers again."""
        for device in self._announced():
            if device not in self.links and device not in self.watches and \
                    device not in self.failed:
                watch = UnansweredSlots(self.takeover_slots)

                def heard(msg: FrameSummaries, w: UnansweredSlots = watch) -> None:
                    w.summaries(int(msg.slot))

                def answered(msg: UploadRequest, w: UnansweredSlots = watch) -> None:
                    w.answered(int(msg.slot))

                subs = [self.create_subscription(FrameSummaries,
                                                 f"{device}/{topics.FRAME_SUMMARIES}", heard,
                                                 qos.PROTOCOL),
                        self.create_subscription(UploadRequest,
                                                 f"{device}/{topics.UPLOAD_REQUEST}", answered,
                                                 qos.PROTOCOL)]
                self.watches[device] = (watch, subs)
                self.get_logger().info(f"standing by for device {device}")
        for device, (watch, subs) in list(self.watches.items()):
            if not watch.due:
                continue
            for sub in subs:
                self.destroy_subscription(sub)
            del self.watches[device]
            self.get_logger().warning(
                f"device {device}: {len(watch.unanswered)} of its slots unanswered (up to "
                f"slot {watch.newest_summaries}): its edge stopped; taking it over")
            self._serve(device)
            if device in self.links:
                self.taken_over.add(device)
        for device in sorted(self.taken_over):
            topic = self.resolve_topic_name(f"{device}/{topics.UPLOAD_REQUEST}")
            if self.count_publishers(topic) <= 1:
                continue
            self.get_logger().warning(f"device {device}: another edge answers it again; "
                                      "giving it back")
            self.taken_over.discard(device)
            self._set_aside(device, keep_checkpoint=True)

    def close(self) -> None:
        """Before the node goes (``run_node`` calls it once the executor stopped): every
        device's slots finished since its last checkpoint (``checkpoint_every``)
        checkpointed, the work queued beside the slots done — the archive's poses of a loop's
        correction written, a running merge look finished — and the worker threads ended: the
        process then ends without waiting for them (:func:`~twinslam.node_runtime.node_main.
        exit_process`), and a file a worker had still to write would be lost."""
        for device, link in self.links.items():
            try:
                link.core.flush_checkpoint()
            except Exception as exc:      # one device's disk must not keep the others' back
                self.get_logger().error(f"device {device}: its last checkpoint not written: "
                                        f"{exc}")
            link.core.close()
        if self.checkpoints is not None:
            self.checkpoints.close()
        if self.merging is not None:
            self.merging.close()

    def _announced(self) -> list[str]:
        """Device namespaces under this node's that publish frame summaries now."""
        base = self.get_namespace().rstrip("/") + "/"
        found = []
        for name, _types in self.get_topic_names_and_types():
            if not (name.startswith(base) and name.endswith(SUMMARIES_SUFFIX)):
                continue
            if not self.count_publishers(name):
                continue
            device = name[len(base):-len(SUMMARIES_SUFFIX)]
            if device and DEVICE_NAME.fullmatch(device):
                found.append(device)
        return sorted(found)


def main(args: list[str] | None = None) -> NoReturn:
    def started(edge: EdgeMapperNode) -> None:
        log = edge.get_logger()
        first = next(iter(edge.links.values()), None)
        if first is not None:
            cfg = first.core.slot_config
            budget = edge.budget
            share = (f"V_total {budget.total} split {budget.allocator} (at least "
                     f"{budget.minimum} a device)" if budget is not None else f"V_max {cfg.vmax}")
            log.info(f"policy {first.control.policy_name}, {share}, alpha {cfg.alpha_mbit} "
                     f"Mbit, D_req {cfg.d_req_s} s")
        for link in edge.links.values():
            log.info(f"listening on {edge.resolve_topic_name(link.topic(topics.FRAME_SUMMARIES))}")
            feed = link.control.feed
            if feed is not None:
                log.info(f"{feed.name} is fed by "
                         f"{edge.resolve_topic_name(link.topic(topics.RATE_LATENT))}; fallback "
                         f"policy {feed.fallback_name} when no latent is at most "
                         f"{feed.max_age} slots old")
        if edge.discover:
            log.info("serving every device namespace that publishes "
                     f"{edge.resolve_topic_name('DEVICE' + SUMMARIES_SUFFIX)}")

    exit_process(run_node("edge_mapper", EdgeMapperNode, args, started=started, long_lived=True))


if __name__ == "__main__":
    main()
