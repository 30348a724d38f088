"""The calibration of the simulator against the device on hand-made frames: what the
simulator predicts for a frame given the kept keyframes, the figures calibration.csv reports,
the threshold fit, and how a live run's frames are placed on recorded frames and maps."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from device_tracker.messages import FrameRecord, frame_summaries_message
from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.live.calibration.frames import PlayedFrames, live_frames, played_frames
from twinslam.live.calibration.prediction import (
    LEFT_OUT,
    MAP_COVERED,
    NEW_GROUND,
    CalibrationFrame,
    FramePrediction,
    balanced_accuracy,
    calibrate,
    failure_cause,
    fit_min_shared,
    level_min_shared,
    predict_frames,
)
from twinslam.live.run_log import RunLog
from twinslam.live.scenarios import Scenario
from twinslam.sequences.opening import open_sequence
from twinslam.slam.map_update import MapSnapshot
from twinslam.uncertainty.map_uncertainty import augmented_uncertainties

#: recorded frames 0..4 and the map points each observes
SETS = [{1, 2, 3, 4}, {3, 4, 5, 6}, {2, 3, 5, 9}, {7, 8}, {4, 6, 10}]


def test_prediction_counts_distinct_shared_points_weights_and_u() -> None:
    data = CovisibilityDataset.from_sets([np.array(sorted(s)) for s in SETS],
                                         stamps=np.arange(5) / 30.0)
    preds = predict_frames(data, [0, 1], [2, 3, 4])
    # frame 2 shares {2, 3, 5}: 3 distinct points, weights 2 (to 0) + 2 (to 1)
    assert (preds[0].shared_points, preds[0].covisibility) == (3, 4.0)
    # frame 3 shares nothing: lost whatever the threshold, u infinite
    assert preds[1].shared_points == 0 and math.isinf(preds[1].uncertainty)
    assert preds[1].lost(1) and not preds[0].lost(3) and preds[0].lost(4)
    # u as the uncertainty library computes it for the same weights
    w = np.array([[0.0, 2.0], [2.0, 0.0]])
    expected = augmented_uncertainties(w, np.array([[2.0, 2.0], [0.0, 0.0], [1.0, 2.0]]))
    assert [p.uncertainty for p in preds] == pytest.approx(list(expected))
    # a place seen twice (the same recorded frame in the map and as a candidate) shares all
    again = predict_frames(data, [0, 1], [1])[0]
    assert again.shared_points == 4 and math.isfinite(again.uncertainty)
    assert all(p.shared_points == 0 for p in predict_frames(data, [], [0, 1]))


def _frame(shared: int, tracked: bool, inliers: int = 0, error: float = math.nan,
           u: float | None = None) -> CalibrationFrame:
    value = -10.0 * shared if u is None else u
    return CalibrationFrame(FramePrediction(shared, float(shared), value if shared else math.inf),
                            tracked, inliers, error)


def test_calibration_figures_on_hand_made_frames() -> None:
    frames = [
        _frame(0, False), _frame(3, False),                   # predicted lost, device failed
        _frame(4, True, 16, 0.30),                            # predicted lost, tracked
        _frame(20, False),                                    # predicted fine, failed
        _frame(30, True, 20, 0.20), _frame(50, True, 40, 0.10), _frame(70, True, 60, 0.05),
    ]
    c = calibrate(frames, min_shared=5)
    assert c.frames == 7
    assert c.predicted_lost_share == pytest.approx(3 / 7)
    assert c.device_failure_share == pytest.approx(3 / 7)
    assert c.precision == pytest.approx(2 / 3) and c.recall == pytest.approx(2 / 3)
    # over the tracked frames the simulator scores: lower u, more inliers, smaller error
    assert c.spearman_u_inliers == pytest.approx(-1.0)
    assert c.spearman_u_error == pytest.approx(1.0)
    nothing_lost = calibrate([_frame(30, True, 20, 0.1), _frame(40, True, 30, 0.1)], 5)
    assert math.isnan(nothing_lost.precision) and math.isnan(nothing_lost.recall)
    assert math.isnan(nothing_lost.spearman_u_error), "fewer than 3 pairs"


def test_the_fitted_threshold_separates_failures_from_tracked_frames() -> None:
    frames = ([_frame(s, False) for s in (0, 2, 5, 7, 9)]
              + [_frame(s, True, 20) for s in (11, 12, 15, 30, 80, 8)])
    k, score = fit_min_shared(frames, range(1, 60))
    assert k == 10                 # 0..9 fail, 11+ track; the tracked frame at 8 is the miss
    assert score == pytest.approx(0.5 * (5 / 5 + 5 / 6))
    assert balanced_accuracy(frames, 1) == pytest.approx(0.5 * (1 / 5 + 1.0))
    assert balanced_accuracy(frames, 1000) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="failures and tracked frames"):
        fit_min_shared([_frame(5, True)])
    # 5 of 11 frames failed: k = 10 calls 0, 2, 5, 7, 9 and the tracked 8 lost (6 of 11);
    # k = 9 calls 0, 2, 5, 7, 8 lost (5 of 11): the first to reach the failure share
    assert level_min_shared(frames, range(1, 60)) == 9
    with pytest.raises(ValueError, match="no threshold"):
        level_min_shared(frames, range(1, 3))


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 60), st.booleans(), st.booleans()), min_size=1,
                max_size=40))
def test_the_thresholds_counted_at_once_are_the_ones_tried_frame_by_frame(
        rows: list[tuple[int, bool, bool]]) -> None:
    """The fit and the levelling count every threshold's lost frames by a search in the
    sorted counts; each must pick what trying every k on every frame picks (ties to the
    smallest k; a frame without a finite u lost at any k)."""
    frames = [CalibrationFrame(FramePrediction(n, float(n), -1.0 * n if finite else math.inf),
                               tracked, 0, math.nan) for n, tracked, finite in rows]
    ks = range(1, 70)
    scores = [balanced_accuracy(frames, k) for k in ks]
    if any(math.isnan(x) for x in scores):
        with pytest.raises(ValueError, match="failures and tracked frames"):
            fit_min_shared(frames, ks)
    else:
        best_k, best = 0, -1.0
        for k, score in zip(ks, scores, strict=True):
            if score > best + 1e-12:
                best_k, best = k, score
        assert fit_min_shared(frames, ks) == (best_k, best)
    failed = sum(not f.device_tracked for f in frames) / len(frames)
    levelled = [k for k in ks
                if sum(f.prediction.lost(k) for f in frames) / len(frames) >= failed]
    if levelled:
        assert level_min_shared(frames, ks) == levelled[0]
    else:
        with pytest.raises(ValueError, match="no threshold"):
            level_min_shared(frames, ks)


def test_played_stamps_find_their_recorded_frames() -> None:
    # forward then back over recorded frames 0..3 (rows 10..13), 30 Hz, replayed at 2x
    played = PlayedFrames(np.arange(7) / 30.0, np.array([10, 11, 12, 13, 12, 11, 10]), 2.0)
    t0 = 100.0
    stamps = t0 + np.array([0, 1, 2, 3, 5, 6]) / 60.0 + 0.002      # position 4 never came
    assert played.rows_at(stamps, t0).tolist() == [10, 11, 12, 13, 11, 10]
    assert played.rows_at(np.array([t0 + 1.0, t0 - 1.0]), t0).tolist() == [-1, -1]


def test_a_covered_lens_shows_no_recorded_frame_so_the_calibration_counts_it_apart() -> None:
    """The scenario's covered-lens burst, placed as the launcher places it, has no dataset
    row: no map could have tracked those frames, so none of them is blamed on a map."""
    reader = open_sequence("synthetic:10")
    data = CovisibilityDataset.from_sets([np.arange(5) + i for i in range(10)],
                                         stamps=np.asarray(reader.stamps, dtype=np.float64))
    covered = Scenario("covered", "forward and back, lens covered", order="forward_backward",
                       blank_at=0.5, blank_s=0.1)
    burst = covered.blank_burst(10, 30.0)
    assert burst == (9, 3)
    rows = played_frames("synthetic:10", 10, covered, data).rows
    assert rows.tolist() == [*range(9), -1, -1, -1, *range(6, -1, -1)]
    plain = dataclasses.replace(covered, blank_at=None)
    assert (played_frames("synthetic:10", 10, plain, data).rows >= 0).all()


def _record(records_by_slot: dict[int, list[FrameRecord]], maps: dict[int, MapSnapshot]
            ) -> RunLog:
    record = RunLog()
    for slot, frames in records_by_slot.items():
        record.summaries[slot] = frame_summaries_message(slot, 40.0, 0, 0, frames, time.time())
    record.maps = maps
    return record


def _snapshot(version: int, keyframes: list[int]) -> MapSnapshot:
    none = np.zeros(0, np.uint64)
    return MapSnapshot(version, np.array(keyframes, np.uint64), np.zeros((0, 4, 4)), none,
                       np.zeros((0, 3)), np.zeros((0, 32), np.uint8), np.zeros(0, np.uint32))


def test_live_frames_are_predicted_against_the_map_before_their_slot() -> None:
    """Slot 1's frames against the map after slot 0; a frame still tracked with the older map
    is also predicted against that one; start-up map frames are counted apart."""
    data = CovisibilityDataset.from_sets([np.array(sorted(s)) for s in SETS],
                                         stamps=np.arange(5) / 30.0)
    played = PlayedFrames(np.arange(5) / 30.0, np.arange(5))

    def rec(i: int, tracked: bool, inliers: int, version: int, slot: int) -> FrameRecord:
        return FrameRecord(i, 50.0 + i / 30.0, np.eye(4), tracked, np.zeros(0, np.uint64),
                           np.zeros(0, np.uint64), slot, False, inliers, version)

    record = _record({0: [rec(0, True, 0, 0, 0), rec(1, True, 30, 0, 0)],
                      1: [rec(2, True, 25, 1, 1), rec(3, False, 0, 1, 1),
                          rec(4, True, 18, 2, 1)],
                      2: []},
                     {0: _snapshot(1, [0]), 1: _snapshot(2, [0, 1])})
    out = live_frames(record, data, played, lag_frames=0)
    assert out.startup == 0 and out.unplaced == 0
    assert [(f.slot, f.position, f.row) for f in out.frames] == [(1, 0, 2), (1, 1, 3),
                                                                   (1, 2, 4)]
    by_row = {f.row: f for f in out.frames}
    # against the map after slot 0 (keyframe 0 = recorded frame 0): frame 2 shares {2, 3}
    assert by_row[2].calibration.prediction.shared_points == 2
    assert by_row[3].calibration.prediction.lost(1) and not by_row[3].calibration.device_tracked
    # frame 4 was tracked with map version 2 (keyframes 0 and 1): shares {4, 6}
    assert by_row[4].calibration.prediction.shared_points == 1
    assert by_row[4].on_tracked_map.shared_points == 2 and by_row[4].map_version == 2
    assert by_row[2].calibration.inliers == 25

    startup = _record({0: [rec(0, True, 0, 0, 0)], 1: [rec(1, True, 30, 0, 1)]},
                      {0: _snapshot(1, [0])})
    counted = live_frames(startup, data, played, lag_frames=0)
    assert counted.startup == 1 and not counted.frames


def test_the_first_frames_of_a_slot_are_predicted_against_the_map_before() -> None:
    """With a lag of one frame, slot 2's first frame is predicted against the map after slot
    0 (the update of slot 1 is still on its way), the second against the map after slot 1;
    slot 1 has no map before it, so all its frames go against the map after slot 0."""
    data = CovisibilityDataset.from_sets([np.array(sorted(s)) for s in SETS],
                                         stamps=np.arange(5) / 30.0)
    played = PlayedFrames(np.arange(5) / 30.0, np.arange(5))

    def rec(frame_id: int, row: int, slot: int) -> FrameRecord:
        return FrameRecord(frame_id, 50.0 + row / 30.0, np.eye(4), True, np.zeros(0, np.uint64),
                           np.zeros(0, np.uint64), slot, False, 20, 1)

    record = _record({0: [rec(0, 0, 0), rec(1, 1, 0)], 1: [rec(2, 3, 1), rec(3, 2, 1)],
                      2: [rec(5, 4, 2), rec(6, 2, 2)]},
                     {0: _snapshot(1, [0]), 1: _snapshot(2, [0, 1])})
    shared = {(f.slot, f.position): f.calibration.prediction.shared_points
              for f in live_frames(record, data, played, lag_frames=1).frames}
    # row 4 = {4, 6, 10}: one point with map {row 0}, two with map {rows 0, 1}
    assert shared[(2, 0)] == 1 and shared[(2, 1)] == 3
    # slot 1: row 3 = {7, 8} shares nothing with {row 0}; row 2 shares {2, 3}
    assert shared[(1, 0)] == 0 and shared[(1, 1)] == 2
    without = {(f.slot, f.position): f.calibration.prediction.shared_points
               for f in live_frames(record, data, played, lag_frames=0).frames}
    assert without[(2, 0)] == 2


def test_agreement_per_scenario_on_hand_made_runs(tmp_path) -> None:
    """The calibration table: per map source and scenario the mean shares, their mean absolute
    error and r over runs; a run with no scored frame is left out."""
    import csv

    from twinslam.live.calibration.report import agreement_by_scenario, read_rows
    from twinslam.live.runs import CALIBRATION_HEADER

    runs = [("v15", 0, 0.10, 0.12), ("v15", 1, 0.20, 0.18), ("v15", 2, 0.40, 0.45),
            ("v25", 0, 0.30, 0.10), ("v25", 1, 0.10, 0.30), ("v25", 2, 0.20, 0.20)]
    with (tmp_path / "calibration.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(CALIBRATION_HEADER)
        for scenario, seed, predicted, failed in runs:
            w.writerow([scenario, "edge", "lff", seed, "", 35, 2, 0, 100, predicted, failed,
                        0.8, 0.7, "nan", -0.2])
        w.writerow(["v25", "edge", "lff", 3, "", 35, 2, 0, 0, "nan", "nan", "nan", "nan",
                    "nan", "nan"])
    rows = {a.scenario: a for a in agreement_by_scenario(read_rows([tmp_path], "calibration.csv"))}
    assert list(rows) == ["v15", "v25", "all"]
    v15, v25 = rows["v15"], rows["v25"]
    assert v15.runs == 3 and v25.runs == 3 and rows["all"].runs == 6
    assert v15.predicted_lost_share == pytest.approx(0.70 / 3)
    assert v15.device_failure_share == pytest.approx(0.75 / 3)
    assert v15.mean_abs_error == pytest.approx(0.09 / 3)
    assert v15.r_over_runs > 0.95 and v25.r_over_runs == pytest.approx(-1.0)
    assert v15.precision == pytest.approx(0.8) and v15.spearman_u_inliers == pytest.approx(-0.2)
    assert math.isnan(v15.spearman_u_error)           # no run measured it


def test_a_failed_frame_is_new_ground_left_out_or_covered_by_what_the_edge_had() -> None:
    """The archive's reach is every keyframe a map up to the device's held: a frame no such
    keyframe covers is new ground, one they cover but the device's map does not was left out,
    one the device's map covers failed in tracking."""
    data = CovisibilityDataset.from_sets([np.array(sorted(s)) for s in SETS],
                                         stamps=np.arange(5) / 30.0)
    played = PlayedFrames(np.arange(5) / 30.0, np.arange(5))

    def rec(frame_id: int, row: int, version: int, slot: int) -> FrameRecord:
        return FrameRecord(frame_id, 50.0 + row / 30.0, np.eye(4), version == 0,
                           np.zeros(0, np.uint64), np.zeros(0, np.uint64), slot, False, 0,
                           version)

    # map 1 holds recorded frames 0 and 1, map 2 only 1 (0 evicted, still in the archive)
    record = _record({0: [rec(0, 0, 0, 0), rec(1, 1, 0, 0)], 1: [rec(5, 3, 1, 1)],
                      2: [rec(6, 0, 2, 2), rec(7, 2, 2, 2), rec(8, 4, 1, 2)],
                      3: [rec(9, 2, 4, 3)]},
                     {0: _snapshot(1, [0, 1]), 1: _snapshot(2, [1]), 2: _snapshot(3, [1])})
    scored = live_frames(record, data, played, lag_frames=0).frames
    # map version 4 never reached the monitor: its archive is that of version 3 (rows 0, 1)
    assert [(f.map_version, f.archive_shared_points) for f in scored if f.slot == 3] == [(4, 3)]
    frames = {f.row: f for f in scored if f.slot < 3}
    # row 0 = {1, 2, 3, 4}: map 2 = {3, 4, 5, 6} shares 2, the archive (rows 0, 1) all 4
    assert (frames[0].on_tracked_map.shared_points, frames[0].archive_shared_points) == (2, 4)
    # row 2 = {2, 3, 5, 9}: 2 with map 2, 3 with the archive; row 3 = {7, 8}: none with either
    assert (frames[2].on_tracked_map.shared_points, frames[2].archive_shared_points) == (2, 3)
    assert frames[3].archive_shared_points == 0
    # row 4 = {4, 6, 10} tracked with map 1: the archive of map 1 is maps up to version 1
    assert (frames[4].on_tracked_map.shared_points, frames[4].archive_shared_points) == (2, 2)
    causes = {row: failure_cause(f.on_tracked_map.shared_points, f.archive_shared_points, 3)
              for row, f in frames.items()}
    assert causes == {0: LEFT_OUT, 2: LEFT_OUT, 3: NEW_GROUND, 4: NEW_GROUND}
    assert failure_cause(3, 4, 3) == MAP_COVERED and failure_cause(2, 3, 2) == MAP_COVERED


