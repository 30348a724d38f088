"""Does the simulator's score predict the device? (docs/architecture.md §2)

The simulator judges a map by the next slot's frames: a frame that shares too few map points
with the keyframes the edge kept is *lost*, the others score u(G ∪ {f}). Policies are trained
and ranked on that score, so it is worth what it predicts about the live device. For each
next-slot frame of a live run this module puts the simulator's view beside the device's
outcome:

* **prediction** (:func:`predict_frames`) — from the covisibility dataset of the played
  sequence (the map points our front end observes in each recorded frame, the simulator's
  data) and the keyframes the edge's map held: the map points the frame shares with them,
  its covisibility weight to them, and u(G ∪ {f});
* **outcome** — whether the device tracked the frame against the edge's map, with how many
  PnP inliers, and its translation error against ground truth.

:func:`calibrate` condenses a run's frames into the figures ``calibration.csv`` reports:
predicted lost share and device failure share, precision and recall of "lost" for "device
failure", and Spearman's rank correlation of u with the translation error and with the
inlier count (over the frames the device tracked and the simulator scores finitely).
:func:`fit_min_shared` finds the threshold k of "lost: fewer than k shared map points" that
best separates the device's failures from its tracked frames; :func:`level_min_shared` the one
at which the predicted lost share reaches the device's failure share (the objective counts
lost frames, so their number is what it must get right).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.uncertainty.map_uncertainty import augmented_uncertainties


@dataclass(frozen=True)
class FramePrediction:
    """The simulator's view of one next-slot frame against a map."""

    shared_points: int        #: |M_f ∩ ∪_{v ∈ map} M_v|: map points the frame could match
    covisibility: float       #: Σ_v w(f, v), the frame's weight to the map's keyframes
    uncertainty: float        #: u(G ∪ {f}); +inf if it shares nothing or leaves G disconnected

    def lost(self, min_shared: int) -> bool:
        """Lost by the rule "fewer than ``min_shared`` shared map points" (or no finite u)."""
        return self.shared_points < min_shared or not math.isfinite(self.uncertainty)


def predict_frames(dataset: CovisibilityDataset, map_frames: Sequence[int],
                   frames: Sequence[int], log_det_pi: float = 0.0) -> list[FramePrediction]:
    """The prediction for each of ``frames`` (dataset indices) against the map of the
    keyframes ``map_frames`` (dataset indices; oldest first, a revisited place may appear
    twice). An empty map predicts every frame lost."""
    map_idx = np.asarray(map_frames, dtype=np.int64)
    cand_idx = np.asarray(frames, dtype=np.int64)
    if cand_idx.size == 0:
        return []
    if map_idx.size == 0:
        return [FramePrediction(0, 0.0, math.inf) for _ in frames]
    map_w = dataset.weights(map_idx, map_idx)
    # two instances of one recorded frame are one place seen twice: their weight stays, but a
    # frame shares no edge with itself
    np.fill_diagonal(map_w, 0.0)
    cand_w = dataset.weights(cand_idx, map_idx)
    u = augmented_uncertainties(map_w, cand_w, log_det_pi)
    shared = dataset.shared_points(map_idx, cand_idx)
    return [FramePrediction(int(s), float(w), float(x))
            for s, w, x in zip(shared, cand_w.sum(axis=1), u, strict=True)]


#: why the device failed a frame (:func:`failure_cause`)
NEW_GROUND = "new ground"
LEFT_OUT = "left out of the map"
MAP_COVERED = "map covered it"
FAILURE_CAUSES = (NEW_GROUND, LEFT_OUT, MAP_COVERED)


def failure_cause(shared_tracked_map: int, shared_archive: int, min_shared: int) -> str:
    """Why the device failed a frame, by what the edge could have sent it: **new ground**
    when even every keyframe the edge had integrated shares fewer than ``min_shared`` map
    points with it (no map could have held the place: only an earlier upload would have);
    **left out of the map** when those keyframes cover it but the map the device held did
    not (which keyframes to keep or restore: the policy's choice); **map covered it** when the
    device's map shared enough points and it still failed (tracking: matching, the motion
    model, relocalisation). The shares of the three say which lever a run is short of."""
    if shared_archive < min_shared:
        return NEW_GROUND
    if shared_tracked_map < min_shared:
        return LEFT_OUT
    return MAP_COVERED


@dataclass(frozen=True)
class CalibrationFrame:
    """One next-slot frame: the simulator's prediction beside the device's outcome."""

    prediction: FramePrediction
    device_tracked: bool      #: tracked against the edge's map (not its start-up map)
    inliers: int              #: PnP inliers of its pose (0 when not tracked)
    translation_error_m: float   #: against ground truth after alignment; NaN without it


@dataclass(frozen=True)
class Calibration:
    """How well "lost" and u predicted the device over a set of frames."""

    frames: int
    predicted_lost_share: float
    device_failure_share: float
    precision: float          #: P(device failed | predicted lost); NaN if none predicted
    recall: float             #: P(predicted lost | device failed); NaN if none failed
    spearman_u_error: float   #: ρ(u, translation error) over tracked, finitely scored frames
    spearman_u_inliers: float   #: ρ(u, inliers) over the same frames

    @property
    def fields(self) -> dict[str, float]:
        return dict(self.__dict__)


