"""``mpc`` at the edge: the planner plans in a world built from the live map — the
camera's poses continued at constant velocity, the map points in the frustum there — and its
answer is a legal slot decision in the edge's frame ids. What the edge accepts by name, and
what stays simulator-only."""

from __future__ import annotations

import itertools
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from edge_mapper.edge_core import EdgeConfig, EdgeMapperCore
from edge_mapper.planning_world import (
    LIVE_MAX_STATES,
    LiveMpc,
    extrapolate,
    overlap_decay,
    predict_frames,
    visible_mask,
)
from edge_mapper.policy_control import make_policies, policy_refused
from edge_mapper.slot_planner import FrameObservations, SlotConfig, SlotView
from twinslam.live.runs import policy_variants
from twinslam.policies.actions import check_map_action
from twinslam.policies.delayed import DelayedPolicy
from twinslam.policies.mpc import MpcPlanner, parse_mpc
from twinslam.policies.registry import make_policy
from twinslam.slam.camera import Camera

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
CAMERA = Camera(K, (480, 640))


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    """Camera-to-map: at (x, 0, 0), turned about the vertical (y) axis, looking along +z."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    out[0, 3] = x
    return out


def test_extrapolation_continues_a_constant_velocity_walk() -> None:
    # a camera that steps 1 cm forward-right and turns half a degree every frame
    step = _pose(0.01, 0.5)
    step[2, 3] = 0.01
    truth = [_pose(0.3, 20.0)]
    for _ in range(39):
        truth.append(truth[-1] @ step)
    # frames 0, 5, …, 25 seen; 30 and 39 predicted
    got = extrapolate(truth[0:30:5], list(range(0, 30, 5)), [5, 14])
    for pose, want in zip(got, (truth[30], truth[39]), strict=True):
        assert np.allclose(pose, want, atol=1e-9)
    # one pose: standing still
    assert np.allclose(extrapolate([truth[3]], [3], [10])[0], truth[3])


def test_the_visible_mask_holds_the_points_in_the_frustum_and_depth_range() -> None:
    points = np.array([[0.0, 0.0, 2.0],      # ahead
                       [0.0, 0.0, -2.0],     # behind
                       [5.0, 0.0, 1.0],      # off the image's side
                       [0.0, 0.0, 9.0]])     # too far
    assert visible_mask(points, np.eye(4), CAMERA).tolist() == [True, False, False, False]
    # turned half round, the camera sees the one that was behind it
    assert visible_mask(points, _pose(0.0, 180.0), CAMERA).tolist() == [
        False, True, False, False]


def _walk_core(vmax: int = 6) -> tuple[EdgeMapperCore, list[FrameObservations]]:
    """A map of a corridor (points on a wall at z = 2, x from -1 to 6) whose keyframes stand
    at x = 0 … 1.0, and a slot walking on along +x: its frames see the points ahead of them."""
    core = EdgeMapperCore(make_policy("lff"), K, EdgeConfig(slot=SlotConfig(vmax=vmax)))
    xs = np.arange(-1.0, 6.0, 0.05)
    pid = [core.map.add_point(np.array([x, 0.0, 2.0]), np.zeros(32, np.uint8)) for x in xs]
    for kf in range(vmax):
        centre = 0.2 * kf
        core.map.add_keyframe(kf, _pose(centre))
        for p, x in zip(pid, xs, strict=True):
            if abs(x - centre) < 1.2:
                core.map.observe(kf, p, (320.0, 240.0), 2.0)
    frames = []
    for i in range(10):
        centre = 1.2 + 0.05 * i
        seen = frozenset(p for p, x in zip(pid, xs, strict=True) if abs(x - centre) < 1.2)
        frames.append(FrameObservations(100 + i, seen, frozenset({1000 + i, 1001 + i}),
                                        True, _pose(centre)))
    return core, frames


def _view(core: EdgeMapperCore, frames: list[FrameObservations]) -> SlotView:
    by_id = {f.frame_id: f for f in frames}
    return SlotView(core.map, core.map.keyframe_ids(), frames,
                    lambda x: core.planner.points_of(by_id, x), CAMERA, core.slot_config)


def test_the_predicted_frames_see_the_map_ahead_of_the_walk() -> None:
    core, frames = _walk_core()
    predicted = predict_frames(_view(core, frames), slots=2)
    assert len(predicted) == 20
    positions = {p: core.map.points[p].position[0] for p in core.map.points}
    first_x = np.mean([positions[p] for p in predicted[0] if p >= 0])
    last_x = np.mean([positions[p] for p in predicted[-1] if p >= 0])
    # the camera walks on along +x at 5 cm a frame: what it sees moves with it
    assert last_x - first_x > 0.3
    # only points that are in the map, or the slot's own tracks (negative keys)
    assert all(p in positions or p < 0 for f in predicted for p in f)


def test_live_mpc_answers_a_legal_slot_decision_in_the_edges_frame_ids() -> None:
    core, frames = _walk_core()
    core.set_policy(LiveMpc(MpcPlanner(parse_mpc("mpc:H=2"))))
    plan = core.plan(0, frames, 40.0, 1)        # 4 uploads, as many evictions (map full)
    obs = plan.observation
    assert obs.n_upload == 4 and obs.n_evict == 4
    check_map_action(0, obs.n_upload, obs.n_evict, set(obs.candidates), obs.map_frames,
                     plan.action)
    # a map full of keyframes behind a camera walking away: it keeps the newest views
    assert set(plan.action.evict) <= {0, 1, 2, 3, *plan.action.upload}


def test_live_mpc_refuses_to_decide_without_the_slots_view() -> None:
    mpc = LiveMpc(MpcPlanner(parse_mpc("mpc")))
    core, frames = _walk_core()
    obs = core.plan(0, frames, 40.0, 1).observation
    with pytest.raises(RuntimeError, match="see_slot"):
        mpc.decide(obs)


def test_the_edge_runs_mpc_and_names_what_stays_simulator_only() -> None:
    assert policy_refused("mpc") is None and policy_refused("mpc:H=2/S=2") is None
    assert "simulator-only" in (policy_refused("mpc:frames=oracle") or "")
    assert "future rates" in (policy_refused("mpc:rates=oracle") or "")
    policy, feed = make_policies({"policy": "mpc:H=2", "policy_checkpoint": "",
                                  "fallback_policy": "lff", "latent_max_age": 3},
                                 EdgeMapperCore.warm_up)
    assert isinstance(policy, LiveMpc) and policy.name == "mpc:H=2" and feed is None
    # twinslam evaluate: an option's '=' is not a label's
    assert policy_variants("lff,mpc:H=2,planner=mpc:H=2/S=1") == [
        ("lff", "lff"), ("mpc:H=2", "mpc:H=2"), ("planner", "mpc:H=2/S=1")]


def test_the_edge_plans_later_slots_exactly_only_on_small_instances_unless_told() -> None:
    assert LiveMpc(MpcPlanner(parse_mpc("mpc"))).planner.config.max_states == LIVE_MAX_STATES
    told = parse_mpc("mpc:states=500")
    assert told.max_states == 500 and told.label() == "mpc:states=500"
    assert LiveMpc(MpcPlanner(told)).planner.config.max_states == 500
    with pytest.raises(ValueError, match="states must be >= 1"):
        parse_mpc("mpc:states=0")


def test_a_delayed_policy_decides_as_its_policy_only_later() -> None:
    core, frames = _walk_core()
    obs = core.plan(0, frames, 40.0, 1).observation
    delayed = make_policy("delay:0.05:lff")
    assert isinstance(delayed, DelayedPolicy) and delayed.name == "delay:0.05:lff"
    started = time.perf_counter()
    action = delayed.decide(obs)
    assert time.perf_counter() - started >= 0.05
    assert action == make_policy("lff").decide(obs)
    # at the edge a delayed mpc still sees the slot: it plans in the live world
    policy, _ = make_policies({"policy": "delay:0:mpc:H=2", "policy_checkpoint": "",
                               "fallback_policy": "lff", "latent_max_age": 3})
    assert isinstance(policy, DelayedPolicy) and isinstance(policy.policy, LiveMpc)
    core.set_policy(policy)
    plan = core.plan(1, [FrameObservations(f.frame_id + 100, f.map_points, f.tracks, True,
                                           f.pose) for f in frames], 40.0, 1)
    assert len(plan.action.upload) == plan.observation.n_upload
    for bad, why in (("delay:x:lff", "delay:SECONDS:POLICY"), ("delay:0.1", "SECONDS:POLICY"),
                     ("delay:-1:lff", "0 <= SECONDS"), ("delay:1:mbrl:a.pt", "rule policy or mpc"),
                     ("delay:1:nothing", "unknown policy")):
        with pytest.raises(ValueError, match=why):
            make_policy(bad)
    assert "simulator-only" in (policy_refused("delay:0.1:mpc:frames=oracle") or "")


def test_the_next_frames_share_fewer_points_the_further_ahead_they_are() -> None:
    """A window of 100 points sliding 2 a frame: the fitted decay starts at 1 for the next
    frame and falls off with the distance ahead; frames that all see the same points keep
    them."""
    sliding = [np.arange(2 * i, 2 * i + 100) for i in range(30)]
    decay = overlap_decay(sliding)
    shares = [decay(d) for d in (1, 5, 10, 20, 40)]
    assert shares[0] == pytest.approx(1.0)
    assert all(a > b for a, b in itertools.pairwise(shares)) and shares[-1] < 0.5
    still = overlap_decay([np.arange(50)] * 10)
    assert still(1) == pytest.approx(1.0) and still(60) == pytest.approx(1.0)