def test_the_failure_causes_table_counts_each_groups_failed_frames(tmp_path) -> None:
    """Per folder, scenario, map source and policy: failed frames by cause, as shares of the
    scored frames; frames of an older evaluate (no failure_cause column) are refused."""
    import csv

    from twinslam.live.calibration.report import (
        failure_causes,
        failure_causes_markdown,
        read_rows,
    )
    from twinslam.live.runs import FRAMES_HEADER

    def row(policy: str, seed: int, tracked: bool, cause: str) -> list[object]:
        return ["revisit-v15", "edge", policy, seed, "", 1, 0, 7, 7, 1, 40, 1.0, -5.0, 40, 1.0,
                -5.0, int(tracked), 30 if tracked else 0, 0.01, 80, cause]

    with (tmp_path / "calibration_frames.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(FRAMES_HEADER)
        w.writerows([row("lff", 0, True, ""), row("lff", 0, False, NEW_GROUND),
                     row("lff", 1, False, LEFT_OUT), row("lff", 1, False, LEFT_OUT),
                     row("pu", 0, True, ""), row("pu", 0, False, MAP_COVERED)])
    lff, pu = failure_causes(read_rows([tmp_path], "calibration_frames.csv"))
    assert (lff.policy, lff.runs, lff.frames, lff.failed) == ("lff", 2, 4, 3)
    assert (lff.new_ground, lff.left_out, lff.map_covered) == (1, 2, 0)
    assert (pu.runs, pu.frames, pu.failed, pu.map_covered) == (1, 2, 1, 1)
    table = failure_causes_markdown([lff, pu])
    assert "| lff | 2 | 4 | 75.0% (3) | 25.0% (1) | 50.0% (2) | 0.0% (0) |" in table
    old = [{k: v for k, v in r.items() if k != "failure_cause"}
           for r in read_rows([tmp_path], "calibration_frames.csv")]
    with pytest.raises(ValueError, match="no failure_cause column"):
        failure_causes(old)


def test_calibrate_still_reads_frames_written_before_the_failure_causes(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """A folder of an older evaluate (no shared_points_archive, failure_cause columns): the
    calibration is measured and written as before, the causes are said to be missing."""
    import csv
    import gzip
    from pathlib import Path

    from twinslam.cli.main import main

    committed = (Path(__file__).resolve().parents[1] / "docs" / "figures" / "archive-restores"
                 / "failure-causes" / "none")
    (tmp_path / "calibration.csv").write_bytes((committed / "calibration.csv").read_bytes())
    rows = list(csv.reader(gzip.decompress(
        (committed / "calibration_frames.csv.gz").read_bytes()).decode().splitlines()))
    assert rows[0][-2:] == ["shared_points_archive", "failure_cause"]
    with (tmp_path / "calibration_frames.csv").open("w", newline="") as fh:
        csv.writer(fh).writerows(row[:-2] for row in rows)
    assert main(["calibrate", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    assert "no failure causes: calibration_frames.csv has no failure_cause column" in printed
    assert "| edge | revisit-v15 | 20 |" in printed and "left out of the map" not in printed
    assert (tmp_path / "rule-calibration.png").is_file()
    assert not (tmp_path / "rule-calibration-failures.csv").exists()


def test_calibrate_writes_its_figure_into_a_folder_it_makes(
        tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--out`` in a folder that does not exist yet: made, not a FileNotFoundError traceback."""
    import gzip
    from pathlib import Path

    from twinslam.cli.main import main

    committed = (Path(__file__).resolve().parents[1] / "docs" / "figures" / "archive-restores"
                 / "failure-causes" / "none")
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "calibration.csv").write_bytes((committed / "calibration.csv").read_bytes())
    (runs / "calibration_frames.csv").write_bytes(
        gzip.decompress((committed / "calibration_frames.csv.gz").read_bytes()))
    out = tmp_path / "new" / "folder" / "rule.png"
    assert main(["calibrate", str(runs), "--out", str(out)]) == 0
    assert out.is_file() and out.with_suffix(".csv").is_file()
    assert "Traceback" not in capsys.readouterr().err


def test_the_calibration_sees_the_played_frames_through_the_players_camera(
        tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The simulator's view of a run's frames is extracted through the camera the player
    shows the device (its colour_intrinsics): a 7-Scenes scene through its colour camera with
    the default device's ``auto``, through the file's own with the paper's preset — each
    cached under a name of its own, never one for the other."""

    import cv2

    from twinslam.live.calibration import frames as calibration

    scene = tmp_path / "scene"
    scene.mkdir()
    np.savetxt(scene / "camera-intrinsics.txt", [[585, 0, 320], [0, 585, 240], [0, 0, 1]])
    for i in range(2):
        cv2.imwrite(str(scene / f"frame-{i:06d}.color.png"), np.zeros((48, 64, 3), np.uint8))
        cv2.imwrite(str(scene / f"frame-{i:06d}.depth.png"), np.full((48, 64), 2000, np.uint16))
        np.savetxt(scene / f"frame-{i:06d}.pose.txt", np.eye(4))
    seen: list[float] = []

    def extract(reader: object) -> tuple[str, None, None]:
        seen.append(float(reader.intrinsics[0, 0]))  # type: ignore[attr-defined]
        return "dataset", None, None

    monkeypatch.setattr(calibration, "extract_covisibility", extract)
    monkeypatch.setattr(calibration, "save_covisibility",
                        lambda path, _: np.savez(path, covis=np.zeros(1)))
    auto = calibration.covisibility_file(str(scene), 2, tmp_path / "covis", lambda _: None,
                                         colour_intrinsics="auto")
    own = calibration.covisibility_file(str(scene), 2, tmp_path / "covis", lambda _: None)
    assert seen == [525.0, 585.0] and auto != own
    assert calibration.covisibility_file(str(scene), 2, tmp_path / "covis", lambda _: None,
                                         colour_intrinsics="auto") == auto     # cached
    assert seen == [525.0, 585.0]
    # a cache cut off while it was written (the run killed) is extracted again, not read
    auto.write_bytes(auto.read_bytes()[:40])
    said: list[str] = []
    assert calibration.covisibility_file(str(scene), 2, tmp_path / "covis", said.append,
                                         colour_intrinsics="auto") == auto
    assert seen == [525.0, 585.0, 525.0] and "cut off" in said[0]
