"""A live run at a glance: one PNG beside its table.

Left, the edge's final map from above (x right, z forward: the camera convention's ground
plane) — its points, its kept keyframes — with the device's trajectory, frames it tracked and
frames it did not told apart, and the ground truth moved into the map frame by ATE's alignment.
Relocalisations are starred on the trajectory. Right, per slot: the map's size (the slots
where the edge brought archived keyframes back marked, with how many), υ (a lost next-slot
frame scoring 0) with the lost share, and the uplink rate d_k with what the device achieved.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from msg_schemas.headers import time_key
from twinslam.live.report import relocalised_stamps
from twinslam.live.run_log import RunLog
from twinslam.live.tracking_quality import truth_in_map
from twinslam.reporting import pyplot

# matplotlib loads when a run is drawn, not with every module that imports this one
if TYPE_CHECKING:
    from matplotlib.axes import Axes

#: at most this many map points drawn (a random subset beyond it: the picture, not the data)
MAX_POINTS_DRAWN = 20_000


def plot_run(record: RunLog, title: str, path: Path) -> None:
    """Write ``path`` (PNG) for the run ``record`` holds."""
    plt = pyplot()
    fig = plt.figure(figsize=(13, 6.5), layout="constrained")
    grid = fig.add_gridspec(3, 2, width_ratios=(1.15, 1.0))
    _top_down(fig.add_subplot(grid[:, 0]), record)
    first = fig.add_subplot(grid[0, 1])
    axes = [first, *(fig.add_subplot(grid[i, 1], sharex=first) for i in (1, 2))]
    _over_slots(axes, record)
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _top_down(ax_: Axes, record: RunLog) -> None:
    if record.maps:
        final = record.maps[max(record.maps)]
        pts = final.positions
        if len(pts) > MAX_POINTS_DRAWN:
            pts = pts[np.random.default_rng(0).choice(len(pts), MAX_POINTS_DRAWN, False)]
        ax_.scatter(pts[:, 0], pts[:, 2], s=0.5, c="0.7", label=f"map points "
                    f"({len(final.positions)})", rasterized=True)
        kf = final.keyframe_poses[:, :3, 3] if len(final.keyframe_poses) else np.zeros((0, 3))
        ax_.scatter(kf[:, 0], kf[:, 2], marker="^", s=40, c="tab:blue",
                    label=f"kept keyframes ({len(kf)})")
    tracked = {time_key(f.stamp): bool(f.tracked) for s in record.summaries.values()
               for f in s.frames}
    stamps = sorted(record.poses)
    if stamps:
        xyz = np.array([record.poses[s][:3, 3] for s in stamps])
        ok = np.array([tracked.get(s, True) for s in stamps])
        ax_.plot(xyz[:, 0], xyz[:, 2], c="tab:green", lw=1.0, label="device")
        ax_.scatter(xyz[~ok, 0], xyz[~ok, 2], s=6, c="tab:red",
                    label=f"device, not tracked ({int((~ok).sum())} frames)")
        back = relocalised_positions(record)
        if len(back):
            ax_.scatter(back[:, 0], back[:, 2], marker="*", s=90, c="tab:orange",
                        edgecolors="k", linewidths=0.5, zorder=5,
                        label=f"relocalised ({len(back)})")
    truth = truth_in_map(record.poses, record.ground_truth)
    if truth:
        gt = np.array([truth[s][:3, 3] for s in sorted(truth)])
        ax_.plot(gt[:, 0], gt[:, 2], c="k", lw=0.8, ls="--",
                 label="ground truth (aligned)")
    ax_.set(xlabel="x (m)", ylabel="z (m)", title="the edge's final map, from above")
    ax_.set_aspect("equal", adjustable="datalim")
    ax_.legend(loc="best", fontsize=8, markerscale=2)


def relocalised_positions(record: RunLog) -> np.ndarray:
    """Where the device counted itself tracked again after a relocalisation (N×3, its own
    estimates): the places a wrong relocalisation would show as a jump in the trajectory."""
    xyz = [record.poses[k][:3, 3] for k in relocalised_stamps(record) if k in record.poses]
    return np.array(xyz).reshape(-1, 3)


def _over_slots(axes: list[Axes], record: RunLog) -> None:
    slots = sorted(record.stats)
    stats = [record.stats[s] for s in slots]
    size_ax, u_ax, rate_ax = axes
    size_ax.plot(slots, [s.map_size for s in stats], c="tab:blue", marker=".")
    restores = [(slot, s.map_size, int(s.restored_keyframes)) for slot, s in zip(slots, stats,
                                                                               strict=True)
                if s.restored_keyframes > 0]
    if restores:
        x, y, n = zip(*restores, strict=True)
        size_ax.scatter(x, y, marker="P", s=60, c="tab:green", edgecolors="k", linewidths=0.5,
                        zorder=5, label=f"restores from the archive ({sum(n)} keyframes)")
        for slot, size, count in restores:
            size_ax.annotate(f"+{count}", (slot, size), textcoords="offset points",
                             xytext=(0, 6), ha="center", fontsize=7, color="tab:green")
        size_ax.legend(loc="best", fontsize=8)
    size_ax.set(ylabel="map (keyframes)", title="per slot")
    u_ax.plot(slots, [s.mean_uncertainty if math.isfinite(s.mean_uncertainty) else np.nan
                      for s in stats], c="tab:purple", marker=".", label="mean υ")
    u_ax.set(ylabel="υ (lost = 0)")
    lost = u_ax.twinx()
    lost.bar(slots, [100 * s.lost_share for s in stats], color="tab:red", alpha=0.3,
             label="lost share")
    lost.set(ylabel="lost (%)", ylim=(0, 100))
    rates = sorted(record.summaries)
    rate_ax.step(rates, [record.summaries[s].rate_mbps for s in rates], where="mid",
                 c="tab:orange", label="d_k (channel)")
    sent = sorted(record.throughput)
    rate_ax.plot(sent, [record.throughput[s].achieved_mbps for s in sent], c="k", ls="",
                 marker="o", ms=3, label="achieved")
    rate_ax.set(xlabel="slot", ylabel="uplink (Mbit/s)")
    from matplotlib.ticker import MaxNLocator

    rate_ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    rate_ax.legend(loc="best", fontsize=8)
