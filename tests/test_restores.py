"""What the edge's restores go by: how much of each archived keyframe's points the coming view
sees, from the best of the predicted poses — every keyframe scored in one pass a pose, a
keyframe's score its own whatever the others hold — and the covisibility weights of each map a
swap tries, counted once for the map's pairs and exactly as from scratch."""

from __future__ import annotations

import numpy as np

from edge_mapper.planning_world import visible_mask
from edge_mapper.restores import TrialWeights, archived_in_view, map_view_scores, view_scores
from twinslam.slam.back_end.keyframe_archive import ArchivedKeyFrame, KeyFrameArchive
from twinslam.slam.back_end.keyframe_map import Incidence, KeyFrameMap, shared_counts
from twinslam.slam.camera import Camera

CAMERA = Camera(np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]]))


def _ahead(n: int, x: float, z: float = 2.0) -> np.ndarray:
    """``n`` points in a small patch ``z`` m along the optical axis, ``x`` m to the side."""
    rng = np.random.default_rng(n)
    return np.column_stack([x + rng.uniform(-0.2, 0.2, n), rng.uniform(-0.2, 0.2, n),
                            np.full(n, z)])


def _moved(x: float) -> np.ndarray:
    pose = np.eye(4)
    pose[0, 3] = x
    return pose


def test_each_keyframe_counts_what_the_best_predicted_pose_sees_of_it() -> None:
    """Keyframe A's points lie before the first pose (and 4 of them behind it), B's before the
    second pose 5 m aside, C has none, D's lie beyond the depth the view reaches: A and B score
    what their pose sees, as each scored alone would."""
    behind = _ahead(4, 0.0, z=-1.0)
    sets = [np.vstack([_ahead(12, 0.0), behind]), _ahead(7, 5.0), np.zeros((0, 3)),
            _ahead(9, 0.0, z=20.0)]
    poses = [np.eye(4), _moved(5.0)]
    scores = view_scores(sets, poses, CAMERA)
    assert scores.tolist() == [12, 7, 0, 0]
    alone = [max((int(visible_mask(s, p, CAMERA).sum()) if len(s) else 0) for p in poses)
             for s in sets]
    assert scores.tolist() == alone


def test_archived_keyframes_in_view_are_ranked_and_kept_as_useful() -> None:
    """The archived keyframes the coming view sees enough of, most first; one it sees too
    little of is left out; those in view count as useful in this slot."""
    archive = KeyFrameArchive(10)
    for kf_id, points in ((1, _ahead(40, 0.0)), (2, _ahead(60, 0.1)), (3, _ahead(3, 0.0))):
        archive.add(ArchivedKeyFrame(kf_id, np.eye(4), np.arange(len(points)) + 100 * kf_id,
                                     points, np.zeros((len(points), 32), np.uint8),
                                     np.zeros((len(points), 3)), 0), write=False)
    assert archived_in_view(archive, [np.eye(4)], CAMERA, slot=7) == [(60, 2), (40, 1)]
    assert archive._useful == {1: 7, 2: 7, 3: 0}


def test_a_trial_maps_weights_are_the_shared_counts_of_its_keyframes() -> None:
    """Whatever map a restore tries — map keyframes left out, archived ones added, in any
    order — its covisibility weights are the shared point counts of its keyframes' sets, as
    counted from scratch."""
    rng = np.random.default_rng(3)
    map_sets = {k: rng.choice(400, 60, replace=False).astype(np.int64) for k in range(8)}
    archived = {100 + k: rng.choice(np.arange(200, 700), 70, replace=False).astype(np.int64)
                for k in range(4)}
    weights = TrialWeights(Incidence.of(list(map_sets), list(map_sets.values())), archived)
    every = {**map_sets, **archived}
    for trial in ([0, 1, 2, 3, 4, 5, 6, 7], [1, 2, 3, 4, 5, 6, 7, 100], [101, 0, 3, 102, 5],
                  [103, 100], [4]):
        np.testing.assert_array_equal(weights.of(trial),
                                      shared_counts([every[k] for k in trial]))
    assert weights.of([0, 100])[0, 1] > 0          # the sets overlap where the ids do
    # a keyframe archived before welding kept its ids apart may name a point twice: the
    # point is shared once
    twice = {200: np.concatenate([archived[100], archived[100][:10]])}
    again = TrialWeights(Incidence.of(list(map_sets), list(map_sets.values())), twice)
    np.testing.assert_array_equal(again.of([0, 1, 200]),
                                  shared_counts([map_sets[0], map_sets[1], archived[100]]))


def test_a_keyframe_touches_a_trial_map_where_its_weights_row_is_not_all_zero() -> None:
    """An archived keyframe is told to touch the rest of a trial map exactly where its row of
    that map's weights is not all zero: through a map keyframe or through another archived
    one, and not at all where it shares no point (the restores skip those without scoring
    the map)."""
    rng = np.random.default_rng(4)
    map_sets = {k: rng.choice(300, 40, replace=False).astype(np.int64) for k in range(6)}
    archived = {100: np.arange(280, 330, dtype=np.int64),        # shares with the map
                101: np.arange(1000, 1040, dtype=np.int64),      # with 102 alone
                102: np.arange(1030, 1090, dtype=np.int64),
                103: np.arange(5000, 5020, dtype=np.int64)}      # with nothing
    weights = TrialWeights(Incidence.of(list(map_sets), list(map_sets.values())), archived)
    told = []
    for trial in ([0, 1, 2, 100], [0, 1, 101], [0, 102, 101], [3, 4, 100, 103],
                  [100, 103], [102, 101], [5, 103]):
        touches = weights.touches(trial[-1], trial[:-1])
        assert touches == bool(weights.of(trial)[-1].any()), trial
        told.append(touches)
    assert told == [True, False, True, False, False, True, False]


def test_a_map_keyframes_score_counts_its_own_points_though_others_share_them() -> None:
    """Map keyframes that share points (each point tested once a pose) score what each alone
    would: its own points the best predicted pose sees, shared ones counted for each."""
    m = KeyFrameMap()
    front, aside = _ahead(30, 0.0), _ahead(20, 5.0)
    ids = m.add_points(np.vstack([front, aside]), np.zeros((50, 32), np.uint8))
    members = {1: ids[:20], 2: ids[10:30] + ids[30:35], 3: ids[30:], 4: ids[5:15]}
    for kf, pids in members.items():
        m.add_keyframe(kf, np.eye(4))
        m.observe_many(kf, pids, [[0.0, 0.0]] * len(pids), [1.0] * len(pids))
    poses = [np.eye(4), _moved(0.3)]
    alone = {kf: max(int(visible_mask(m.positions_of(pids), p, CAMERA).sum()) for p in poses)
             for kf, pids in members.items()}
    assert map_view_scores(m, m.incidence(list(members)), poses, CAMERA) == alone
    assert alone[1] == 20 and alone[3] == 0
