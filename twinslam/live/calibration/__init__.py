"""Does the simulator's rule of a lost frame predict the live device? Calibration, in one place.

* :mod:`twinslam.live.calibration.prediction` — the simulator's view of a next-slot frame (the
  map points it shares with the kept keyframes, its covisibility, u(G ∪ {f})) beside the
  device's outcome, and the measures over many frames: precision and recall of "lost", the
  threshold k fitted on them;
* :mod:`twinslam.live.calibration.frames` — a live run's next-slot frames as calibration
  frames: each matched by stamp to the recorded frame it is, the covisibility of the played
  frames extracted once through the camera the device sees;
* :mod:`twinslam.live.calibration.report` — what ``twinslam calibrate`` prints from the
  ``calibration.csv`` and ``calibration_frames.csv`` evaluate wrote: the rule's agreement per
  map source and scenario, where the failed frames come from, the figure.

The rule itself is a constant of the slot protocol
(:mod:`twinslam.slot_protocol.lost_frame_rule`), read by the simulator, the edge and the
device alike; what measures it lives here, beside the live runs it is measured on.
"""
