"""The tables and the figure of docs/results/many-devices.md, from the
files the commands wrote (every command is on that page beside its table):

* ``scaling`` — fleet/edge-scaling.csv (``python -m bench.edge_scaling``) and
  fleet/sim-scaling.csv (``python -m bench.fleet``) → fleet/scaling.png: live, the edge's
  compute per device-slot, the latency to the map update and the missed deadlines vs N; in the
  simulator, milliseconds a fleet slot vs N;
* ``edges`` — fleet/edge-scaling-pools-edges.csv (``python -m bench.edge_scaling --edges 1,2
  --pools cores,one``) and fleet/edge-scaling-arrays.csv (``--edges 1,2 --pools one``, a later
  commit) beside fleet/edge-scaling-default-1s.csv (the default edge before) →
  fleet/edge-scaling-edges.png: the late share and the edges' CPU per device vs N, a line per
  setting (the math pools, the edge processes);
* ``hosts`` — fleet/edge-hosts/{loopback,hosts}-R.csv (``python -m bench.edge_scaling
  --edges 2 [--hosts]``, run R of each, alternated) → fleet/edge-hosts.png: the late share
  and the summaries → map p95 vs N, the two edge processes on one loopback domain and on two
  edge hosts (network namespaces), every run a line;
* ``stagger`` — fleet/host-and-stagger/{in-step,staggered}-R.csv (``python -m
  bench.edge_scaling --edges 1,2 --devices 16,24,32 [--stagger 10]``, run R of each) →
  fleet/host-and-stagger.png: the late share vs N with the devices walking in step and at
  places of their own, one and two edge processes, every run a line; and where the host's
  two cores went: the edges', the emulated devices' and what stayed idle;
* ``revisit`` — fleet/loop-worker-revisit/{nice,share}-N-roundR.csv and their ``-slots``
  files (``python -m bench.edge_scaling --recording R2 --devices N --edges 2
  --loop-worker-niceness 0,10`` or ``--loop-worker-share 1,0.5,0.25``, R2 a 39-slot walk that
  comes back) → fleet/loop-worker-revisit.png and a table: each run's late share and loops
  closed, a point a run, and when the loops closed (the slot of each, all runs of a setting
  together), for the loop workers at the slots' priority, below it and capped;
* ``curve`` — fleet/scaling-curve/curve.csv (``python -m bench.edge_scaling --devices
  4,8,12,16,24,32,50 --edges 1,2``, the default edge and emulator of 2026-12-05) beside
  fleet/edge-scaling-default-1s.csv (the default edge on 2026-11-29) →
  fleet/edge-scaling-curve.png: the late share, the edges' CPU a device-slot and the host's
  cores (the edges', the emulator's, idle) vs N, one and two edge processes;
* ``fifty`` — fleet/staggered/*.csv (``python -m bench.edge_scaling --devices 50 --edges 2
  [--stagger 10] [--merge-maps on --places 38] [--compute-budget B] [--edge-param
  loop_closing:=false]``, two runs of each setting) → fleet/fifty-devices.png: fifty devices
  on one 2-core host, each setting's late share and summaries → map p95, a point a run, with
  the goal's 5 % and 1 s drawn;
* ``two-hosts`` — fleet/two-hosts/*.csv and their ``bench.process_cpu --threads`` reports
  (``python -m bench.process_cpu --threads -- python -m bench.edge_scaling --devices 50
  --edges 2 --places 38 …`` on one host, and each half on a host of its own: ``--devices 25
  --places 13`` — the twelve pairs and one — or ``--places 25``, the 25 alone; ``--stagger 10
  --merge-maps on [--compute-budget 0.6] [--hosts]``) → fleet/fifty-on-two-hosts.png: each
  setting's late share and summaries → map p95, a point a run, and the edges' cores by thread;
* ``one-core`` — fleet/one-core/{alone,half-sharing}-R.csv (``python -m bench.edge_scaling
  --devices N --edges 1 --stagger 10 --edge-cores 1 --device-cores 0``, with ``--places 20``
  for devices alone in their places, ``--places 3N/4 --merge-maps on`` for half of them in
  pairs sharing one; round R) → fleet/one-core.png: what one edge process on a core of its
  own carries, the emulated devices on the other core: the late share and summaries → map
  p95 vs N, a line a round;
* ``emulator FILE…`` — ``python -m bench.edge_scaling --devices 50 --edges 1,2
  --emulator-executor single,events`` runs, one file a round: per emulator and edge count,
  each round's late share, answered device-slots, summaries → map p95, the edges' and the
  emulator's CPU and the host's idle share, the rounds side by side;
* ``sim FILE…`` — ``twinslam sim --devices N --csv`` files: per allocator the fleet mean (over
  devices, then seeds) of mean υ, lost share and υ tracked, Jain's index of the devices'
  tracked shares, and the paired differences with ``equal`` on the same seeds;
* ``split BEFORE.csv AFTER.csv`` — two ``twinslam sim --devices N --csv`` files of the same
  fleets and seeds that differ in one setting (``--cell-split``): per allocator the second
  minus the first, paired by seed;
* ``live FILE`` — a ``twinslam launch --devices N`` fleet_runs.csv: per allocator the devices'
  failure share (frames they could not track), ATE, the edge's lost share and keyframe shares,
  paired by seed with ``equal``.

    .venv/bin/python docs/figures/fleet_tables.py scaling
    .venv/bin/python docs/figures/fleet_tables.py edges
    .venv/bin/python docs/figures/fleet_tables.py hosts
    .venv/bin/python docs/figures/fleet_tables.py stagger
    .venv/bin/python docs/figures/fleet_tables.py revisit
    .venv/bin/python docs/figures/fleet_tables.py fifty
    .venv/bin/python docs/figures/fleet_tables.py two-hosts
    .venv/bin/python docs/figures/fleet_tables.py one-core
    .venv/bin/python docs/figures/fleet_tables.py sim docs/figures/fleet/sim-n10-lff.csv
    .venv/bin/python docs/figures/fleet_tables.py split \
        docs/figures/fleet/sim-n10-lff-cell400.csv \
        docs/figures/fleet/sim-n10-lff-cell400-split.csv
    .venv/bin/python docs/figures/fleet_tables.py live docs/figures/fleet/live-runs.csv
"""

