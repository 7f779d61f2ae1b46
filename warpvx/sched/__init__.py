"""DAG scheduling: baseline, HEFT, XEFT and best-of policies, metrics, generator.

Task graphs are :class:`networkx.DiGraph` objects (model in :mod:`warpvx.sched.dag`); policies
are plain functions ``policy(dag) -> Schedule``. The Gantt chart and the synthetic study live in
:mod:`warpvx.sched.gantt` and :mod:`warpvx.sched.study` (matplotlib is imported only there).
This package is pure algorithms (networkx in, :class:`Schedule` out) and never imports Warp;
running a schedule for real is :mod:`warpvx.runtime`. Frames in flight: :func:`unroll` a DAG
over K frames (or ``schedule(dag, policy, frames=K)``); every policy orders it frame-major.
"""

from .dag import cpu_gpu_dag, exclusive_kind, processor_kinds
from .frames import FrameTimes, frame_times, unroll
from .generator import random_dag
from .metrics import (
    IdleTime,
    exclusive_overlap,
    idle_time,
    makespan,
    max_exclusive_overlap,
    metrics,
    min_critical_path,
    overlap,
    serial_time,
    slr,
    speedup,
    xo_efficiency,
)
from .policies import POLICIES, baseline, best, heft, schedule, upward_rank, xeft, xeft_order
from .schedule import Schedule, ScheduledTask
from .validate import validate_schedule


def plot_gantt(schedule, ax=None, dag=None, title=None):
    """Draw a Gantt chart; see :func:`warpvx.sched.gantt.plot_gantt` (needs matplotlib)."""
    from .gantt import plot_gantt as _plot

    return _plot(schedule, ax=ax, dag=dag, title=title)


def save_gantt(schedule, path, dag=None, title=None):
    """Write a Gantt chart image; see :func:`warpvx.sched.gantt.save_gantt` (needs matplotlib)."""
    from .gantt import save_gantt as _save

    return _save(schedule, path, dag=dag, title=title)


__all__ = [
    "Schedule",
    "ScheduledTask",
    "cpu_gpu_dag",
    "processor_kinds",
    "exclusive_kind",
    "random_dag",
    "unroll",
    "frame_times",
    "FrameTimes",
    "upward_rank",
    "xeft_order",
    "baseline",
    "heft",
    "xeft",
    "best",
    "POLICIES",
    "schedule",
    "validate_schedule",
    "makespan",
    "min_critical_path",
    "slr",
    "serial_time",
    "speedup",
    "overlap",
    "exclusive_overlap",
    "max_exclusive_overlap",
    "idle_time",
    "IdleTime",
    "xo_efficiency",
    "metrics",
    "plot_gantt",
    "save_gantt",
]
