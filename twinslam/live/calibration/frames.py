"""A live run's next-slot frames as calibration frames: the simulator's prediction beside the
device's outcome (the measures are :mod:`twinslam.live.calibration.prediction`'s).

The simulator's view needs, for every frame the device tracked, the recorded frame it is (the
player may play a sequence forward and back) and the covisibility of that recorded frame — the
map points our front end observes in it, extracted once from the same frames the player reads
(:func:`covisibility_file`, cached). Frames are matched to recorded frames by stamp: the player
stamps played position p at ``t0 + recorded_time(p) / rate``, ``t0`` being the first played
frame's stamp (the first ground-truth pose the monitor heard).

Each next-slot frame of slot k + 1 is predicted as the simulator scores it
(:mod:`twinslam.slot_protocol.lost_frame_rule`): its first frames against the map the edge published
after slot k - 1 (the update of slot k is still on its way), the rest against the map after
slot k; and, apart, against the map version the device actually tracked it with. Frames
tracked on the device's start-up map (map version 0) are counted apart, as are frames whose
recorded frame or keyframes cannot be placed — a covered-lens frame shows no recorded frame.
"""

from __future__ import annotations

import math
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from msg_schemas.headers import time_key, time_seconds
from twinslam.covisibility.dataset import CovisibilityDataset, save_covisibility
from twinslam.live.calibration.prediction import CalibrationFrame, FramePrediction, predict_frames
from twinslam.live.run_log import RunLog
from twinslam.live.scenarios import Scenario
from twinslam.live.tracking_quality import translation_errors
from twinslam.reporting import file_name
from twinslam.sequence_player.playback import Playback, PlayedSequence
from twinslam.sequences.decoded_frames import DecodedFrameCache
from twinslam.sequences.opening import AUTO, open_sequence
from twinslam.simulator.extraction import extract_covisibility
from twinslam.slam.map_update import MapSnapshot
from twinslam.slot_protocol import table1
from twinslam.slot_protocol.lost_frame_rule import MAP_UPDATE_LAG_FRAMES


@dataclass(frozen=True)
class PlayedFrames:
    """Which recorded frame the player showed at each played position, and when."""

    recorded_s: np.ndarray      #: per position: recorded seconds after the first played frame
    rows: np.ndarray            #: per position: the covisibility dataset's row (-1: none)
    rate: float = 1.0           #: playback speed

    def rows_at(self, stamps: np.ndarray, first_stamp: float) -> np.ndarray:
        """The dataset row of the frame played at each stamp (seconds); -1 where no played
        position lies within half a frame period."""
        t = (np.asarray(stamps, dtype=np.float64) - first_stamp) * self.rate
        if self.recorded_s.size == 0:
            return np.full(t.shape, -1, dtype=np.int64)
        pos = np.clip(np.searchsorted(self.recorded_s, t), 1, self.recorded_s.size - 1) \
            if self.recorded_s.size > 1 else np.zeros(t.shape, dtype=np.int64)
        if self.recorded_s.size > 1:
            left = self.recorded_s[pos - 1]
            pos = np.where(np.abs(t - left) <= np.abs(self.recorded_s[pos] - t), pos - 1, pos)
        period = float(np.median(np.diff(self.recorded_s))) if self.recorded_s.size > 1 \
            else 1.0
        near = np.abs(self.recorded_s[pos] - t) <= 0.5 * period
        return np.where(near, self.rows[pos], -1)


