"""Many devices, one edge, in the simulator: each device a
:class:`~twinslam.policies.world_model.MapManagementEnv` of its own walk and uplink, all inside one
keyframe budget V_total that an allocator (:mod:`twinslam.allocation.allocators`) splits
every slot, and optionally one cell whose capacity their uplinks share.

The devices step in lockstep here (one slot for all, then the next), so a device's share is its
V_max for the slot at once: each map after the slot holds at most its share and the maps
together at most V_total. (The live edge, whose devices keep their own clocks, grants shares
through :mod:`edge_mapper.keyframe_budget` instead.) What each allocator reads is causal:

* ``equal`` — nothing;
* ``motion`` — the novelty of each device's slot: the share of its frames' points its map
  does not hold;
* ``twin`` — each device's value curve (:mod:`twinslam.allocation.budget_value`): its slot's
  frames against its map's keyframes and the uploads its rate twin (the Bayesian regime twin
  of the device's channel states) expects next slot.

A shared cell of capacity C gives each device d_i · min(1, C / Σ_j d_j) (proportional shares of
what the links could carry alone), or (``cell_split="allocator"``) a share by the allocator's
own signal — equal, novelty, or the share of its frames its map would not track — each device
at most its own link's rate d_i and what a capped device leaves going to the others.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from twinslam.allocation.allocators import (
    DeviceDemand,
    allocate,
    check_budget,
    check_fleet,
    jain_index,
    split_capacity,
)
from twinslam.allocation.budget_value import budget_value, expected_uploads
from twinslam.covisibility.dataset import CovisibilityDataset
from twinslam.policies.protocol import MapPolicy
from twinslam.policies.world_model import MapManagementEnv, SimConfig
from twinslam.reporting import mean_ci95, paired_difference
from twinslam.twin.regime_twin import RegimeConfig, RegimeTwin
from twinslam.uncertainty.map_uncertainty import SlotUncertainty, UncertaintyTally
from twinslam.uplink.channels import MarkovChannel, TraceChannel

#: how a shared cell's capacity is split (FleetConfig.cell_split)
CELL_SPLITS = ("proportional", "allocator")


@dataclass(frozen=True)
class FleetConfig:
    devices: int
    vmax_total: int
    allocator: str = "equal"
    min_keyframes: int = 5
    fairness: float = 0.0
    cell_capacity_mbps: float = 0.0          #: 0: every device has its link to itself
    #: how a cell is shared: "proportional" to what each link could carry alone, or by the
    #: "allocator" (equal shares; motion: by novelty; twin: by the frames its map would
    #: not track), no device above its own link
    cell_split: str = "proportional"
    sim: SimConfig = field(default_factory=SimConfig)

    def check(self) -> None:
        check_fleet(self.devices, self.allocator, self.vmax_total, self.min_keyframes)
        check_budget(self.vmax_total, self.devices, self.min_keyframes)   # 0 is no budget
        if self.cell_split not in CELL_SPLITS:
            raise ValueError(f"unknown cell split {self.cell_split!r}: one of "
                             f"{', '.join(CELL_SPLITS)}")
        if not math.isfinite(self.cell_capacity_mbps) or self.cell_capacity_mbps < 0:
            raise ValueError(f"cell capacity must be >= 0 Mbit/s, got {self.cell_capacity_mbps}")


@dataclass
class DeviceResult:
    """One device's episode: υ pooled over its slots' frames, and its shares."""

    tally: UncertaintyTally
    budgets: list[int]                       #: its share of V_total, slot by slot
    map_sizes: list[int] = field(default_factory=list)     #: its map after each slot
    rates: list[float] = field(default_factory=list)       #: the Mbit/s it uploaded at

    @property
    def tracked_share(self) -> float:
        return 1.0 - self.tally.lost_share


@dataclass
class FleetResult:
    allocator: str
    seed: int
    devices: list[DeviceResult]
    seconds: float = 0.0                     #: wall time of the episode

    @property
    def mean_uncertainty(self) -> float:
        return float(np.mean([d.tally.mean for d in self.devices]))

    @property
    def lost_share(self) -> float:
        return float(np.mean([d.tally.lost_share for d in self.devices]))

    @property
    def tracked_uncertainty(self) -> float:
        values = [d.tally.tracked_uncertainty for d in self.devices
                  if math.isfinite(d.tally.tracked_uncertainty)]
        return float(np.mean(values)) if values else math.nan

    @property
    def jain_tracked(self) -> float:
        return jain_index([d.tracked_share for d in self.devices])


class FleetSimulator:
    """``devices`` as (covisibility dataset, channel) pairs, one policy each (made by
    ``make_policy``), one budget."""

    def __init__(self, devices: Sequence[tuple[CovisibilityDataset,
                                               MarkovChannel | TraceChannel]],
                 config: FleetConfig, make_policy: Callable[[], MapPolicy],
                 speeds: Sequence[float] | None = None) -> None:
        config.check()
        if len(devices) != config.devices:
            raise ValueError(f"{len(devices)} devices given for a fleet of {config.devices}")
        self.config = config
        speeds = list(speeds) if speeds is not None else [config.sim.speed] * len(devices)
        self.envs = [MapManagementEnv(data, channel, replace(config.sim, speed=speed))
                     for (data, channel), speed in zip(devices, speeds, strict=True)]
        self.policies = [make_policy() for _ in devices]
        self.twins = [RegimeTwin(RegimeConfig(n_states=channel.n_states))
                      for _, channel in devices]
        self.rates = [np.asarray(channel.rates, dtype=np.float64) for _, channel in devices]
        #: each dataset's point ids lie in 0 … bound − 1 (the value curves index by them)
        self.id_bounds = [int(data.point_ids.max()) + 1 if data.point_ids.size else 0
                          for data, _ in devices]

    def run(self, seed: int) -> FleetResult:
        """One episode of every device (device i on seed ``seed × 1000 + i``: its own walk
        start and channel draw)."""
        started = time.perf_counter()
        cfg, n = self.config, self.config.devices
        for i, (env, policy, twin) in enumerate(zip(self.envs, self.policies, self.twins,
                                                    strict=True)):
            env.reset(seed * 1000 + i)
            policy.reset(seed * 1000 + i)
            twin.reset()
        tallies: list[list[SlotUncertainty]] = [[] for _ in range(n)]
        results = [DeviceResult(UncertaintyTally(), []) for _ in range(n)]
        for _slot in range(cfg.sim.slots):
            for env, twin in zip(self.envs, self.twins, strict=True):
                twin.observe(env.observation().rate_state)     # d_k, as the device reports it
            demands = [self._demand(i) for i in range(n)]
            shares = allocate(cfg.allocator, cfg.vmax_total, demands, cfg.min_keyframes,
                              cfg.fairness)
            if cfg.cell_capacity_mbps > 0:
                self._share_cell(demands)
            for i, (env, policy) in enumerate(zip(self.envs, self.policies, strict=True)):
                env.set_vmax(shares[i])
                obs = env.observation()
                _obs, _r, _t, _trunc, info = env.step(policy.decide(obs))
                tallies[i].append(info["uncertainty"])
                results[i].budgets.append(shares[i])
                results[i].map_sizes.append(int(info["map_size"]))
                results[i].rates.append(obs.rate_mbps)
        for result, slots in zip(results, tallies, strict=True):
            result.tally = UncertaintyTally.of(slots)
        return FleetResult(cfg.allocator, seed, results, time.perf_counter() - started)

    def _share_cell(self, demands: list[DeviceDemand]) -> None:
        """Every device's rate this slot within the cell's capacity (:data:`CELL_SPLITS`)."""
        cfg = self.config
        links = [env.observation().rate_mbps for env in self.envs]
        if cfg.cell_split == "proportional" or cfg.allocator == "equal":
            weights = links if cfg.cell_split == "proportional" else [1.0] * len(links)
        elif cfg.allocator == "motion":
            weights = [d.novelty for d in demands]
        else:                # twin: the share of its frames its map would not track
            weights = [1.0 - float(d.value[min(d.map_size, d.value.size - 1)])
                       if d.value is not None else 1.0 for d in demands]
        for env, rate in zip(self.envs, split_capacity(cfg.cell_capacity_mbps, links, weights),
                             strict=True):
            env.set_rate(rate)

    def _demand(self, i: int) -> DeviceDemand:
        cfg, env = self.config, self.envs[i]
        obs = env.observation()
        if cfg.allocator == "equal":
            return DeviceDemand(f"{i}", len(obs.map_frames))
        data, stream = env.dataset, env.stream
        frames = stream.dataset_index(obs.candidates)
        if cfg.allocator == "motion":
            if not obs.map_frames or not len(frames):
                return DeviceDemand(f"{i}", len(obs.map_frames), 1.0)
            shared = data.shared_points(stream.dataset_index(obs.map_frames), frames)
            sizes = np.diff(data.point_offsets)[frames]
            novelty = float(np.mean(1.0 - shared / np.maximum(sizes, 1)))
            return DeviceDemand(f"{i}", len(obs.map_frames), novelty)
        twin = self.twins[i]
        probs = twin.predict([obs.rate_state])
        uploads = expected_uploads(probs, self.rates[i], cfg.sim.alpha_mbit, cfg.sim.d_req_s,
                                   len(frames), cfg.sim.slot_seconds)
        keyframes = [data.points(int(k)) for k in stream.dataset_index(obs.map_frames)]
        value = budget_value(keyframes, [data.points(int(f)) for f in frames], uploads,
                             cfg.sim.min_shared, cfg.vmax_total, id_bound=self.id_bounds[i])
        return DeviceDemand(f"{i}", len(obs.map_frames), value=value)


@dataclass
class AllocatorResult:
    """One allocator over the seeds: each seed's fleet."""

    allocator: str
    runs: list[FleetResult]

    def per_seed(self, figure: str) -> list[float]:
        return [float(getattr(r, figure)) for r in self.runs]

    def mean_ci(self, figure: str) -> tuple[float, float]:
        return mean_ci95(self.per_seed(figure))

    def paired(self, other: AllocatorResult, figure: str) -> tuple[float, float]:
        """Mean and 95 % CI of this − ``other`` on the same seeds (the same walks and
        uplinks)."""
        mine, theirs = self.per_seed(figure), other.per_seed(figure)
        if len(mine) != len(theirs):
            raise ValueError(f"{len(mine)} seeds against {len(theirs)}: a paired difference "
                             "needs the same seeds")
        d = paired_difference([mine], theirs)
        return d.mean, d.high - d.mean

    @property
    def device_slots_per_s(self) -> float:
        slots = sum(len(r.devices) * len(r.devices[0].budgets) for r in self.runs if r.devices)
        seconds = sum(r.seconds for r in self.runs)
        return slots / seconds if seconds > 0 else math.nan


