"""The edge node's ROS parameters: name, default, description, range, and which change live.

Defaults are the default device's edge (:mod:`twinslam.slot_protocol.default_device`: LFF,
D_req 0.25 s, three restores a slot) and the paper's Table I elsewhere (V_max 45 keyframes,
α 5 Mbit); ``config/paper-table1.yaml`` is the paper's edge. ``ros2 param
describe /edge_mapper vmax`` shows the description and range; a value out of range or a policy
that cannot be made is refused with the reason (:mod:`edge_mapper.policy_control`).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

from edge_mapper.device_link import LinkSettings
from edge_mapper.edge_core import EdgeConfig
from edge_mapper.policy_control import (
    checkpoint_refused,
    fallback_refused,
    policy_refused,
)
from edge_mapper.slot_planner import SlotConfig
from msg_schemas import topics
from twinslam.allocation.allocators import ALLOCATORS
from twinslam.node_runtime.parameters import ParamSpec
from twinslam.slam.back_end import loop_closing
from twinslam.slam.back_end.loop_detection import MIN_INLIERS
from twinslam.slam.back_end.map_back_end import BackEndConfig
from twinslam.slam.back_end.map_merging import LENT_VIEW_DEG, LENT_VIEW_M, MERGE_MIN_INLIERS
from twinslam.slam.back_end.view_coverage import CoverageBounds
from twinslam.slot_protocol import default_device, table1


def _devices_refused(value: object) -> str | None:
    """Why a device list is not one (None: it is): namespace names, each once."""
    names = [str(v).strip("/") for v in value] if isinstance(value, list | tuple) else []
    bad = [n for n in names if not DEVICE_NAME.fullmatch(n)]
    if bad:
        return (f"{', '.join(map(repr, bad))}: a device is a namespace name (letters, digits, "
                "_ and / between them, e.g. ar1 or lab/ar1)")
    if len(set(names)) != len(names):
        return "a device is listed twice"
    return None

#: a device's namespace, relative to the edge's: ROS name tokens joined by /
DEVICE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*")

PARAMETERS = (
    ParamSpec("policy", default_device.POLICY, "map-management policy: lff | pu | adapt | random | "
              "mbrl (with policy_checkpoint) | mbrl:CHECKPOINT | mpc[:H=2/S=4/...] (the "
              "causal planner) | delay:SECONDS:POLICY (a control: POLICY's decisions, late)",
              live=True,
              check=policy_refused),
    ParamSpec("policy_checkpoint", "", "the trained policy of policy:=mbrl "
              "(`twinslam train -o FILE`)", live=True, check=checkpoint_refused),
    ParamSpec("vmax", table1.VMAX, "V_max, keyframes the edge map holds at most", low=2,
              high=10_000, live=True),
    ParamSpec("alpha_mbit", table1.ALPHA_MBIT, "alpha, uplink Mbit one uploaded frame occupies",
              low=1e-6, high=1e6),
    ParamSpec("d_req_s", default_device.D_REQ_S, "D_req, seconds a slot's uploads may take "
              "(Table I: 0.5)", low=1e-3,
              high=1e3),
    ParamSpec("progress_uploads", True, "where Theorem 1's floor(d_k D_req / alpha) is 0 but "
              "the uplink carries alpha within the slot (d_k under alpha / D_req), ask for one "
              "frame, its deadline stretched to the slot's end, so a slow uplink still grows "
              "the map; false: Theorem 1 exactly (the paper's preset)"),
    ParamSpec("connected_map", True, "where the policy's decision would leave the map in "
              "more pieces (uploads that share no point with it, as in a fast turn, or an "
              "eviction of the keyframe that ties a piece to the rest), upload as many of the "
              "slot's newest frames that tie to the map and evict keyframes whose eviction "
              "splits nothing instead; and where the map is in pieces, evict whole a piece "
              "no tracked frame has tied to for two slots (the camera left it; it waits in "
              "the archive); false: the policy's decision as it is (the paper's preset)"),
    ParamSpec("checkpoint", "", "map file written every checkpoint_every slots and resumed "
              "from after a restart (a standby edge takes a device over from it); empty: none"),
    ParamSpec("checkpoint_every", 1, "slots between two checkpoints of a device's map (with "
              "checkpoint): gathering one is ~7-11 ms of a device's slot on the 7-Scenes "
              "walk; an edge resumed from one up to this many slots old goes on from the map "
              "version its device holds, and a clean stop writes the last", low=1, high=3600),
    ParamSpec("checkpoint_in_background", False, "write the checkpoints on a thread of their "
              "own: the slot thread, which every device of the edge waits for, only gathers "
              "the map's arrays (the write and its fsync took ~20 ms a device-slot on a VM's "
              "disk), and the evicted keyframes' archive files are written there too, just "
              "before the checkpoint; each lands shortly after its slot's map update went "
              "out, and an edge "
              "killed in between resumes one checkpoint back (an edge of many devices, or on a "
              "slow disk). false: written before the update goes out, a map the device got "
              "survives the edge"),
    ParamSpec("states", 2, "N uplink channel states (the rate history's alphabet)", low=1,
              high=64),
    ParamSpec("archive_keyframes", 500, "evicted keyframes the edge keeps (pose, map points, "
              "descriptors; ~90 kB a keyframe of 1000 points) for relocalisation and restores, "
              "the least recently useful leaving first; 0: an evicted keyframe is forgotten",
              low=0, high=1_000_000),
    ParamSpec("restore_keyframes", default_device.RESTORE_KEYFRAMES, "archived keyframes "
              "brought back into the map a slot "
              "at most: those the camera is heading for (the device's poses continued at "
              "constant velocity), each in place of the keyframe that sees least of that view; "
              "0: none (the paper's edge)", low=0, high=1000),
    ParamSpec("point_fusion", True, "the points a restored keyframe brings back that the map "
              "made again since are fused into the map's (one corner, one point); false: they "
              "stay as copies, as before the fusion (for measuring what it changes)"),
    ParamSpec("point_culling", False, "a map point that later keyframes look at and find in "
              "fewer than a quarter of their views (after four) leaves the map (ORB-SLAM's "
              "map-point culling); false: a point stays until its last observer leaves"),
    ParamSpec("integration_fusion", default_device.INTEGRATION_FUSION, "a new keyframe's "
              "feature that would make a map point within 5 cm (+2 % of its depth) of a map "
              "point in view that looks alike observes that point instead: one corner, one "
              "point, where the matching by pixel refused a corner the map holds twice; false: "
              "every unmatched feature with depth makes a point"),
    ParamSpec("loop_closing", default_device.LOOP_CLOSING, "look for a loop from every "
              "keyframe the edge integrates (a place its archive or map saw far earlier, "
              "found by PnP, measured from the two keyframes' depths) and close it with a pose "
              "graph over every keyframe and the loops before, on a worker thread; the "
              "corrected map goes to the device in the next map update"),
    ParamSpec("loop_worker_niceness", loop_closing.WORKER_NICENESS, "steps (Linux nice) the "
              "worker thread of the loop closer and the merge looks runs below the slots' "
              "priority, for every device of the process: where the edges fill the host's cores, "
              "the slots keep their deadline and the loops wait (12 devices on two processes of "
              "a 2-core host, a walk and back, 10 steps: 0-7 % late instead of 14-55 %, 24-36 of "
              "36 loops closed a median two slots later; on a walk that ends five slots after "
              "its revisit none closed); 0: the same priority", low=0, high=19),
    ParamSpec("loop_worker_share", loop_closing.WORKER_SHARE, "the most of one core the worker of "
              "the loop closer and the merge looks takes, for every device of the process: after "
              "each job it rests until its CPU time is this share of the time since it began, so "
              "the slots keep the rest and the loops wait (12 devices on two processes of a "
              "2-core host, a walk and back, a quarter: 0.9-12.8 % late instead of 14-55 %, "
              "23-31 of 36 loops closed, later than 10 nice steps below); 1: all it can get",
              low=0.05, high=1.0),
    ParamSpec("loop_worker_yields", loop_closing.WORKER_YIELDS, "the worker of the loop closer "
              "and the merge looks waits, before each loop query or keyframe looked for, while "
              "the slots' work (any device's callback) runs, at most 0.5 s a query: within one "
              "process it shares the slot thread's interpreter, which a nice value does not "
              "reach (8 devices on one process of a 2-core host, a walk and back: 0-15 % late "
              "instead of 33-49 % in four paired rounds of five, the loops closed in the same "
              "slots); false: it runs whenever it has work"),
    ParamSpec("shared_vocabulary", True, "every device of this edge process searches its "
              "archive under one vocabulary of visual words, learned by the first archive that "
              "outgrows exact search and again by one that outgrows it eightfold (ORB-SLAM's "
              "maps share one DBoW2 vocabulary); false: each device's archive learns its own, "
              "~0.7 s of k-means on the loop closer's worker once a device (a merged place's "
              "devices still share their root's)"),
    ParamSpec("reloc_restore_keyframes", 0, "archived keyframes brought back at the end of a "
              "slot around the pose the edge found in its archive for a lost device's frame "
              "(device/relocalisation_request, the device's reloc_period_s), the map keyframes "
              "not connected to them leaving; 0: the edge does not relocalise devices "
              "(default: measured to lose more frames, BENCHMARKS.md)", low=0, high=1000),
    ParamSpec("ba_window", default_device.BA_WINDOW, "newest keyframes bundle-adjusted each "
              "slot, by id: in a merged map the newest copies of other devices' keyframes "
              "(0: none, the default device: the device's own poses and depths make a map "
              "that agrees with itself better, docs/results/map-consistency.md; 5: the "
              "paper's edge)", low=0, high=1000),
    ParamSpec("slot_timeout_s", 10.0, "finish a slot without keyframes that never came after "
              "this many seconds", low=0.1, high=3600.0),
    ParamSpec("image_width", 640, "camera image width in pixels", low=1, high=100_000),
    ParamSpec("image_height", 480, "camera image height in pixels", low=1, high=100_000),
    ParamSpec("fallback_policy", default_device.POLICY, "decides when a twin-driven policy "
              "has no fresh "
              f"{topics.RATE_LATENT}", live=True, check=fallback_refused),
    ParamSpec("latent_max_age", 2, "slots a twin latent stays fresh", low=0, high=1_000_000,
              live=True),
    ParamSpec("visualisation", True, f"publish {topics.MAP_POINTS} (PointCloud2), "
              f"{topics.KEYFRAME_POSES} (PoseArray) and {topics.DECISIONS} (MarkerArray) once a "
              "slot, latched, for RViz / Foxglove; each made only while something subscribes to it "
              "(a viewer that joins gets the map at the next slot's end)"),
    ParamSpec("trajectory_every", 30, f"with visualisation, publish {topics.KEYFRAME_TRAJECTORY} "
              "(nav_msgs/Path of every keyframe kept, the map's and the archive's, latched) every "
              "this many slots and after every slot that closed a loop; 0: only after loops",
              low=0, high=1_000_000),
    ParamSpec("map_frame", "map", "frame id of the map the edge publishes (the device's "
              "map_frame: its first frame's camera frame); with several devices, each device's "
              "is DEVICE/map_frame"),
    # one edge, many devices
    ParamSpec("devices", (), "device namespaces this edge serves, e.g. [ar1, ar2] (their "
              "ar1/device/... topics, relative to the edge's namespace); empty: the one device "
              "of the edge's own namespace", check=_devices_refused),
    ParamSpec("discover_devices", False, "also serve every device namespace that appears on "
              "the graph (a DEVICE/device/frame_summaries publisher)"),
    ParamSpec("vmax_total", 0, "V_total: keyframes of every served device's map together, "
              "split by allocator slot by slot; 0: each device has vmax", low=0, high=1_000_000),
    ParamSpec("allocator", "equal", "how vmax_total is split: equal, motion (by each "
              "device's novelty: the share of its frames' points its map lacks) or twin (by "
              "the tracked share each keyframe buys a device, its rate twin's expected uploads "
              "included)", check=lambda v: None if v in ALLOCATORS
              else f"must be one of {', '.join(ALLOCATORS)}"),
    ParamSpec("min_keyframes", 5, "the least share of vmax_total a device gets", low=1,
              high=1_000_000),
    ParamSpec("standby", False, "a standby edge: serve a device namespace that publishes frame "
              "summaries once takeover_slots of its slots went unanswered (its edge died), "
              "from its checkpoint where the edges share the checkpoint path; give it back "
              "when another edge answers it again"),
    ParamSpec("takeover_slots", 3, "a device's slots without an upload request before a "
              "standby edge takes it over", low=1, high=1000),
    ParamSpec("merge_maps", False, "with several devices: a device's map joins the frame of a "
              "device served before it once its keyframes are found in that device's map, or "
              "that device's in its own (confirmed by two more, as a loop), and adopts that "
              "map's keyframes into its archive, which restores bring in where it heads: their "
              "poses in one frame, on shared keyframes; the looks beside the slots and the "
              "keyframe database cost the loop worker ~14 ms of CPU a slot per unmerged "
              "device (twelve alone on one core), and the database's words ~3 s once"),
    ParamSpec("merge_join", False, "with merge_maps: a merge makes the two maps one map of "
              "the place — the joining map's keyframes and points moved into the place's, its "
              "duplicate points fused — which every device of the place feeds and holds a "
              "slice of under its own policy and V_max: the place's bundle adjustment and "
              "loop closing run once, not once a device, and a device restores the keyframes "
              "any device uploaded (in process, 7-Scenes: 51 % fewer uploads than alone "
              "against lending's 46 %, the joined device's slot 18 ms shorter); a place's "
              "loops are its first device's walk's, and the edge writes no checkpoint "
              "(needs checkpoint empty); false: each map borrows the others' keyframes as "
              "copies (lend_in_view, loops_across_devices)"),
    ParamSpec("merge_min_inliers", MERGE_MIN_INLIERS, "with merge_maps: the PnP inliers "
              "each of a merge's three detections needs (a loop's 50 at least): a merge places "
              "a whole map by one keyframe's geometry, and waiting for a place both maps see "
              "well merged later and left both devices nearer the truth (live, 100 against 50: "
              "ATE -0.58 and -0.26 cm; their agreement on the same frames not told apart)",
              low=MIN_INLIERS, high=10_000),
    ParamSpec("merge_look_backoff_slots", 1, "with merge_maps: the most slots between two "
              "looks of a device whose looks find no candidate place in the maps they search "
              "(after each such look the wait doubles, up to this; a candidate found, or a "
              "device served anew, and it looks after every slot again): the looks of devices "
              "alone in their places cost the loop worker ~14 ms a device-slot, and a device "
              "that walks into a mapped place then merges up to this many slots less one "
              "later; 1: a look after every slot", low=1, high=1000),
    ParamSpec("lend_in_view", True, "with merge_maps: a device's map adopts another device's "
              "keyframe of its place once its camera, where it heads, sees it (as a restore "
              "would score it; everything while it is lost): each map welds what its device "
              "comes to, not every keyframe every device of its place makes; false: each as "
              "soon as its device made it"),
    ParamSpec("lent_view_m", LENT_VIEW_M, "with merge_maps: a device's map "
              "adopts another device's keyframe only where no copy of the other devices' "
              "keyframes it holds stands within this many metres of it, turned by at most "
              "lent_view_deg: where several devices walk one place, a view is lent once, not "
              "once for each device that uploaded it (a map's copies, each welded, archived, "
              "searched and moved by its lender's loops, then grow with the place, not with "
              "its devices); the map's own keyframes never decline a copy (its loops across "
              "devices close with it); 0: every keyframe of the place is lent",
              low=0.0, high=10.0),
    ParamSpec("lent_view_deg", LENT_VIEW_DEG, "the turn, degrees, within which a "
              "copy a map holds declines another device's keyframe of its view (with "
              "lent_view_m)", low=0.0, high=180.0),
    ParamSpec("lent_unseen_slots", 0, "with merge_maps and lend_in_view: the slots a copy "
              "of another device's keyframe stays in this device's archive while the device "
              "neither holds it nor sees it, before it goes back to its lender, to be lent "
              "again once the device comes where it is (a map then holds copies of where its "
              "device is and was lately, not of every place it passed); 0: kept until the "
              "archive's capacity drops them", low=0, high=1_000_000),
    ParamSpec("loops_across_devices", True, "with merge_maps: a device's loop closer also "
              "closes loops with the keyframes its place's other devices lent its map at "
              "least five slots before (where it comes to a place another device mapped "
              "first, its walk bends towards that device's keyframes: the two walks' drift "
              "apart since the merge taken out there); false: loops among a device's own "
              "keyframes only"),
    ParamSpec("covered_m", 0.30, "a frame whose camera stands within this many metres of "
              "a keyframe that covers it (with merge_maps one another device uploaded, lent to "
              "this device's map; with own_coverage_after_slots one of the device's own of an "
              "earlier visit) and looks the same way (covered_deg) is not uploaded: the map "
              "holds that view (unless the map does not serve it: fewer than "
              "covered_min_points of the frame's reported points are the map's), and a slot's "
              "upload count shrinks with its share of views the map lacks; 0: every device "
              "uploads as Theorem 1 sizes it",
              low=0.0, high=100.0),
    ParamSpec("covered_deg", 20.0, "the turn, degrees, within which a keyframe covers a "
              "frame's view (with covered_m); the bounds' defaults tried on four devices along "
              "the synthetic corridor, judged on the 7-Scenes walk; on a long place walked by "
              "several people each at their own height and gaze, 0.5 m and 45 degrees saved a "
              "fifth of the later devices' uploads at a few tenths of a point more frames lost, "
              "and nothing in a room (docs/results/shared-map.md)",
              low=0.0, high=180.0),
    ParamSpec("covered_min_points", 50, "a covered frame (covered_m, covered_deg) is left "
              "out of the uploads only where at least this many of its reported points are the "
              "map's; below, it stays a candidate. 50 (ORB-SLAM's bar for tracking just after a "
              "relocalisation): a device in a mapped 7-Scenes place lost no more frames than "
              "alone and uploaded 42 % fewer in process, 68 % live; 15 (the device's tracking "
              "floor: any frame the map serves) uploaded 62 % and 80 % fewer but lost 5.6 "
              "points more of its frames in process, and cost the edge less time a slot "
              "(docs/results/shared-map.md)",
              low=0, high=1_000_000),
    ParamSpec("covered_by_points", False, "a tracked frame is also covered where at least "
              "covered_min_points of its reported points are points of keyframes another "
              "device lent this map, wherever the camera stands: on a long place several "
              "people walk each at their own height, sway and gaze, seldom within covered_m "
              "and covered_deg of another's keyframes, though their frames track on the points "
              "those keyframes made; four devices on walks of their own along the corridor "
              "uploaded 24-34 % fewer keyframes than alone (5-8 % without it) at 0.3-0.6 "
              "points more of their frames lost by the edge's rule, two in a room the same as "
              "without it (docs/results/shared-map.md); false: the pose alone decides"),
    ParamSpec("own_coverage_after_slots", 0, "a frame whose view one of the device's own "
              "keyframes of an earlier visit covers (within covered_m and covered_deg; "
              "restored from the archive, or uploaded at least this many slots before) is "
              "not uploaded either, as a lent keyframe's, while the camera heads where the "
              "device was before: a device coming back to where it was uploads what its map "
              "lacks there; 10 cut the uploads of walks that come back by 31-48 % and the "
              "edge's time a device by 36-61 %, with 0.17-0.32 points more frames lost on "
              "average (docs/results/shared-map.md); 0: its own keyframes cover nothing, and "
              "a device alone uploads as Theorem 1 sizes it (the paper's)",
              low=0, high=1_000_000),
    ParamSpec("fairness", 0.0, "alpha of the twin allocator's alpha-fair sum (0: total "
              "tracked share; 1: proportional fairness)", low=0.0, high=10.0),
    ParamSpec("device_silent_s", 10.0, "a device without summaries this long is silent: its "
              "map is kept, its share goes to the others", low=0.1, high=86_400.0),
    ParamSpec("diagnostics_period_s", 1.0, "seconds between two statuses of the edge's load "
              "on /diagnostics (diagnostic_msgs/DiagnosticArray, named '<node>: load'): the "
              "devices served, the slots answered and their latency, the slot work against "
              "compute_budget, each named thread's share of a core; WARN while the budget trims "
              "or a map came later than its slot; 0: none", low=0.0, high=3600.0),
    ParamSpec("compute_budget", 0.0, "share of one core the edge's slot work may take "
              "(planning, keyframes, bundle adjustment, map updates, over 10 s); over it the "
              "local bundle adjustment shrinks step by step (5, 3, 1 keyframes, none) and then, "
              "with loop_closing or merge_maps, no new loop search or place look starts (the "
              "worker's CPU and the interpreter it shares go to the slots; devices not merged "
              "yet wait to merge); below 60 % of it they come back, the searches first; 0: no "
              "budget", low=0.0, high=64.0),
    ParamSpec("device_reclaim_s", 60.0, "a device silent this much longer loses its map and "
              "its share", low=0.0, high=86_400.0),
)


def edge_config(p: Mapping[str, Any]) -> EdgeConfig:
    """The core's configuration from the node's parameters (V_max, α, D_req as they start)."""
    return EdgeConfig(slot=SlotConfig(vmax=int(p["vmax"]), alpha_mbit=float(p["alpha_mbit"]),
                                      d_req_s=float(p["d_req_s"]),
                                      progress=bool(p["progress_uploads"]),
                                      connected_map=bool(p["connected_map"])),
                      restore_keyframes=int(p["restore_keyframes"]),
                      reloc_restore_keyframes=int(p["reloc_restore_keyframes"]),
                      coverage=CoverageBounds(float(p["covered_m"]), float(p["covered_deg"]),
                                               int(p["covered_min_points"]),
                                               bool(p["covered_by_points"])),
                      own_coverage_after_slots=int(p["own_coverage_after_slots"]),
                      checkpoint_every=int(p["checkpoint_every"]),
                      back_end=BackEndConfig(
                          ba_window=int(p["ba_window"]),
                          archive_keyframes=int(p["archive_keyframes"]),
                          point_fusion=bool(p["point_fusion"]),
                          point_culling=bool(p["point_culling"]),
                          integration_fusion=bool(p["integration_fusion"]),
                          loop_closing=bool(p["loop_closing"]),
                          loops_across_devices=bool(p["loops_across_devices"]),
                          image_shape=(int(p["image_height"]), int(p["image_width"]))))


def link_settings(p: Mapping[str, Any]) -> LinkSettings:
    """What every device link of the node shares."""
    return LinkSettings(edge_config(p), str(p["checkpoint"]), int(p["states"]),
                        float(p["slot_timeout_s"]), bool(p["visualisation"]),
                        str(p["map_frame"]), int(p["trajectory_every"]))


def device_names(p: Mapping[str, Any]) -> list[str]:
    """The ``devices`` parameter as namespace names (no leading or trailing /)."""
    return [str(d).strip("/") for d in p["devices"]]
