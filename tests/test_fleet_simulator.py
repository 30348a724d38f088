"""Many devices inside one edge's keyframe budget in the simulator: every slot the
allocator hands out exactly V_total, every map stays within its share, a shared cell never
carries more than its capacity, one device alone is the single-device simulator, and the same
seeds give the same numbers."""

from __future__ import annotations

import numpy as np
import pytest

from twinslam.cli.main import main
from twinslam.covisibility.geometric import geometric_covisibility
from twinslam.policies.plan import rollout
from twinslam.policies.rules import make_rule_policy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.simulator.fleet import FleetConfig, FleetSimulator, evaluate_fleet
from twinslam.uplink.channels import parse_channel

DATA = geometric_covisibility(n_frames=400, n_points=2000, seed=3)


def _fleet(n: int, total: int, allocator: str, policy: str = "lff", slots: int = 12,
           cell: float = 0.0) -> FleetSimulator:
    config = FleetConfig(n, total, allocator, 4, cell_capacity_mbps=cell,
                         sim=SimConfig(slots=slots))
    return FleetSimulator([(DATA, parse_channel("markov:N=2", seed=i)) for i in range(n)],
                          config, lambda: make_rule_policy(policy))


@pytest.mark.parametrize("allocator", ["equal", "motion", "twin"])
def test_every_slot_splits_v_total_and_every_map_keeps_within_its_share(allocator: str) -> None:
    result = _fleet(5, 40, allocator, "adapt").run(0)
    for slot in range(12):
        shares = [d.budgets[slot] for d in result.devices]
        assert sum(shares) == 40 and min(shares) >= 4
        assert all(d.map_sizes[slot] <= d.budgets[slot] for d in result.devices)
    assert 0 < result.jain_tracked <= 1 and 0 <= result.lost_share <= 1


@pytest.mark.parametrize("allocator, split", [("equal", "proportional"),
                                              ("motion", "allocator"), ("twin", "allocator")])
def test_a_shared_cell_never_carries_more_than_its_capacity(allocator: str, split: str) -> None:
    config = FleetConfig(4, 40, allocator, 4, cell_capacity_mbps=100.0, cell_split=split,
                         sim=SimConfig(slots=12))
    sim = FleetSimulator([(DATA, parse_channel("markov:N=2", seed=i)) for i in range(4)],
                         config, lambda: make_rule_policy("lff"))
    result = sim.run(1)                                      # links of 40-80 Mbit/s each
    for slot in range(12):
        assert sum(d.rates[slot] for d in result.devices) == pytest.approx(100.0)
    alone = _fleet(4, 40, "equal").run(1)
    for slot in range(12):
        assert all(d.rates[slot] <= a.rates[slot] + 1e-9          # never above its own link
                   for d, a in zip(result.devices, alone.devices, strict=True))


def test_one_device_alone_is_the_single_device_simulator() -> None:
    fleet = _fleet(1, 15, "equal", "adapt", slots=10).run(2)
    env = MapManagementEnv(DATA, parse_channel("markov:N=2", seed=0), SimConfig(vmax=15,
                                                                                slots=10))
    single = rollout(env, make_rule_policy("adapt"), 2 * 1000).tally
    assert fleet.devices[0].tally.mean == pytest.approx(single.mean)
    assert fleet.devices[0].tally.lost_share == pytest.approx(single.lost_share)


def test_the_same_seeds_give_the_same_numbers_and_a_small_budget_is_refused() -> None:
    def once() -> list[float]:
        results = evaluate_fleet(DATA, lambda i: parse_channel("markov:N=2", seed=i),
                                 FleetConfig(3, 30, "equal", 4, sim=SimConfig(slots=8)),
                                 ["equal", "twin"], lambda: make_rule_policy("lff"), [0, 1])
        return [r.mean_uncertainty for a in results for r in a.runs]

    first = once()
    assert first == once() and np.all(np.isfinite(first))
    with pytest.raises(ValueError, match="V_total 10 is below 3 devices x 4 keyframes"):
        _fleet(3, 10, "equal")


def test_sim_compares_allocators_for_many_devices(capsys: pytest.CaptureFixture[str],
                                                  tmp_path: object) -> None:
    code = main(["sim", "--covis", "geometric:300", "--devices", "6", "--vmax-total", "48",
                 "--policy", "lff", "--slots", "6", "--seeds", "2", "--csv",
                 f"{tmp_path}/fleet.csv"])
    out = capsys.readouterr().out
    assert code == 0, out
    rows = [line.split()[0] for line in out.splitlines() if line.split()
            and line.split()[0] in ("equal", "motion", "twin")]
    assert rows == ["equal", "motion", "twin"] and "dev-slots/s" in out
    lines = open(f"{tmp_path}/fleet.csv", encoding="utf-8").read().splitlines()
    assert len(lines) == 1 + 3 * 2 * 6                        # allocators × seeds × devices
    assert main(["sim", "--covis", "geometric:300", "--devices", "6", "--vmax-total", "20",
                 "--policy", "lff"]) == 2
    assert "V_total 20 is below 6 devices x 5 keyframes" in capsys.readouterr().err


def test_devices_walk_at_their_own_speeds_and_uplinks(capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """A walking speed maps camera frames onto recorded ones (0: standing still, 2: every
    other frame); a device standing still sees nothing new, one walking fast a lot."""
    from twinslam.policies.world_model import FrameStream

    assert FrameStream(DATA, start=5, horizon=4, speed=0.0).dataset_index([0, 1, 2, 3]).tolist() \
        == [5, 5, 5, 5]
    assert FrameStream(DATA, start=5, horizon=4, speed=2.0).dataset_index([0, 1, 2, 3]).tolist() \
        == [5, 7, 9, 11]
    config = FleetConfig(2, 20, "motion", 4, sim=SimConfig(slots=6))
    sim = FleetSimulator([(DATA, parse_channel("markov:N=2", seed=i)) for i in range(2)], config,
                         lambda: make_rule_policy("lff"), speeds=[0.0, 3.0])
    result = sim.run(0)
    # the walker's novelty draws the budget: its share exceeds the standing device's
    assert sum(result.devices[1].budgets[2:]) > sum(result.devices[0].budgets[2:])
    assert main(["sim", "--covis", "geometric:300", "--devices", "4", "--vmax-total", "40",
                 "--policy", "lff", "--slots", "4", "--seeds", "1", "--speeds", "0,2",
                 "--device-rates", "5-20,40-80", "--allocator", "equal,motion"]) == 0
    assert "walking speeds [0.0, 2.0] and uplink ranges ['5-20', '40-80']" in \
        capsys.readouterr().out
