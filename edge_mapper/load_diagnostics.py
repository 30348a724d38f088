"""The edge's load as a ROS 2 diagnostics status (``diagnostic_msgs/DiagnosticArray`` on
``/diagnostics``): the first thing a user of an edge serving many devices asks — is it keeping
up, and what takes its cores? — answered where ROS tools look (``ros2 topic echo
/diagnostics``, ``rqt_runtime_monitor``, Foxglove's diagnostics panel), not only in its log.

A status a period (``diagnostics_period_s``): the devices served, the slots answered in the
period and their summaries → map latency (median and the longest), the slot work's share of a
core against ``compute_budget`` and the budget's level, and each named thread's share of a core
(the slot thread as ``main``; ``loop-closer_0``, ``place-words``, ``checkpoints``:
:mod:`twinslam.thread_names`; those under LISTED_SHARE summed), and the loop worker's queue:
the loop work and the place looks waiting on it, and the looks that waited past their bound
behind the loops in the period. WARN while the budget has trimmed the edge's work, while a
slot's map came later than the slot period itself (the device then tracks on an older map),
or while looks waited past their bound (the loops keep the worker busy: devices merge late);
OK otherwise. Pure: the node gathers the figures and
publishes what this returns.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from msg_schemas.headers import set_header
from twinslam.node_runtime.thread_cpu import MAIN

#: a thread is listed by name from this share of a core on (the slot thread always); the
#: others — Fast DDS's dozen mostly idle ones, named by port — are summed into one value
LISTED_SHARE = 0.01


@dataclass(frozen=True)
class EdgeLoad:
    """What an edge did over one diagnostics period."""

    devices: int                           #: devices it serves now
    #: each slot answered in the period: (summaries → map latency, the device's slot period),
    #: in seconds
    answered: Sequence[tuple[float, float]]
    load: float                            #: slot work, a share of one core (governor window)
    budget: float                          #: compute_budget (0: none)
    level: str                             #: what the budget's level does, in words
    trimmed: bool                          #: the level is below the edge's full work
    threads: Mapping[str, float] = field(default_factory=dict)  #: name → share of a core
    #: the loop worker's queue now: (loop work, place looks and filing) not started
    worker_waiting: tuple[int, int] = (0, 0)
    #: place looks that waited past their bound behind the loops in the period
    looks_overdue: int = 0


def load_status(node_name: str, host: str, load: EdgeLoad, stamp: float) -> DiagnosticArray:
    """The edge's load over a period as one status named ``"<node_name>: load"`` (each edge
    process of a fleet has its own), from host ``host``."""
    latencies = [latency for latency, _ in load.answered]
    late = sum(1 for latency, period in load.answered if latency > period)
    warn = []
    if load.trimmed:
        warn.append(f"over its compute budget: {load.level}")
    if late:
        warn.append(f"{late} of {len(load.answered)} maps later than their slot")
    if load.looks_overdue:
        warn.append(f"{load.looks_overdue} place look{'' if load.looks_overdue == 1 else 's'} "
                    "waited past their bound behind the loop jobs")
    budget = f" of a budget of {load.budget:.0%}" if load.budget > 0 else ""
    summary = (f"{load.devices} device{'' if load.devices == 1 else 's'}, "
               f"{len(load.answered)} slots answered, slot work "
               f"{load.load:.0%} of a core{budget}")
    status = DiagnosticStatus(
        level=DiagnosticStatus.WARN if warn else DiagnosticStatus.OK,
        name=f"{node_name}: load", hardware_id=host,
        message="; ".join([summary, *warn]))
    values = [("devices", str(load.devices)), ("slots_answered", str(len(load.answered))),
              ("slots_late", str(late)),
              ("latency_ms_median",
               f"{1000 * float(np.median(latencies)):.0f}" if latencies else ""),
              ("latency_ms_max", f"{1000 * max(latencies):.0f}" if latencies else ""),
              ("slot_work_cores", f"{load.load:.3f}"), ("compute_budget", f"{load.budget:g}"),
              ("budget_level", load.level),
              ("loop_work_waiting", str(load.worker_waiting[0])),
              ("looks_waiting", str(load.worker_waiting[1])),
              ("looks_overdue", str(load.looks_overdue))]
    listed = {name: share for name, share in load.threads.items()
              if share >= LISTED_SHARE or name == MAIN}
    values += [(f"cores {name}", f"{share:.3f}")
               for name, share in sorted(listed.items(), key=lambda kv: -kv[1])]
    if len(listed) < len(load.threads):
        rest = sum(share for name, share in load.threads.items() if name not in listed)
        values.append(("cores other threads", f"{rest:.3f}"))
    status.values = [KeyValue(key=key, value=value) for key, value in values]
    return set_header(DiagnosticArray(status=[status]), stamp, "")
