"""One device's topics on the edge node: its protocol in, its map and decisions out
(docs/architecture.md §1 steps 3, 5, 6). The edge node holds one link when it serves the device of
its own namespace, and one per device namespace when it serves several; the work is
the link's :class:`~edge_mapper.edge_core.EdgeMapperCore`'s, the link only moves messages.

* ``<device>/device/frame_summaries`` → the policy's U_k and C_k on
  ``<device>/edge/upload_request``, planned with the V_max the edge's keyframe budget grants
  this device for this slot (:mod:`edge_mapper.keyframe_budget`), or the node's ``vmax``;
* ``<device>/device/keyframes`` → integrated when the slot's plan asked for them; when the
  slot closes (:mod:`edge_mapper.slot_lifecycle`) C_k is evicted, the newest keyframes
  bundle-adjusted, the map checkpointed, and ``<device>/edge/map_update``,
  ``<device>/edge/map_stats`` and the viewer topics go out;
* ``<device>/udt/rate_latent`` → the twin's features for a twin-driven policy, and the
  expected uploads the ``twin`` allocator weighs the device by.
"""

from __future__ import annotations

import math
import shutil
import time
import traceback
import zlib
from collections.abc import Callable
from dataclasses import dataclass
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
    Relocalisation,
    RelocalisationRequest,
    UplinkThroughput,
    UploadRequest,
)

from edge_mapper.checkpoint_writer import CheckpointWriter
from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore, SlotOutcome, set_aside
from edge_mapper.messages import (
    map_stats_message,
    map_update_message,
    read_frame_summaries,
    read_keyframe,
    relocalisation_message,
    upload_request_message,
)
from edge_mapper.place_merging import PlaceMerging
from edge_mapper.policy_control import POLICY_KEYS, Note, PolicyControl
from edge_mapper.restart_watch import RestartWatch, Verdict
from edge_mapper.slot_lifecycle import Closing, SlotLifecycle
from edge_mapper.slot_planner import FrameObservations
from edge_mapper.viewer_topics import ViewerTopics
from msg_schemas import qos, topics
from msg_schemas.headers import time_seconds
from twinslam.node_runtime.checked_subscription import CheckedSubscription
from twinslam.node_runtime.long_lived_objects import release_frozen
from twinslam.node_runtime.matched_readers import logging_writer_matches
from twinslam.node_runtime.site_logging import SiteLogger
from twinslam.policies.connected_map import mended_decision
from twinslam.rotations import rotation_angle_deg
from twinslam.slam.back_end.foreign_keyframes import is_foreign, keyframe_label
from twinslam.slam.back_end.loop_closing import SHARED_WORKER
from twinslam.slam.back_end.map_back_end import ClosedLoop, archive_folder
from twinslam.slam.back_end.place_words import PlaceWords


@dataclass(frozen=True)
class LinkSettings:
    """What every link of one edge shares (the node's read-only parameters)."""

    config: EdgeConfig
    checkpoint: str                          #: "" none; with several devices, one file each
    n_states: int
    slot_timeout_s: float
    visualisation: bool
    map_frame: str
    #: slots between two keyframe trajectories (and after each loop closed); 0: after loops
    trajectory_every: int = 30
    #: the process's checkpoint writer, shared by its devices (None: each checkpoint written
    #: on the slot thread, before the slot's map update goes out)
    writer: CheckpointWriter | None = None
    #: the visual words every device of the process searches its archive under
    #: (``shared_vocabulary``; None: each archive learns its own)
    words: PlaceWords | None = None


#: the budget's hooks, for an edge serving several devices: (device, slot, frames, d_k, latent,
#: core) → the V_max this slot is planned with; and (device, slot, map size) when it finished;
#: and the compute a finished slot took (seconds), for the edge's compute budget
Granting = Callable[[str, int, list[FrameObservations], float, RateLatent | None,
                     EdgeMapperCore], int]
Finishing = Callable[[str, int, int], None]
Spending = Callable[[float], None]
#: a finished slot's summaries → map latency and the device's slot period (the spacing of its
#: summaries), in seconds, for the edge's load on /diagnostics
Answering = Callable[[float, float], None]