from __future__ import annotations

import csv
import math
import statistics
import sys
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from twinslam.allocation.allocators import jain_index
from twinslam.reporting import mean_ci95, pyplot

HERE = Path(__file__).resolve().parent


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _fleet_means(rows: list[dict[str, str]], figures: dict[str, str]
                 ) -> dict[str, dict[int, dict[str, float]]]:
    """allocator → seed → figure → the mean over that seed's devices (``figures``: name →
    column; "jain" is Jain's index of the devices' tracked shares)."""
    by: dict[tuple[str, int], list[dict[str, str]]] = defaultdict(list)
    for r in rows:
        by[(r["allocator"], int(r["seed"]))].append(r)
    out: dict[str, dict[int, dict[str, float]]] = defaultdict(dict)
    for (allocator, seed), devices in by.items():
        means = {}
        for name, column in figures.items():
            values = [float(d[column]) for d in devices if math.isfinite(float(d[column]))]
            means[name] = sum(values) / len(values) if values else math.nan
        tracked = [1 - float(d["lost_share"]) for d in devices]
        if "untracked_frames" in devices[0]:
            tracked = [1 - int(d["untracked_frames"]) / max(1, int(d["frames"]))
                       for d in devices]
            means["failed"] = 1 - sum(tracked) / len(tracked)
        means["jain"] = jain_index(tracked)
        out[allocator][seed] = means
    return out


def _cell(values: list[float], digits: int, scale: float = 1.0) -> str:
    mean, half = mean_ci95([v * scale for v in values])
    return f"{mean:.{digits}f} ± {half:.{digits}f}" if math.isfinite(half) else \
        f"{mean:.{digits}f}"


def _table(path: Path, figures: dict[str, str], shown: list[tuple[str, str, int, float]],
           paired: list[tuple[str, str, int, float]]) -> None:
    means = _fleet_means(_rows(path), figures)
    base = means.get("equal")
    seeds = sorted(next(iter(means.values())))
    devices = len({r["device"] for r in _rows(path)})
    print(f"\n{path.name}: {devices} devices, {len(seeds)} seeds (mean ± 95 % CI over seeds "
          "of the mean over devices; Δ paired by seed against equal)\n")
    head = [title for _, title, _, _ in shown] + [f"Δ {t} vs equal" for _, t, _, _ in paired]
    print("| allocator | " + " | ".join(head) + " |")
    print("|---" * (len(head) + 1) + "|")
    for allocator, by_seed in means.items():
        cells = [_cell([by_seed[s][name] for s in seeds], d, k) for name, _, d, k in shown]
        for name, _, d, k in paired:
            if base is None or allocator == "equal":
                cells.append("—")
            else:
                cells.append(_cell([by_seed[s][name] - base[s][name] for s in seeds], d, k))
        print(f"| {allocator} | " + " | ".join(cells) + " |")