def _ratio(num: int, den: int) -> float:
    return num / den if den else math.nan


def _spearman(a: Sequence[float], b: Sequence[float]) -> float:
    """Spearman's ρ; NaN with fewer than 3 pairs or a constant side."""
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    if x.size < 3 or np.ptp(x) == 0 or np.ptp(y) == 0:
        return math.nan
    # scipy.stats takes 0.4 s to import: loaded only where a ρ is measured
    from scipy.stats import spearmanr

    return float(spearmanr(x, y).statistic)


def calibrate(frames: Iterable[CalibrationFrame], min_shared: int) -> Calibration:
    """The calibration figures of ``frames`` under the rule "lost: fewer than
    ``min_shared`` shared map points"."""
    rows = list(frames)
    lost = [f.prediction.lost(min_shared) for f in rows]
    failed = [not f.device_tracked for f in rows]
    both = sum(p and d for p, d in zip(lost, failed, strict=True))
    scored = [f for f, p in zip(rows, lost, strict=True)
              if f.device_tracked and not p]
    return Calibration(
        frames=len(rows), predicted_lost_share=_ratio(sum(lost), len(rows)),
        device_failure_share=_ratio(sum(failed), len(rows)),
        precision=_ratio(both, sum(lost)), recall=_ratio(both, sum(failed)),
        spearman_u_error=_spearman([f.prediction.uncertainty for f in scored],
                                   [f.translation_error_m for f in scored]),
        spearman_u_inliers=_spearman([f.prediction.uncertainty for f in scored],
                                     [float(f.inliers) for f in scored]))


def balanced_accuracy(frames: Sequence[CalibrationFrame], min_shared: int) -> float:
    """Mean of the rule's recall on the device's failures and on its tracked frames: a rule
    that calls everything lost (or nothing) scores 0.5, whatever the failure share."""
    fails = [f for f in frames if not f.device_tracked]
    tracked = [f for f in frames if f.device_tracked]
    if not fails or not tracked:
        return math.nan
    hit = sum(f.prediction.lost(min_shared) for f in fails) / len(fails)
    kept = sum(not f.prediction.lost(min_shared) for f in tracked) / len(tracked)
    return 0.5 * (hit + kept)


class _SharedCounts:
    """How many of a set of frames each rule "lost: fewer than k shared map points" calls
    lost, for any k at once: the frames no k can keep (no finite u) plus those of the rest
    with fewer than k points — a binary search in their sorted counts, where trying two
    hundred thresholds frame by frame took seconds on a ten-run evaluation."""

    def __init__(self, frames: Sequence[CalibrationFrame]) -> None:
        shared = np.array([f.prediction.shared_points for f in frames], dtype=np.int64)
        finite = np.isfinite(np.array([f.prediction.uncertainty for f in frames],
                                      dtype=np.float64))
        self.size = len(frames)
        self.always_lost = int(np.count_nonzero(~finite))
        self._sorted = np.sort(shared[finite])

    def lost(self, candidates: Sequence[int]) -> list[int]:
        """The number of frames each of ``candidates`` calls lost."""
        below = np.searchsorted(self._sorted, np.asarray(candidates, dtype=np.int64),
                                side="left")
        return [self.always_lost + int(n) for n in below]


def fit_min_shared(frames: Sequence[CalibrationFrame], candidates: Iterable[int] = range(1, 201)
                   ) -> tuple[int, float]:
    """(k, balanced accuracy) of the threshold that best separates the device's failures
    from its tracked frames (:func:`balanced_accuracy`, each k's); the smallest such k on
    ties. ValueError when the frames hold no failure or no tracked frame (nothing to
    separate)."""
    ks = list(candidates)
    fails = _SharedCounts([f for f in frames if not f.device_tracked])
    tracked = _SharedCounts([f for f in frames if f.device_tracked])
    if not fails.size or not tracked.size:
        if not ks:
            raise ValueError("no threshold to try")
        raise ValueError("the frames need device failures and tracked frames to fit a "
                         "threshold")
    best: tuple[int, float] | None = None
    for k, hit, dropped in zip(ks, fails.lost(ks), tracked.lost(ks), strict=True):
        score = 0.5 * (hit / fails.size + (tracked.size - dropped) / tracked.size)
        if best is None or score > best[1] + 1e-12:
            best = (k, score)
    if best is None:
        raise ValueError("no threshold to try")
    return best


def level_min_shared(frames: Sequence[CalibrationFrame], candidates: Iterable[int] = range(1, 201)
                     ) -> int:
    """The smallest k at which the share of ``frames`` predicted lost reaches the share the
    device failed; ValueError when no candidate does (or there are no frames)."""
    rows = list(frames)
    if not rows:
        raise ValueError("no frames to level a threshold on")
    failed = sum(not f.device_tracked for f in rows) / len(rows)
    ks = list(candidates)
    for k, lost in zip(ks, _SharedCounts(rows).lost(ks), strict=True):
        if lost / len(rows) >= failed:
            return k
    raise ValueError(f"no threshold predicts the device's failure share {failed:.1%}")