#: a device's looks for another map's place that found none: one log line in this many
LOOKS_LOGGED_EVERY = 5


def checkpoint_of(path: str, device: str) -> Path | None:
    """A device's own checkpoint beside the node's: ``edge.npz`` → ``edge.ar1.npz``."""
    if not path:
        return None
    if not device:
        return Path(path)
    p = Path(path)
    return p.with_name(f"{p.stem}.{device.replace('/', '_')}{p.suffix}")


class DeviceLink:
    """The topics of one device (``device`` "" = the node's own namespace) on ``node``."""

    def __init__(self, node: Node, device: str, settings: LinkSettings,
                 live: Callable[[], dict[str, Any]],
                 grant: Granting | None = None, finished: Finishing | None = None,
                 spent: Spending | None = None, merging: PlaceMerging | None = None,
                 on_fault: Callable[[str, str], None] | None = None,
                 answered: Answering | None = None) -> None:
        self.node, self.device, self.settings = node, device, settings
        self.answered = answered
        #: the last slot whose summaries came, and when (the slots' clock): the device's slot
        #: period is their spacing
        self._last_summaries: tuple[int, float] | None = None
        #: each open slot's period estimate, taken when its summaries came
        self._periods: dict[int, float] = {}
        #: this device's lines, each named by the link's code that wrote it (one or more a
        #: slot per device: rclpy's own caller lookup cost 7 % of a fifty-device edge's slots)
        self.lines = SiteLogger(node.get_logger(), depth=2)
        #: told (device, traceback) when this device's work raised — an edge serving several
        #: devices then stops serving this one and goes on with the others (None: the error
        #: propagates, and the node stops as a one-device edge should)
        self.on_fault = on_fault
        self.fault = ""                 #: the traceback of the work that failed ("": none)
        #: whether the device's summaries say it started again: the node then serves it
        #: afresh (:attr:`RestartWatch.restart`)
        self.restarts = RestartWatch()
        self.closed = False             #: :meth:`close` ran: callbacks still due do nothing
        self.live, self.grant, self.finished, self.spent = live, grant, finished, spent
        #: the edge's map merging across its devices (None: each device's map stays apart)
        self.merging = merging
        self.control = PolicyControl({k: v for k, v in live().items() if k in POLICY_KEYS},
                                     EdgeMapperCore.warm_up)
        self.core = EdgeMapperCore(self.control.policy, None, settings.config,
                                   checkpoint_of(settings.checkpoint, device),
                                   settings.n_states)
        self.core.spread_checkpoints(zlib.crc32(device.encode()))
        self.core.writer = settings.writer
        if settings.words is not None:
            self.core.archive.words.share(settings.words)
        self.slots = SlotLifecycle(settings.slot_timeout_s)
        #: the frame of this device's map: with several devices each has its own on /tf
        self.map_frame = f"{device}/{settings.map_frame}" if device else settings.map_frame
        self.latent: RateLatent | None = None    #: the twin's newest, for the allocator
        self.last_heard = time.monotonic()
        self.prefix = f"{device}/" if device else ""
        pub = node.create_publisher
        self.pub_request = pub(UploadRequest, self.topic(topics.UPLOAD_REQUEST), qos.PROTOCOL)
        self.pub_map = pub(MapUpdate, self.topic(topics.MAP_UPDATE), qos.MAP)
        self.pub_stats = pub(MapStats, self.topic(topics.MAP_STATS), qos.PROTOCOL)
        self.pub_relocalisation = pub(Relocalisation, self.topic(topics.RELOCALISATION),
                                      qos.PROTOCOL)
        self.views = (ViewerTopics(node, self.topic, settings.trajectory_every)
                      if settings.visualisation else None)
        guarded = self._guarded
        self.subscriptions = [
            # its matches logged: a device (or a test) whose first slot must reach this edge
            # waits for "…/frame_summaries: 1 writer(s) matched"
            CheckedSubscription(node, FrameSummaries, self.topic(topics.FRAME_SUMMARIES),
                                guarded(self._on_summaries), qos.PROTOCOL,
                                event_callbacks=logging_writer_matches(
                                    node, self.topic(topics.FRAME_SUMMARIES))),
            CheckedSubscription(node, Keyframe, self.topic(topics.KEYFRAMES),
                                guarded(self._on_keyframe), qos.PROTOCOL),
            CheckedSubscription(node, UplinkThroughput, self.topic(topics.UPLINK_THROUGHPUT),
                                guarded(self._on_throughput), qos.PROTOCOL),
            CheckedSubscription(node, RateLatent, self.topic(topics.RATE_LATENT),
                                guarded(self._on_latent), qos.PROTOCOL),
            CheckedSubscription(node, RelocalisationRequest,
                                self.topic(topics.RELOCALISATION_REQUEST),
                                guarded(self._on_relocalisation_request), qos.PROTOCOL),
        ]
        #: :meth:`finish_due` for the node's timer, guarded as the callbacks are
        self.tick = guarded(self.finish_due)
        for problem in self.core.archive_problems:
            self.warning(f"archived keyframe skipped: {problem}")
        if self.core.restored:
            self.info(self.core.restored_summary())
            # with the whole track table: the device may still hold tracks of before the stop
            self.pub_map.publish(map_update_message(self.core.slice, self.core.last_slot,
                                                    self.core.version, self._now(),
                                                    self.map_frame,
                                                    tracks=self.core.local_mapping.track_points,
                                                    frame_correction=self.core.frame_correction))

    def _guarded(self, work: Callable[..., None]) -> Callable[..., None]:
        """``work`` (a callback of this device) run only while the device's work has not
        failed; with ``on_fault``, an exception it raises is kept and told, not raised: on an
        edge serving several devices, one device's failure must not stop the others' slots."""
        def run(*args: Any) -> None:
            if self.fault or self.closed:     # a sample handed over after the link closed
                return
            # the slots' work: a loop worker that yields to it waits meanwhile
            with SHARED_WORKER.slot_work():
                if self.on_fault is None:
                    work(*args)
                    return
                try:
                    work(*args)
                except Exception:       # told to the node, which stops serving this device
                    self.fault = traceback.format_exc()
                    self.on_fault(self.device, self.fault)

        return run

    def topic(self, name: str) -> str:
        """A topic of this device, relative to the node's namespace."""
        return self.prefix + name

    # -- logging -----------------------------------------------------------------------------

    def _text(self, text: str) -> str:
        return f"[{self.device}] {text}" if self.device else text

    def info(self, text: str) -> None:
        self.lines.info(self._text(text))

    def warning(self, text: str) -> None:
        self.lines.warning(self._text(text))

    def error(self, text: str) -> None:
        self.lines.error(self._text(text))

    def _log(self, notes: list[Note]) -> None:
        # one call site per severity: rclpy refuses a logging line whose severity changes
        for note in notes:
            if note.level == "error":
                self.error(note.text)
            elif note.level == "warning":
                self.warning(note.text)
            else:
                self.info(note.text)

    def _now(self) -> float:
        return self.node.get_clock().now().nanoseconds * 1e-9

    # -- the protocol ------------------------------------------------------------------------

    def _on_relocalisation_request(self, msg: RelocalisationRequest) -> None:
        """A lost device's frame: looked for in the archive, answered at once."""
        slot, frame_id = int(msg.slot), int(msg.frame_id)
        found = self.core.relocalise(np.asarray(msg.keypoints_xy, np.float64).reshape(-1, 2),
                                     np.asarray(msg.descriptors, np.uint8).reshape(-1, 32))
        if found.found:
            self.info(f"slot {slot}: lost frame {frame_id} found in the archive (keyframe "
                      f"{found.keyframe}, {found.inliers} inliers): that place comes back with "
                      "the slot's map update")
        else:
            self.info(f"slot {slot}: lost frame {frame_id} not found in the archive: "
                      f"{found.reason}")
        self.pub_relocalisation.publish(relocalisation_message(
            slot, frame_id, found, self._now(), self.map_frame))

    def _restart_seen(self, slot: int, stamps: list[float]) -> bool:
        """Whether summaries of ``slot`` (frames captured at ``stamps``) are left unanswered
        as a restarted run's (:class:`~edge_mapper.restart_watch.RestartWatch`: one old slot
        is evidence, the new run's next slot proof). The node then serves the device afresh
        from its timer, outside this callback."""
        verdict = self.restarts.summaries(slot, stamps, self.core.is_restart(slot),
                                          self.core.newest_planned)
        if verdict is Verdict.EVIDENCE:
            self.warning(f"slot {slot}: summaries of a slot this edge closed already (the "
                         "device started again, or a stray message): not answered")
        return verdict is not Verdict.PLAN

    def _on_summaries(self, msg: FrameSummaries) -> None:
        slot = int(msg.slot)
        self.last_heard = time.monotonic()
        stamps = [time_seconds(f.stamp) for f in msg.frames]
        if self._restart_seen(slot, stamps):
            return
        before = self.core.version
        if self.core.catch_up_version(int(msg.map_version)):
            why = ("its checkpoint was written before the last maps went out"
                   if self.core.back_end.restored_from_file else
                   "this edge's map of it is new: an edge served it before, and that map "
                   "was set aside or not checkpointed")
            self.info(f"slot {slot}: the device holds map version {msg.map_version}, newer "
                      f"than this edge's {before} ({why}): versions go on from the device's")
        live = self.live()
        self._log(self.control.apply({k: live[k] for k in POLICY_KEYS}, slot))
        self.core.set_policy(self.control.policy)
        frames = read_frame_summaries(msg)
        started, received = time.perf_counter(), self.slots.clock()
        frames = self.core.resolve_tracks(frames)   # the budget and the plan read them alike
        vmax = (self.grant(self.device, slot, frames, float(msg.rate_mbps), self.latent,
                           self.core)
                if self.grant is not None else int(live["vmax"]))
        if vmax != self.core.slot_config.vmax:
            if self.grant is None:
                self.info(f"slot {slot}: V_max {vmax} from this slot on (was "
                          f"{self.core.slot_config.vmax})")
            self.core.set_vmax(vmax)
        try:
            plan = self.core.plan(slot, frames, float(msg.rate_mbps), int(msg.rate_state),
                                  tracks_resolved=True)
        except ValueError as exc:
            self.error(f"slot {slot}: cannot plan: {exc}")
            if self.finished is not None:      # the grant was never used
                self.finished(self.device, slot, len(self.core.slice.keyframes))
            return
        self.restarts.planned(stamps)
        if plan.policy_action is not None:
            mended = mended_decision(plan.policy_action, plan.action, _keyframe_name)
            self.info(f"slot {slot}: {mended}")
        decided_by, notes = self.control.decided(slot)
        self._log(notes)
        self.pub_request.publish(upload_request_message(slot, decided_by,
                                                        float(msg.rate_mbps), plan.action,
                                                        self._now()))
        self.slots.open(slot, time.perf_counter() - started, plan.uncertainty, decided_by, vmax,
                        received, covered=len(plan.covered))
        if self._last_summaries is not None and slot > self._last_summaries[0]:
            self._periods[slot] = (received - self._last_summaries[1]) / \
                (slot - self._last_summaries[0])
        self._last_summaries = (slot, received)
        self.finish_due()                        # a slot that uploads nothing is due at once

    def _on_latent(self, msg: RateLatent) -> None:
        self.latent = msg
        if self.control.feed is None:
            return
        try:
            self.control.feed.offer(int(msg.slot), np.asarray(msg.mu), np.asarray(msg.sigma),
                                    int(msg.model_version))
        except ValueError as exc:
            self.error(f"rate latent of slot {msg.slot} refused: {exc}")

    def _on_keyframe(self, msg: Keyframe) -> None:
        started = time.perf_counter()
        data = read_keyframe(msg)
        report = self.core.add_keyframe(data)
        self.slots.charge(data.slot, time.perf_counter() - started)
        if report is None:
            self.warning(f"keyframe {data.frame_id} of slot {data.slot} was not asked for, came "
                         "twice or after its slot closed: ignored")
            return
        if self.merging is not None and not report.refused:
            self.merging.keyframe(self.device, data)
        self.finish_due()

    def _on_throughput(self, msg: UplinkThroughput) -> None:
        """The device's account of a slot: once what it sent is in, nothing more will come."""
        slot = int(msg.slot)
        if slot in self.core.pending:
            self.slots.device_sent(slot, int(msg.frames_sent))
            self.finish_due()

    def finish_due(self) -> None:
        """Finish open slots, oldest first, while the oldest is due (slots finish in order so
        that no map the edge publishes holds more than its V_max keyframes)."""
        while (slot := self.core.oldest_open) is not None:
            action, received = self.core.pending[slot]
            closing = self.slots.closing(slot, action.upload, received)
            if closing is None:
                return
            if closing is Closing.SHORT:
                self.warning(f"slot {slot}: the device sent {self.slots.open_slots[slot].sent} "
                             f"of {len(action.upload)} requested keyframes (the rest were no "
                             "longer held); finishing without them")
            elif closing is Closing.TIMEOUT:
                self.warning(f"slot {slot}: {len(set(action.upload) - received)} requested "
                             f"keyframe(s) did not arrive within {self.slots.timeout_s:g} s; "
                             "finishing without them")
            self._finish(slot)
            started = time.perf_counter()
            if self.core.integrate_held() and self.core.oldest_open is not None:
                self.slots.charge(self.core.oldest_open, time.perf_counter() - started)

    def _finish(self, slot: int) -> None:
        started = time.perf_counter()
        entry = self.slots.close(slot, self.control.policy_name)
        self._take_merge(slot)                # first: the poses below are in the new frame
        before = ({k: kf.pose for k, kf in self.core.map.keyframes.items()}  # evicted: where
                  if self.views is not None and self.views.wants_decisions() else {})
        out: SlotOutcome = self.core.finish_slot(slot)
        if self.merging is not None:
            self.merging.look(self.device, slot)
        if self.finished is not None:
            self.finished(self.device, slot, len(self.core.slice.keyframes))
        now, frame = self._now(), self.map_frame
        self.pub_map.publish(map_update_message(self.core.slice, slot, out.version, now, frame,
                                                tracks=out.tracks,
                                                frame_correction=self.core.frame_correction))
        ba_ms = out.bundle_adjustment.milliseconds if out.bundle_adjustment else 0.0
        compute_s = entry.compute_s + time.perf_counter() - started
        latency_s = entry.latency_s(self.slots.clock())     # summaries → this map update
        self.pub_stats.publish(map_stats_message(
            slot, entry.decided_by, self.core.slice, out.map_uncertainty, entry.uncertainty,
            uploads=len(out.integrated), optimisation_ms=ba_ms, processing_ms=compute_s * 1000,
            stamp=now, keyframe_budget=entry.vmax,
            latency_ms=latency_s * 1000,
            archived=len(self.core.archive), restored=len(out.restored),
            refused=len(out.refused), missing=len(out.not_in),
            frame_id=frame, loops_closed=self.core.loops_closed,
            loop_ms=out.loop.worker_ms if out.loop else 0.0,
            loops_refused=self.core.loops_refused))
        if out.loop is not None and out.loop.old < 0:
            self.warning(f"slot {slot}: {out.loop.refused} (looking from keyframe "
                         f"{out.loop.new}); the edge goes on without it")
        elif out.loop is not None and out.loop.refused:
            self.warning(f"slot {slot}: loop between {_loop_ends(out.loop)} refused, "
                         f"{out.loop.refused}")
        elif out.loop is not None:
            self.info(f"slot {slot}: loop closed between {_loop_ends(out.loop)} "
                      f"({out.loop.inliers} inliers), the map moved up to "
                      f"{out.loop.moved_m:.3f} m; the loop closer took "
                      f"{out.loop.worker_ms:.0f} ms beside the slots{_waited(out.loop)}")
        for failure in out.loop_failures:
            self.error(f"slot {slot}: {failure}; the map is corrected, the archive on disk "
                       "is not (a restart reads the poses before the loop)")
        if out.optimisation_refused:
            self.warning(f"slot {slot}: the bundle adjustment's answer not applied, "
                         f"{out.optimisation_refused}")
        for frame_id, why in sorted(out.refused.items()):
            self.warning(f"slot {slot}: keyframe {frame_id} refused, {why}: it enters neither "
                         "the map nor the archive")
        if self.spent is not None:
            self.spent(compute_s)
        period = self._periods.pop(slot, math.inf)      # the first slot: none to judge by
        if self.answered is not None:
            self.answered(latency_s, period)
        if self.views is not None:             # after MapStats: not in its compute time
            self.views.publish(self.core.map, slot, now, frame, out.integrated, out.evicted,
                               out.restored, before, out.loop is not None and
                               not out.loop.refused and out.loop.old >= 0,
                               self.core.back_end.keyframe_trajectory)
        u = out.map_uncertainty
        kept = f" (kept {len(out.spared)} of C_k: uploads missing)" if out.spared else ""
        if entry.covered:
            kept += f", {entry.covered} frames not asked for: the map covers their views"
        if out.restored:
            kept += f", {len(out.restored)} restored from the archive {out.restored}"
            if out.fused_points:
                kept += f" ({out.fused_points} of their points fused with the map's)"
        self.info(f"slot {slot}: +{len(out.integrated)} keyframes, -{len(out.evicted)}{kept}, map "
                  f"{len(self.core.slice.keyframes)} keyframes / {len(self.core.slice.points)} "
                  f"points, u(G) {u:.1f}{'' if math.isfinite(u) else ' (disconnected)'}, BA "
                  f"{ba_ms:.0f} ms, version {out.version}")

    def _take_merge(self, slot: int) -> None:
        """A merge found beside the slots, applied before ``slot``'s end: the map update this
        slot sends is in the place's frame."""
        if self.merging is None:
            return
        looks = self.merging.unmerged_looks.get(self.device, (0, ""))[0]
        merged, adopted, carried = self.merging.before_slot_end(self.device, slot)
        count, found = self.merging.unmerged_looks.get(self.device, (0, ""))
        if count > looks and count % LOOKS_LOGGED_EVERY == 1:
            self.info(f"slot {slot}: no other map's place found yet ({count} looks; the last "
                      f"{found})")
        if adopted:
            declined = self.merging.declined(self.device)
            self.info(f"slot {slot}: {adopted} keyframes of the other maps in its frame "
                      "adopted into the archive" + (
                          f" ({declined} declined: a copy it holds has their view)"
                          if declined else ""))
        for move in carried:
            if move.refused:
                self.warning(f"slot {slot}: another device's loop moved {move.copies} of its "
                          f"keyframes this map holds; its own keyframes tied to them stay: "
                          f"{move.refused}")
            else:
                self.info(f"slot {slot}: another device's loop moved {move.copies} of its "
                          f"keyframes this map holds, and {move.own} of the map's own with "
                          f"them (up to {move.own_moved_m * 100:.1f} cm; its graph "
                          f"{move.graph_ms:.0f} ms): the device's frame moves with the next "
                          "map update")
        for failure in self.merging.failures():
            self.error(f"slot {slot}: {failure}; the map stays in its own frame")
        for clash in self.merging.tag_clashes():
            self.error(f"slot {slot}: {clash}")
        for notice in self.merging.notices():
            self.info(f"slot {slot}: {notice}")
        # a joined map is one map of the place from now on; a merged one its own, borrowing
        joined_or_merged = "joined" if self.merging.join else "merged into"
        for event in self.merging.brought(self.device):
            t = event.merge.alignment[:3, 3]
            self.info(f"slot {slot}: {event.device}'s map {joined_or_merged} this device's place "
                      f"({event.place}/{self.settings.map_frame}): this map's keyframe "
                      f"{event.merge.place} found in {event.via or event.device}'s map at its "
                      f"keyframe {event.merge.joining} ({event.merge.inliers} inliers, "
                      f"confirmed by the next keyframes); {event.device}'s map moved by "
                      f"({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}) m and turned "
                      f"{rotation_angle_deg(event.merge.alignment[:3, :3]):.2f}°")
        if merged is not None:
            # what the edge publishes of this device is in the place's frame from now on
            self.map_frame = f"{merged.place}/{self.settings.map_frame}"
            t = merged.merge.alignment[:3, 3]
            how = (f"keyframe {merged.merge.joining} and {merged.place}'s place's keyframe "
                   f"{merged.merge.place} seeing one place" if not merged.via else
                   f"with its place, where {merged.via}'s map met {merged.place}'s place")
            self.info(f"slot {slot}: map {joined_or_merged} {merged.place}'s: {how} "
                      f"({merged.merge.inliers} inliers, confirmed by the next keyframes); "
                      f"the map moved by ({t[0]:.3f}, {t[1]:.3f}, {t[2]:.3f}) m and turned "
                      f"{rotation_angle_deg(merged.merge.alignment[:3, :3]):.2f}° into "
                      f"{merged.place}'s frame ({self.map_frame}), the look took "
                      f"{merged.look_ms:.0f} ms beside the slots")

    def close(self, keep_checkpoint: bool = False) -> None:
        """Stop listening and publishing (a reclaimed device): its slots are dropped and its
        checkpoint, if any, moved aside to ``FILE.reclaimed`` so that the device, should it
        come back, starts afresh (the file is still there to inspect or restore) — or left
        where it is (``keep_checkpoint``: a standby edge giving the device back to its own
        edge, which writes that file). Slots finished since the last checkpoint
        (``checkpoint_every``) are not written: the device's own edge owns the file again, or
        the device starts afresh (a clean stop writes them: :meth:`EdgeMapperNode.close`)."""
        self.closed = True
        checkpoint = self.core.checkpoint
        try:
            # a write still under way would land after the file moved aside (a new file where
            # the device's checkpoint was), or over the file its own edge writes again
            self.core.wait_for_checkpoint()
        except OSError as exc:
            self.node.get_logger().error(f"device {self.device}: its last checkpoint was not "
                                         f"written: {exc}")
        if checkpoint is not None and not keep_checkpoint:
            for kept in (checkpoint, archive_folder(checkpoint)):
                aside = set_aside(kept)
                if kept.exists():
                    if aside.is_dir():          # an earlier reclaim's archive
                        shutil.rmtree(aside)
                    kept.replace(aside)
        self.core.close()
        for sub in self.subscriptions:
            self.node.destroy_subscription(sub.subscription)
        for pub in (self.pub_request, self.pub_map, self.pub_stats):
            self.node.destroy_publisher(pub)
        if self.views is not None:
            self.views.destroy(self.node)
        # the map and the link's callbacks go: the collector sees the frozen objects again
        release_frozen()


def _waited(loop: ClosedLoop) -> str:
    """How long the loop job waited for the slots' work, for its log line ("" under a
    millisecond): its time above is its own work, and a busy edge's job waits seconds."""
    return f" (and waited {loop.waited_ms:.0f} ms for them)" if loop.waited_ms >= 1.0 else ""


def _loop_ends(loop: ClosedLoop) -> str:
    """The two keyframes of a loop as the log names them: "keyframes 30 and 900", or, closed
    with another device's keyframe (a loop across devices), "another device's keyframe 30
    (copy …) and keyframe 900"."""
    if not is_foreign(loop.old):
        return f"keyframes {loop.old} and {loop.new}"
    return f"{keyframe_label(loop.old)} and keyframe {loop.new}"


def _keyframe_name(kf_id: int) -> str:
    """A keyframe as the mended-decision line lists it: its id, or another device's copy as
    :func:`keyframe_label` names it."""
    return keyframe_label(kf_id) if is_foreign(kf_id) else str(kf_id)