def sim(paths: list[str]) -> None:
    figures = {"mean": "mean_uncertainty", "lost": "lost_share",
               "tracked": "tracked_uncertainty", "budget": "mean_budget"}
    for path in paths:
        _table(Path(path), figures,
               [("mean", "mean υ", 1, 1.0), ("lost", "lost (%)", 2, 100.0),
                ("tracked", "υ tracked", 1, 1.0), ("jain", "Jain", 3, 1.0)],
               [("lost", "lost (pts)", 2, 100.0), ("mean", "mean υ", 1, 1.0)])


def split(paths: list[str]) -> None:
    """Two runs of the same fleets and seeds that differ in one setting (the cell split):
    per allocator, the second minus the first, paired by seed."""
    if len(paths) != 2:
        raise SystemExit("split takes two files: BEFORE.csv AFTER.csv")
    figures = {"mean": "mean_uncertainty", "lost": "lost_share",
               "tracked": "tracked_uncertainty"}
    before, after = (_fleet_means(_rows(Path(p)), figures) for p in paths)
    print(f"\n{Path(paths[1]).name} minus {Path(paths[0]).name}, paired by seed (mean ± 95 % "
          "CI over seeds of the mean over devices)\n")
    print("| allocator | Δ lost (pts) | Δ mean υ | Δ lost (pts) per seed |")
    print("|---|---|---|---|")
    for allocator, by_seed in after.items():
        seeds = sorted(set(by_seed) & set(before.get(allocator, {})))
        lost = [100 * (by_seed[s]["lost"] - before[allocator][s]["lost"]) for s in seeds]
        mean = [by_seed[s]["mean"] - before[allocator][s]["mean"] for s in seeds]
        print(f"| {allocator} | {_cell(lost, 2)} | {_cell(mean, 1)} | "
              + ", ".join(f"{v:+.2f}" for v in sorted(lost)) + " |")


def live(paths: list[str]) -> None:
    figures = {"mean": "mean_uncertainty", "lost": "lost_share", "ate": "ate_m",
               "budget": "mean_budget", "late": "late_slots", "dropped": "frames_dropped"}
    for path in paths:
        _table(Path(path), figures,
               [("failed", "device failed (%)", 1, 100.0), ("ate", "ATE (m)", 3, 1.0),
                ("lost", "edge lost (%)", 1, 100.0), ("mean", "mean υ", 0, 1.0),
                ("jain", "Jain", 3, 1.0), ("late", "late slots", 1, 1.0),
                ("dropped", "frames dropped", 1, 1.0)],
               [("failed", "device failed (pts)", 1, 100.0), ("ate", "ATE (m)", 3, 1.0)])


def scaling() -> None:
    plt = pyplot()
    live_rows = _rows(HERE / "fleet/edge-scaling.csv")
    n = [int(r["devices"]) for r in live_rows]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    for column, label, style in (("compute_ms_median", "edge compute, median", "o-"),
                                 ("compute_ms_p95", "edge compute, p95", "o--"),
                                 ("latency_ms_median", "summaries → map, median", "s-"),
                                 ("latency_ms_p95", "summaries → map, p95", "s--")):
        ax.plot(n, [float(r[column]) for r in live_rows], style, label=label)
    ax.axhline(2000, color="grey", lw=1)
    ax.text(n[-1], 2150, "slot period (2 s)", color="grey", fontsize=8, ha="right")
    ax.set(xlabel="devices served by one edge", ylabel="ms per device-slot", yscale="log",
           title="live edge (2 cores): time per device-slot")
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[1]
    ax.plot(n, [100 * float(r["missed_share"]) for r in live_rows], "o-",
            label="device-slots whose map came after a slot period")
    ax.plot(n, [100 * float(r["edge_cpu_share"]) for r in live_rows], "s-",
            label="edge process CPU (% of one core)")
    budget = HERE / "fleet/edge-scaling-budget.csv"
    if budget.is_file():                  # the same with compute_budget (one run a point)
        rows = _rows(budget)
        share = float(rows[0]["compute_budget"])
        ax.plot([int(r["devices"]) for r in rows], [100 * float(r["missed_share"]) for r in rows],
                "o--", color="C0", label=f"late, with compute_budget {share:g}")
    ax.set(xlabel="devices served by one edge", ylabel="%", ylim=(0, 105),
           title="live edge: missed deadlines and its CPU")
    ax.legend(fontsize=8, loc="upper left")
    ax = axes[2]
    sim_rows = _rows(HERE / "fleet/sim-scaling.csv")
    for allocator in ("equal", "motion", "twin"):
        mine = [r for r in sim_rows if r["allocator"] == allocator]
        ax.plot([int(r["devices"]) for r in mine],
                [1000 * int(r["devices"]) / float(r["device_slots_per_s"]) for r in mine],
                "o-", label=allocator)
    ax.set(xlabel="devices", ylabel="ms per slot of the whole fleet", xscale="log",
           yscale="log", title="simulator (one core): a slot of N devices")
    ax.legend(fontsize=8, title="allocator")
    _save(fig, "fleet/scaling.png")