def evaluate_fleet(dataset: CovisibilityDataset, channel: Callable[[int], MarkovChannel |
                   TraceChannel], config: FleetConfig, allocators: Sequence[str],
                   make_policy: Callable[[], MapPolicy], seeds: Sequence[int],
                   progress: Callable[[str], None] | None = None,
                   speed: Callable[[int], float] | None = None) -> list[AllocatorResult]:
    """Every allocator over ``seeds``, the same walks and uplinks for each (device i of seed s:
    walk and channel of seed s × 1000 + i; ``channel(i)`` builds device i's channel,
    ``speed(i)`` gives its walking speed)."""
    results = []
    for allocator in allocators:
        cfg = replace(config, allocator=allocator)
        cfg.check()
        sim = FleetSimulator([(dataset, channel(i)) for i in range(cfg.devices)], cfg,
                             make_policy, [speed(i) if speed else cfg.sim.speed
                                           for i in range(cfg.devices)])
        runs = []
        for seed in seeds:
            run = sim.run(seed)
            runs.append(run)
            if progress:
                progress(f"{allocator}: seed {seed} mean υ {run.mean_uncertainty:.1f}, lost "
                         f"{run.lost_share:.1%}, Jain {run.jain_tracked:.3f} "
                         f"({run.seconds:.1f} s)")
        results.append(AllocatorResult(allocator, runs))
    return results