def played_frames(sequence: str, frames: int, scenario: Scenario, dataset: CovisibilityDataset,
                  rate: float = 1.0, start: int = 0,
                  frame_rate_hz: float = table1.FRAME_RATE_HZ) -> PlayedFrames:
    """What the player plays of ``sequence``'s ``frames`` frames from ``start`` in
    ``scenario``'s order, each position tied to the dataset row extracted from the same
    recorded frame (by its recorded stamp). The scenario's covered-lens burst (placed as the
    launcher places it, at the device's nominal ``frame_rate_hz``) shows no recorded frame:
    those positions have no row, so the calibration counts them apart instead of blaming a
    map for a frame no map could track."""
    reader = open_sequence(sequence, start, start + frames)
    played = PlayedSequence(reader, Playback(scenario.order))
    stamps = np.asarray(reader.stamps, dtype=np.float64)
    sources = np.asarray(played.positions, dtype=np.int64)
    if scenario.order == "forward":
        recorded = stamps[sources] - stamps[0]
    else:
        recorded = np.arange(sources.size) * played.period_s
    row_of = {}
    if dataset.stamps is not None:
        row_of = {float(s): r for r, s in enumerate(dataset.stamps)}
    rows = np.array([row_of.get(float(stamps[s]), -1) for s in sources], dtype=np.int64)
    burst = scenario.blank_burst(frames, frame_rate_hz)
    if burst is not None:
        rows[burst[0]:burst[0] + burst[1]] = -1
    return PlayedFrames(recorded, rows, rate)


def covisibility_file(sequence: str, frames: int, cache: Path,
                      echo: Callable[[str], None] = print, start: int = 0,
                      colour_intrinsics: str = "") -> Path:
    """The file holding the covisibility of ``sequence``'s ``frames`` frames from ``start``,
    as the front end the simulator's datasets come from extracts it, seen through the camera
    the player shows the device (its ``colour_intrinsics``: "" the folder's own, ``auto``, or
    a file); extracted into ``cache`` the first time, read from there afterwards."""
    camera = "" if not colour_intrinsics else (
        "-auto" if colour_intrinsics == AUTO else f"-{Path(colour_intrinsics).stem}")
    slug = file_name(f"{Path(sequence).name or sequence}-{start}-{frames}{camera}", "-_.", "_")
    path = cache / f"{slug}.covis.npz"
    if path.is_file():
        if whole_archive(path):
            return path
        echo(f"{path} is cut off or damaged (a run stopped while writing it?): extracting it "
             "again")
    # the frames the runs played: read back decoded where the player's cache holds them
    reader = open_sequence(sequence, start, start + frames, colour_intrinsics,
                           frame_cache=DecodedFrameCache.from_environment())
    echo(f"extracting the covisibility of {len(reader)} frames of {sequence} for the "
         f"calibration (once; cached in {path})")
    dataset, _, _ = extract_covisibility(reader)
    cache.mkdir(parents=True, exist_ok=True)
    save_covisibility(path, dataset)
    return path


def whole_archive(path: Path) -> bool:
    """Whether ``path`` is a whole zip archive (an ``.npz``), every member's checksum right."""
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.testzip() is None
    except (OSError, EOFError, zlib.error, zipfile.BadZipFile):
        return False


@dataclass(frozen=True)
class LiveFrame:
    """One next-slot frame of a run, ready for the calibration figures and the CSV."""

    slot: int
    position: int                       #: its place in the slot (0: the slot's first frame)
    frame_id: int
    row: int                            #: its recorded frame's dataset row
    map_version: int                    #: the map the device tracked it with
    calibration: CalibrationFrame       #: predicted against the map after the previous slot
    on_tracked_map: FramePrediction     #: predicted against the map it was tracked with
    #: map points it shares with every keyframe the edge had integrated by the map it was
    #: tracked with — the most any map the edge could have sent then would share (the edge
    #: keeps what it evicts in its archive)
    archive_shared_points: int = 0


@dataclass
class LiveFrames:
    frames: list[LiveFrame] = field(default_factory=list)
    startup: int = 0        #: next-slot frames tracked on the start-up map (counted apart)
    unplaced: int = 0       #: frames whose recorded frame or map keyframes could not be placed


def _integrated_rows(by_version: dict[int, MapSnapshot], row_of: dict[int, int]
                     ) -> dict[int, np.ndarray]:
    """For each map version, the dataset rows of every keyframe a map up to it held: what the
    edge had integrated by then (each upload enters a map once)."""
    seen: set[int] = set()
    out = {}
    for version in sorted(by_version):
        seen.update(r for k in by_version[version].keyframe_ids
                    if (r := row_of.get(int(k), -1)) >= 0)
        out[version] = np.array(sorted(seen), dtype=np.int64)
    return out