def edges() -> None:
    """The default edge at 1 s slots: before, and per math-pool and edge-process setting."""
    plt = pyplot()
    series: dict[str, list[dict[str, str]]] = {
        "before (2026-11-29 21:22, pools a thread a core)":
            _rows(HERE / "fleet/edge-scaling-default-1s.csv")}
    for r in _rows(HERE / "fleet/edge-scaling-pools-edges.csv"):
        edges_word = "edge" if r["edges"] == "1" else "edges"
        pools = "a thread a core" if r["pools"] == "cores" else "one thread"
        label = f"faiss matcher, pools {pools}, {r['edges']} {edges_word}"
        series.setdefault(label, []).append(r)
    for r in _rows(HERE / "fleet/edge-scaling-arrays.csv"):
        edges_word = "edge" if r["edges"] == "1" else "edges"
        series.setdefault(f"+ votes and candidates on arrays, {r['edges']} {edges_word}",
                          []).append(r)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    _late_and_cpu(axes, series, cpu_unit=100.0)
    axes[1].set(xlabel="devices", ylabel="% of one core per device",
                title="the edges' CPU per device (falls where slots go unserved)")
    axes[0].legend(fontsize=7, loc="upper left")
    _save(fig, "fleet/edge-scaling-edges.png")


def _late_and_cpu(axes: Any, series: dict[str, list[dict[str, str]]], cpu_unit: float
                  ) -> None:
    """A line a series on the late share (``axes[0]``) and the edges' CPU per device
    (``axes[1]``, the core's share times ``cpu_unit``), the first series dashed: the one
    before."""
    for i, (label, rows) in enumerate(series.items()):
        n = [int(r["devices"]) for r in rows]
        style = "k--" if i == 0 else f"C{i}o-"
        axes[0].plot(n, [100 * float(r["missed_share"]) for r in rows], style, label=label)
        axes[1].plot(n, [cpu_unit * float(r["edge_cpu_share"]) / int(r["devices"])
                         for r in rows], style, label=label)
    _late_share_axis(axes[0], "late maps (2 cores, one run a point)", goal_x=1)


def curve() -> None:
    """The edge's scaling curve before (2026-11-29) and now, at the default 1 s slots."""
    plt = pyplot()
    series: dict[str, list[dict[str, str]]] = {
        "2026-11-29, 1 edge process (before)": _rows(HERE / "fleet/edge-scaling-default-1s.csv")}
    now: dict[str, list[dict[str, str]]] = {}       # today's runs, by their edge processes
    for r in _rows(HERE / "fleet/scaling-curve/curve.csv"):
        word = "process" if r["edges"] == "1" else "processes"
        now.setdefault(f"{r['edges']} edge {word}", []).append(r)
    series.update({f"2026-12-05, {edges}": rows for edges, rows in now.items()})
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.4))
    # a core's share over the run, per device and 1 s slot: ms of a core a device-slot
    _late_and_cpu(axes, series, cpu_unit=1000.0)
    for i, (edges, rows) in enumerate(now.items(), start=1):    # colours as the series'
        n = [int(r["devices"]) for r in rows]
        axes[2].plot(n, [100 * float(r["edge_cpu_share"]) for r in rows], f"C{i}o-",
                     label=f"the edges, {edges}")
        axes[2].plot(n, [100 * float(r["devices_cpu_share"]) for r in rows], f"C{i}s:",
                     label=f"the emulated devices, {edges}")
        axes[2].plot(n, [200 * float(r["host_idle_share"]) for r in rows], f"C{i}^--",
                     label=f"idle, {edges}")
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].axhline(40, color="grey", lw=1)
    axes[1].text(1, 42, "fifty on two cores: 40 ms for everything", color="grey", fontsize=8)
    axes[1].set(xlabel="devices", ylabel="ms of a core a device-slot",
                title="the edges' CPU per device (falls where slots go unserved)")
    axes[2].set(xlabel="devices", ylabel="% of one core", ylim=(0, 200),
                title="where the host's two cores go")
    axes[2].legend(fontsize=6, loc="upper left")
    _save(fig, "fleet/edge-scaling-curve.png")


