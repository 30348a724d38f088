"""When a frame loses tracking: the rule the simulator, the edge's MapStats, training and every
figure share, measured on the live device (``twinslam evaluate``'s calibration).

One rule — the device tracks a frame when it matches enough points of the map it holds — in
the units of whoever counts: the device and the edge's ``MapStats`` count the device's own
matches (:data:`MIN_INLIERS`, its PnP threshold); the simulator counts the map points its
covisibility dataset says a frame shares with the kept keyframes (:data:`MIN_SHARED_POINTS`,
measured to predict the same failures).

The paper scores a next-slot frame by u(G ∪ {f}) and calls it lost (u = ∞) when it shares no
map point. The live device (``map_source: edge``, the paper's device) lives by two facts that
rule leaves out:

* **it needs enough points**, not one: PnP needs ``min_inliers`` = 15 inliers, and the
  simulator's point sets (our front end's map points per recorded frame, guided over the whole
  map) are not the edge's map points one for one. :data:`MIN_SHARED_POINTS` is the threshold
  on the shared map points the simulator counts at which the predicted lost share reaches the
  share of frames the device failed, over every next-slot frame of the tuning runs (36 live
  runs, 7-Scenes frames 500-799 forward and back — a stretch the evaluation does not play —
  V_max 15 / 25 and an uplink with outages, LFF / PU / ADAPT / random, seeds 100-102, 16 648
  frames: the device failed 30.4 %; ``twinslam calibrate``): balanced accuracy 0.904, where the
  best any threshold reaches is 0.906 (at 37), and the per-run predicted and failed shares
  correlate at r = 0.98. The paper's rule (1) predicts 0.9 % of those frames lost.
* **the update comes late**: slot k's uploads take up to D_req and the edge then integrates,
  optimises and publishes, so the first frames of slot k + 1 are still tracked against the map
  before (the paper's timeline sends the update "within the subsequent time slot"). In the same
  runs the device tracked a median of 20 frames a slot (mean 17.8; 0.6 s at 30 Hz) with the
  previous map version: D_req plus :data:`MAP_UPDATE_DELAY_S`.

A frame the device loses has no pose, so it cannot become a keyframe: the simulator, like the
edge (``FrameObservations.tracked``), never uploads one.
"""

from __future__ import annotations

from twinslam.slot_protocol import table1

#: PnP inliers the device needs to track a frame; the edge's MapStats calls a next-slot frame
#: lost when its reported map points share fewer with the map than this
MIN_INLIERS = 15
#: the simulator calls a next-slot frame lost when it shares fewer map points than this with
#: the map it is tracked against (1 would be the paper's "shares no map point")
MIN_SHARED_POINTS = 35
#: seconds from the end of a slot's uploads (D_req) to the device holding the new map
MAP_UPDATE_DELAY_S = 0.13


def update_lag_frames(d_req_s: float = table1.D_REQ_S,
                      frame_rate_hz: float = table1.FRAME_RATE_HZ) -> int:
    """How many first frames of a slot are tracked against the map before the last update."""
    return max(0, round((d_req_s + MAP_UPDATE_DELAY_S) * frame_rate_hz))


#: the lag at the paper's D_req (0.5 s) and 30 Hz: 19 frames
MAP_UPDATE_LAG_FRAMES = update_lag_frames()