def _at_or_before(integrated: dict[int, np.ndarray], version: int) -> np.ndarray:
    """The rows integrated by map ``version``: those of the newest recorded version not after
    it (the monitor keeps a slot's last map, so a version sent and replaced within one slot
    is not among them); none before the first."""
    known = [v for v in integrated if v <= version]
    return integrated[max(known)] if known else np.zeros(0, np.int64)


def live_frames(record: RunLog, dataset: CovisibilityDataset, played: PlayedFrames,
                log_det_pi: float = 0.0, lag_frames: int = MAP_UPDATE_LAG_FRAMES) -> LiveFrames:
    """Every next-slot frame of the run (slots after the first whose previous map arrived),
    predicted by the simulator's rule and paired with the device's outcome: the first
    ``lag_frames`` frames of slot k + 1 against the map after slot k - 1 (where there was
    one), the rest against the map after slot k."""
    out = LiveFrames()
    frames = [(slot, f) for slot in sorted(record.summaries)
              for f in record.summaries[slot].frames]
    if not frames:
        return out
    stamps = np.array([time_seconds(f.stamp) for _, f in frames])
    first = (min(record.ground_truth) * 1e-9 if record.ground_truth else float(stamps.min()))
    rows = played.rows_at(stamps, first)
    row_of = {int(f.frame_id): int(r) for (_, f), r in zip(frames, rows, strict=True)}
    errors = translation_errors(record.poses, record.ground_truth)
    by_version: dict[int, MapSnapshot] = {m.version: m for m in record.maps.values()}
    integrated = _integrated_rows(by_version, row_of)

    def keyframe_rows(snapshot: MapSnapshot | None) -> list[int] | None:
        if snapshot is None:
            return None
        placed = [row_of.get(int(k), -1) for k in snapshot.keyframe_ids]
        return None if any(r < 0 for r in placed) else placed

    def predict(snapshot: MapSnapshot | None, cand: list[int]) -> list[FramePrediction] | None:
        map_rows = keyframe_rows(snapshot)
        return None if map_rows is None else predict_frames(dataset, map_rows, cand, log_det_pi)

    for slot in sorted(record.summaries):
        after = record.maps.get(slot - 1)
        if slot == 0 or after is None:
            continue
        before = record.maps.get(slot - 2)
        slot_frames = list(record.summaries[slot].frames)
        out.startup += sum(int(f.map_version) == 0 for f in slot_frames)
        scored = [(i, f) for i, f in enumerate(slot_frames) if int(f.map_version) > 0]
        placed = [(i, f) for i, f in scored if row_of[int(f.frame_id)] >= 0]
        out.unplaced += len(scored) - len(placed)
        early = [(i, f) for i, f in placed if i < lag_frames and before is not None]
        late = [(i, f) for i, f in placed if not (i < lag_frames and before is not None)]
        for snapshot, group in ((before, early), (after, late)):
            if not group:
                continue
            predicted = predict(snapshot, [row_of[int(f.frame_id)] for _, f in group])
            if predicted is None:
                out.unplaced += len(group)
                continue
            for (i, f), pred in zip(group, predicted, strict=True):
                row = row_of[int(f.frame_id)]
                used = predict(by_version.get(int(f.map_version)), [row])
                error = errors.get(time_key(f.stamp), math.nan)
                archive = _at_or_before(integrated, int(f.map_version))
                out.frames.append(LiveFrame(
                    slot, i, int(f.frame_id), row, int(f.map_version),
                    CalibrationFrame(pred, bool(f.tracked), int(f.inliers), error),
                    used[0] if used else FramePrediction(0, 0.0, math.inf),
                    int(dataset.shared_points(archive, np.array([row]))[0])
                    if archive.size else 0))
    out.frames.sort(key=lambda f: (f.slot, f.position))
    return out