def _save(fig: Any, name: str) -> None:
    """Write the figure beside this script as ``name`` and say where."""
    fig.tight_layout()
    out = HERE / name
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def _late_share_axis(ax: Any, title: str, goal_x: float) -> None:
    """The late share's axis: % of device-slots whose map came after the 1 s slot, with the
    goal's 5 % drawn at ``goal_x``."""
    ax.axhline(5, color="grey", lw=1)
    ax.text(goal_x, 7, "goal: 5 % late", color="grey", fontsize=8)
    ax.set(xlabel="devices", ylabel="% of device-slots whose map came after 1 s",
           ylim=(0, 100), title=title)


def _late_and_p95_by_run(series: Sequence[tuple[str, list[Path], str]], title: str,
                         name: str, runs_are: str = "runs") -> None:
    """The late share and the summaries → map p95 against the devices served, a line a run
    (``series``: a colour, the runs' CSVs and a label each), saved as ``name``."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    for colour, runs, label in series:
        for i, path in enumerate(runs):
            rows = _rows(path)
            n = [int(r["devices"]) for r in rows]
            legend = f"{label}, {len(runs)} {runs_are}" if i == 0 else None
            axes[0].plot(n, [100 * float(r["missed_share"]) for r in rows], "o-",
                         color=colour, alpha=0.8, label=legend)
            axes[1].plot(n, [float(r["latency_ms_p95"]) / 1000 for r in rows], "o-",
                         color=colour, alpha=0.8, label=legend)
    _late_share_axis(axes[0], title, goal_x=8)
    axes[1].axhline(1, color="grey", lw=1)
    axes[1].set(xlabel="devices", ylabel="seconds", ylim=(0, None),
                title="summaries → map update, p95")
    axes[0].legend(fontsize=8, loc="upper left")
    _save(fig, name)


def hosts() -> None:
    """Two edge processes on one loopback domain against two edge hosts, run by run."""
    folder = HERE / "fleet/edge-hosts"
    _late_and_p95_by_run(
        [("C0", sorted(folder.glob("loopback-*.csv")), "two edge processes, one loopback domain"),
         ("C3", sorted(folder.glob("hosts-*.csv")), "two edge hosts (network namespaces, UDP)")],
        "late maps (2 cores shared by every host)", "fleet/edge-hosts.png")


def stagger() -> None:
    """Devices walking in step against at places of their own, one and two edge processes;
    and what of the host's cores the edges, the emulated devices and nothing used."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    for kind, style, walk in (("in-step", "-", "in step"), ("staggered", ":",
                                                            "starts over 10 slots")):
        runs = sorted((HERE / "fleet/host-and-stagger").glob(f"{kind}-[0-9].csv"))
        for i, path in enumerate(runs):
            rows = [r for r in _rows(path) if int(r["devices"]) >= 16]
            for edges, colour in (("1", "C0"), ("2", "C3")):
                mine = [r for r in rows if r["edges"] == edges]
                n = [int(r["devices"]) for r in mine]
                name = (f"{walk}, {edges} edge process{'es' if edges == '2' else ''}, "
                        f"{len(runs)} runs") if i == 0 else None
                axes[0].plot(n, [100 * float(r["missed_share"]) for r in mine], "o" + style,
                             color=colour, alpha=0.8, label=name)
                if kind == "in-step":
                    axes[1].plot(n, [100 * float(r["host_idle_share"]) for r in mine], "o-",
                                 color=colour, alpha=0.8,
                                 label=f"idle, {edges} edge process"
                                       f"{'es' if edges == '2' else ''}" if i == 0 else None)
                    axes[1].plot(n, [50 * float(r["edge_cpu_share"]) for r in mine], "s--",
                                 color=colour, alpha=0.5,
                                 label=f"the edge{'s' if edges == '2' else ''}"
                                       if i == 0 else None)
                    axes[1].plot(n, [50 * float(r["devices_cpu_share"]) for r in mine], "^:",
                                 color=colour, alpha=0.5,
                                 label="the emulated devices" if i == 0 else None)
    _late_share_axis(axes[0], "late maps (2 cores, the devices on them too)", goal_x=26)
    axes[0].legend(fontsize=7, loc="upper left")
    axes[1].set(xlabel="devices", ylabel="% of the host's two cores", ylim=(0, 100),
                title="where the host's CPU went (devices in step)")
    axes[1].legend(fontsize=7, loc="upper right")
    _save(fig, "fleet/host-and-stagger.png")


def _worker_setting(row: dict[str, str]) -> str:
    """A fleet row's loop-worker setting as the figure names it."""
    nice = int(row["loop_worker_niceness"])
    share = float(row["loop_worker_share"]) if row["loop_worker_share"] else math.nan
    if nice > 0:
        return f"{nice} nice steps below"
    if not math.isnan(share) and share < 1:
        return f"a {share:g} share of a core"
    return "the slots' priority, uncapped"


def _closing_slots(path: Path) -> dict[str, list[int]]:
    """The slot of every loop a ``--slots-csv`` file's devices closed, by setting (the
    column counts the loops a device closed so far)."""
    slots: dict[str, list[int]] = defaultdict(list)
    rows = sorted(_rows(path), key=lambda r: (r["loop_worker_niceness"],
                                              r["loop_worker_share"], r["device"],
                                              int(r["slot"])))
    closed: dict[tuple[str, str, str], int] = {}
    for r in rows:
        key = (r["loop_worker_niceness"], r["loop_worker_share"], r["device"])
        now = int(float(r["loops_closed"] or 0))
        slots[_worker_setting(r)] += [int(r["slot"])] * (now - closed.get(key, 0))
        closed[key] = now
    return slots


def revisit() -> None:
    """The loop workers at the slots' priority, below it and capped, on a walk that comes
    back: the late share and the loops each run closed, and when they closed."""
    plt = pyplot()
    folder = HERE / "fleet/loop-worker-revisit"
    colours = {"the slots' priority, uncapped": "C0", "10 nice steps below": "C3",
               "a 0.5 share of a core": "C1", "a 0.25 share of a core": "C2"}
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    print("| devices | loop worker | late, each run | loops closed, each run | "
          "median slot a loop closed |")
    print("|---|---|---|---|---|")
    for devices, marker in (("12", "o"), ("16", "s")):
        late: dict[str, list[float]] = defaultdict(list)
        loops: dict[str, list[int]] = defaultdict(list)
        when: dict[str, list[int]] = defaultdict(list)
        for path in sorted(folder.glob(f"*-{devices}-round[0-9].csv")):
            for r in _rows(path):
                late[_worker_setting(r)].append(100 * float(r["missed_share"]))
                loops[_worker_setting(r)].append(int(r["loops_closed"]))
            slots = path.with_name(path.stem + "-slots.csv")
            if slots.exists():
                for setting, closed in _closing_slots(slots).items():
                    when[setting] += closed
        for setting, colour in colours.items():
            if setting not in late:
                continue
            first = setting == next(iter(colours))
            x = [list(colours).index(setting) + (0.15 if devices == "16" else -0.15)] * \
                len(late[setting])
            axes[0].plot(x, late[setting], marker, color=colour, alpha=0.8,
                         label=f"{devices} devices" if first else None)
            axes[1].plot(x, loops[setting], marker, color=colour, alpha=0.8)
            middle = sorted(when[setting])[len(when[setting]) // 2] if when[setting] else "–"
            print(f"| {devices} | {setting} | "
                  f"{', '.join(f'{v:.1f} %' for v in late[setting])} | "
                  f"{', '.join(map(str, loops[setting]))} | {middle} |")
            if devices == "12" and when[setting]:
                runs = len(loops[setting])
                closing = sorted(when[setting])
                axes[2].step(closing, [(i + 1) / runs for i in range(len(closing))],
                             where="post", color=colour, label=f"{setting} ({runs} runs)")
    names = [name.replace(", ", ",\n").replace(" of a", "\nof a").replace(" below", "\nbelow")
             for name in colours]
    for ax, label in ((axes[0], "% of device-slots whose map came after 1 s"),
                      (axes[1], "loops the edges closed in the run")):
        ax.set_xticks(range(len(colours)), names, fontsize=7)
        ax.set(ylabel=label)
    axes[0].axhline(5, color="grey", lw=1)
    axes[0].set(ylim=(0, 100), title="late maps, two edge processes, 2 cores")
    axes[0].legend(fontsize=7, loc="upper right")
    axes[1].set(ylim=(0, None), title="loops closed (12 devices: 36 uncapped)")
    axes[2].set(xlabel="slot of the walk (it turns back after slot 19)",
                ylabel="loops closed so far, a run's mean", title="when they closed, 12 devices")
    axes[2].legend(fontsize=7, loc="lower right")
    _save(fig, "fleet/loop-worker-revisit.png")


#: the emulators as the table names them
EMULATORS = {"single": "`SingleThreadedExecutor`", "events": "`EventsExecutor`"}


def emulator_table(paths: Sequence[Path]) -> list[str]:
    """The emulated devices' executor against the edges' late share: a row an emulator and
    edge count (by edges, then the emulators in :data:`EMULATORS`' order), each figure of
    every round (a file each) side by side."""
    rounds = [{(r["emulator_executor"], r["edges"]): r for r in _rows(p)} for p in paths]

    def each(key: tuple[str, str], figure: Callable[[dict[str, str]], str]) -> str:
        return " / ".join(figure(found[key]) for found in rounds)

    def share(key: tuple[str, str], column: str, digits: int) -> str:
        return each(key, lambda r: f"{100 * float(r[column]):.{digits}f}")

    lines = ["| emulator | edges | late, rounds " + " / ".join(
                 str(k + 1) for k in range(len(paths))) +
             " | answered of 1000 | summaries → map p95, s | the edges' CPU "
             "| the emulator's CPU | host idle |",
             "|---|---|---|---|---|---|---|---|"]
    for edges_n in sorted({e for found in rounds for _, e in found}, key=int):
        for name, label in EMULATORS.items():
            key = (name, edges_n)
            if not all(key in found for found in rounds):
                continue
            p95 = each(key, lambda r: f"{float(r['latency_ms_p95']) / 1000:.1f}")
            lines.append(f"| {label} | {edges_n} | {share(key, 'missed_share', 1)} % "
                         f"| {each(key, lambda r: r['answered'])} | {p95} "
                         f"| {share(key, 'edge_cpu_share', 0)} % "
                         f"| {share(key, 'devices_cpu_share', 0)} % "
                         f"| {share(key, 'host_idle_share', 0)} % |")
    return lines


#: fleet/staggered/'s settings, in the order drawn: (the file stem before the run's number, or
#: several stems of runs of the same setting, label)
FIFTY_SETTINGS = (
    ("in-step-loops-off-before", "in step, no loop closer (before the integration cut)"),
    ("in-step-loops-off", "in step, no loop closer"),
    ("in-step-budget06", "in step, compute_budget 0.6"),
    ("staggered-default", "starts over 10 slots, the default edge"),
    ("staggered-budget08", "starts over 10 slots, compute_budget 0.8"),
    ("staggered-budget06", "starts over 10 slots, compute_budget 0.6"),
    ("staggered-loops-off", "starts over 10 slots, no loop closer"),
    ("half-shared-default-before",
     "half in pairs sharing a place (starts over 10 slots), the default edge"),
    ("half-shared-loops-off-before", "half sharing, no loop closer"),
    ("half-shared-budget06-before", "half sharing, budget 0.6, looks not paused"),
    (("half-shared-budget06", "half-shared-budget06-words-same-priority"),
     "half sharing, budget 0.6, looks paused"),
    ("half-shared-budget06-words-lowest-priority",
     "the same, the words learned at the lowest priority"),
    ("half-shared-budget06-filing-learns", "the same, alternated with the next"),
    ("half-shared-budget06-filing-files", "the same, the filing learns no words (now)"),
)


def fifty() -> None:
    """Fifty devices on two edge processes of one 2-core host: each setting's runs, late
    share and summaries → map p95."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), sharey=True)
    folder = HERE / "fleet/staggered"
    for y, (stems, _) in enumerate(FIFTY_SETTINGS):
        stems = (stems,) if isinstance(stems, str) else stems
        rows = [_rows(path)[0] for stem in stems
                for path in sorted(folder.glob(f"{stem}-[0-9].csv"))]
        stem = stems[0]
        late = [100 * float(r["missed_share"]) for r in rows]
        p95 = [float(r["latency_ms_p95"]) / 1000 for r in rows]
        axes[0].plot(late, [y] * len(late), "o", color="C3" if "half" in stem else "C0")
        axes[1].plot(p95, [y] * len(p95), "o", color="C3" if "half" in stem else "C0")
    _goal_axes(axes, [label for _, label in FIFTY_SETTINGS])
    _save(fig, "fleet/fifty-devices.png")


def _goal_axes(axes: Any, labels: list[str]) -> None:
    """The fleet goal's two panels: a setting a row (``labels``, top down), the late share
    with the goal's 5 % and the summaries → map p95 with its 1 s."""
    axes[0].set_yticks(range(len(labels)), labels, fontsize=8)
    axes[0].invert_yaxis()
    axes[0].axvline(5, color="grey", lw=1)
    axes[0].set(xlabel="% of device-slots whose map came after 1 s", xlim=(-2, 102),
                title="late maps (goal: 5 %), a point a run")
    axes[1].axvline(1, color="grey", lw=1)
    axes[1].set(xlabel="seconds", xlim=(0, None), title="summaries → map update, p95 (goal: 1 s)")


TWO_HOSTS_SETTINGS = (
    ("one-host-fifty-budget06", "fifty on one host (24 in pairs sharing a place)"),
    ("pairs-half-budget06", "host A: the 12 pairs and one (25)"),
    ("pairs-half-default", "host A, the default edge"),
    ("pairs-half-hosts-budget06", "host A, devices across a namespace bridge"),
    ("alone-half-budget06", "host B: the 25 alone in their places"),
    ("alone-half-default", "host B, the default edge"),
    ("alone-half-hosts-budget06", "host B, devices across a namespace bridge"),
)
#: an edge process's threads (``bench.process_cpu --threads`` labels) as the figure groups them
EDGE_THREADS = (("main thread", "slot threads"), ("threads loop-closer_#", "loop worker"),
                ("threads place-words#", "words' learning"))


def process_threads(path: Path) -> tuple[float, dict[str, float]]:
    """A ``bench.process_cpu --threads`` report's wall seconds (the whole command's) and the
    edges' CPU seconds by thread label (``python -m edge_mapper.node · LABEL`` lines)."""
    wall, cpu = math.nan, {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if " s wall;" in line:
            wall = float(line.split(" s wall;")[0].rsplit(" ", 1)[-1])
        elif "edge_mapper.node · " in line:
            seconds = float(line.split()[0])
            label = line.split("edge_mapper.node · ", 1)[1].strip()
            cpu[label] = cpu.get(label, 0.0) + seconds
    return wall, cpu


def two_hosts() -> None:
    """Fifty devices, half of them in pairs sharing a place: on one 2-core host, and each
    half on a 2-core host of its own (what two edge hosts carry): each setting's late share
    and summaries → map p95, a point a run, and the edges' cores over the run (the bench's
    ``edge_cpu_share``) split by thread as ``bench.process_cpu --threads`` counted their CPU
    (mean of the runs)."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6), sharey=True)
    folder = HERE / "fleet/two-hosts"
    for y, (stem, _) in enumerate(TWO_HOSTS_SETTINGS):
        runs = sorted(folder.glob(f"{stem}-[0-9].csv"))
        rows = [_rows(path)[0] for path in runs]
        colour = "C3" if stem.startswith("one-host") else "C0"
        axes[0].plot([100 * float(r["missed_share"]) for r in rows], [y] * len(rows), "o",
                     color=colour)
        axes[1].plot([float(r["latency_ms_p95"]) / 1000 for r in rows], [y] * len(rows), "o",
                     color=colour)
        # the edges' cores over the run (the bench's window), split as their threads' CPU
        # over the whole command splits it
        split = [process_threads(path.with_suffix(".txt"))[1] for path in runs]
        left = 0.0
        for k, (label, name) in enumerate((*EDGE_THREADS, (None, "other threads"))):
            cores = statistics.fmean(
                float(r["edge_cpu_share"]) * (
                    cpu.get(label, 0.0) if label is not None else
                    sum(v for t, v in cpu.items() if t not in dict(EDGE_THREADS)))
                / max(sum(cpu.values()), 1e-9)
                for r, cpu in zip(rows, split, strict=True)) if rows else 0.0
            axes[2].barh(y, cores, left=left, color=f"C{k}", label=name if y == 0 else None)
            left += cores
    _goal_axes(axes, [label for _, label in TWO_HOSTS_SETTINGS])
    axes[2].axvline(2, color="grey", lw=1)
    axes[2].set(xlabel="cores over the run", title="the edges' CPU by thread")
    axes[2].legend(fontsize=8, loc="lower right")
    _save(fig, "fleet/fifty-on-two-hosts.png")


def one_core() -> None:
    """One edge process held to a core of its own, the emulated devices to the other: the
    late share and the summaries → map p95 vs the devices it serves, alone in their places
    and half of them sharing one, a line a round."""
    folder = HERE / "fleet/one-core"
    _late_and_p95_by_run(
        [("C0", sorted(folder.glob("alone-*.csv")), "each device alone in its place"),
         ("C3", sorted(folder.glob("half-sharing-*.csv")),
          "half of them in pairs sharing a place")],
        "late maps: an edge process on one core of its own", "fleet/one-core.png", "rounds")


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("scaling", "edges", "hosts", "stagger", "revisit", "sim",
                                   "split", "live", "emulator", "curve", "fifty",
                                   "two-hosts", "one-core"):
        print(__doc__)
        return 2
    {"scaling": lambda a: scaling(), "edges": lambda a: edges(), "hosts": lambda a: hosts(),
     "stagger": lambda a: stagger(), "revisit": lambda a: revisit(), "sim": sim,
     "split": split, "live": live, "curve": lambda a: curve(), "fifty": lambda a: fifty(),
     "two-hosts": lambda a: two_hosts(), "one-core": lambda a: one_core(),
     "emulator": lambda a: print("\n".join(emulator_table([Path(p) for p in a])))
     }[argv[0]](argv[1:])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
