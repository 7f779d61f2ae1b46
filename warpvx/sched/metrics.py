"""Schedule metrics (thesis §5.2-5.3, eq. 2-5; Topcuoglu et al. 2002 §5.1).

Overlaps are sums over *unordered pairs of distinct tasks* (eq. 4-5 read as sums over pairs:
a pair counts once, a task never overlaps itself). Both are computed by a sweep over start and
finish times: with k(t) tasks running at time t, O(A) = integral of k(k-1)/2, and with x_K(t)
tasks exclusive to kind K running, XO(A) = integral of the sum over kind pairs of x_I * x_J.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import networkx as nx

from ..errors import WarpvxTypeError
from .dag import Problem, prepare
from .schedule import Schedule


@dataclass(frozen=True)
class IdleTime:
    """Idle time of a schedule within [0, makespan].

    Attributes
    ----------
    per_processor : dict
        processor -> makespan minus the time it is busy.
    total : float
        Sum over processors.
    fraction : float
        ``total / (number of processors * makespan)`` (0 for an empty makespan); the thesis'
        "Idle time (%)" of Table 5.1.
    """

    per_processor: dict
    total: float
    fraction: float


def _check(schedule):
    if not isinstance(schedule, Schedule):
        raise WarpvxTypeError(f"schedule: expected a Schedule, got {type(schedule).__name__}")


def makespan(schedule: Schedule) -> float:
    """Finish time of the last task (schedules start at time 0)."""
    _check(schedule)
    return schedule.makespan


def _min_critical_path(problem: Problem) -> float:
    longest = [0.0] * len(problem.names)
    for v in reversed(problem.topo):
        tail = max((longest[q] for q, _ in problem.succs[v]), default=0.0)
        longest[v] = min(problem.cost[v][k] for k in problem.can[v]) + tail
    return max(longest)


def min_critical_path(dag: nx.DiGraph) -> float:
    """Length of the critical path with each task at its minimum cost and no communication.

    A lower bound of every schedule's makespan; the denominator of the SLR.
    """
    return _min_critical_path(prepare(dag))


def slr(dag: nx.DiGraph, schedule: Schedule) -> float:
    """Schedule length ratio: makespan over :func:`min_critical_path` (>= 1; NaN if that is 0).

    Topcuoglu et al. 2002 eq. 11: the denominator sums the minimum costs of the tasks on the
    critical path of the DAG weighted by minimum costs.
    """
    _check(schedule)
    cp = min_critical_path(dag)
    return schedule.makespan / cp if cp > 0 else math.nan


def _serial_time(problem: Problem) -> float:
    P = len(problem.procs)
    whole = [sum(row[k] for row in problem.cost) for k in range(P)]
    finite = [t for t in whole if math.isfinite(t)]
    if finite:
        return min(finite)
    return sum(min(row[k] for k in runs) for row, runs in zip(problem.cost, problem.can))


def serial_time(dag: nx.DiGraph) -> float:
    """Best serial execution time, the numerator of :func:`speedup`.

    The smallest sum of costs over the processors that can run every task (Topcuoglu et al.
    2002 §5.1). When no single processor can run every task (a CPU/GPU DAG with exclusive
    tasks of both kinds), the serial time is the sum over tasks of each task's minimum cost: the
    tasks run one at a time, each on its fastest processor, without communication.
    """
    return _serial_time(prepare(dag))


def speedup(dag: nx.DiGraph, schedule: Schedule) -> float:
    """:func:`serial_time` over the makespan (NaN for a zero makespan)."""
    _check(schedule)
    span = schedule.makespan
    return _serial_time(prepare(dag)) / span if span > 0 else math.nan


def _sweep(intervals) -> float:
    """Integral over time of sum_{I<J} x_I x_J, intervals given as (start, finish, group)."""
    events = []
    for s, f, g in intervals:
        if f > s:
            events.append((s, 1, g))
            events.append((f, -1, g))
    events.sort(key=lambda e: (e[0], e[1]))
    counts = {}
    total = sq = 0
    area = 0.0
    prev = 0.0
    for t, d, g in events:
        if total > 1:
            area += (total * total - sq) * 0.5 * (t - prev)
        prev = t
        c = counts.get(g, 0)
        sq += 2 * c * d + 1  # (c + d)^2 - c^2 with d = +-1
        counts[g] = c + d
        total += d
    return area


def overlap(schedule: Schedule) -> float:
    """O(A): sum over pairs of tasks of the length of time both run (thesis eq. 2, 4)."""
    _check(schedule)
    # Each task its own group: sum_{I<J} x_I x_J is then the number of running pairs.
    return _sweep((t.start, t.finish, i) for i, t in enumerate(schedule.tasks.values()))


def _exclusive_overlap(problem: Problem, schedule: Schedule) -> float:
    index = {v: i for i, v in enumerate(problem.names)}
    excl = problem.excl
    return _sweep(
        (t.start, t.finish, excl[index[v]])
        for v, t in schedule.tasks.items()
        if excl[index[v]] >= 0
    )


def exclusive_overlap(dag: nx.DiGraph, schedule: Schedule) -> float:
    """XO(A): overlap summed over pairs of tasks exclusive to different kinds (thesis eq. 3, 5).

    With CPUs and a GPU: pairs of one CPU-only and one GPU-only task.
    """
    _check(schedule)
    return _exclusive_overlap(prepare(dag), schedule)


def _max_exclusive_overlap(problem: Problem) -> float:
    nk = len(problem.kinds)
    load = [0.0] * nk
    for row, runs, e in zip(problem.cost, problem.can, problem.excl):
        if e >= 0:
            load[e] += max(row[k] for k in runs)
    size = problem.kind_size
    return sum(
        min(size[j] * load[i], size[i] * load[j]) for i in range(nk) for j in range(i + 1, nk)
    )


def max_exclusive_overlap(dag: nx.DiGraph) -> float:
    """Upper bound of XO(A) over all schedules (thesis Table 5.1, "Max XO").

    For kinds I and J with n_I, n_J processors and T_I, T_J the summed (largest) costs of the
    tasks exclusive to them: sum over kind pairs of min(n_J * T_I, n_I * T_J), since at most
    n_J tasks of J run beside each task of I. With n CPUs and one GPU this is
    ``min(n * T_gpu_only, T_cpu_only)``, which reproduces Table 5.1's Max XO column (e.g. 30.0
    for a 15 ms GPU-only node and 2 CPUs). Precedence is ignored, so it may be unreachable.
    """
    return _max_exclusive_overlap(prepare(dag))


def xo_efficiency(dag: nx.DiGraph, schedule: Schedule) -> float:
    """XO(A) / max XO (thesis Table 5.1 "XO/Max_XO"); NaN when no exclusive overlap is possible."""
    _check(schedule)
    problem = prepare(dag)
    mx = _max_exclusive_overlap(problem)
    return _exclusive_overlap(problem, schedule) / mx if mx > 0 else math.nan


def idle_time(schedule: Schedule) -> IdleTime:
    """Idle time per processor and in total, within [0, makespan] (see :class:`IdleTime`)."""
    _check(schedule)
    span = schedule.makespan
    busy = {p: 0.0 for p in schedule.processors}
    for t in schedule.tasks.values():
        busy[t.processor] = busy.get(t.processor, 0.0) + (t.finish - t.start)
    per = {p: max(0.0, span - b) for p, b in busy.items()}
    total = sum(per.values())
    frac = total / (len(per) * span) if span > 0 and per else 0.0
    return IdleTime(per, total, frac)


def metrics(dag: nx.DiGraph, schedule: Schedule) -> dict:
    """Every metric of one schedule.

    Returns
    -------
    dict
        ``makespan``, ``slr``, ``speedup``, ``serial_time``, ``min_critical_path``,
        ``overlap`` (O(A)), ``exclusive_overlap`` (XO(A)), ``max_exclusive_overlap``,
        ``xo_efficiency``, ``idle_time`` (total), ``idle_fraction``, ``idle_per_processor``
        (dict).
    """
    _check(schedule)
    problem = prepare(dag)
    span = schedule.makespan
    cp = _min_critical_path(problem)
    serial = _serial_time(problem)
    xo = _exclusive_overlap(problem, schedule)
    mx = _max_exclusive_overlap(problem)
    idle = idle_time(schedule)
    return {
        "makespan": span,
        "slr": span / cp if cp > 0 else math.nan,
        "speedup": serial / span if span > 0 else math.nan,
        "serial_time": serial,
        "min_critical_path": cp,
        "overlap": overlap(schedule),
        "exclusive_overlap": xo,
        "max_exclusive_overlap": mx,
        "xo_efficiency": xo / mx if mx > 0 else math.nan,
        "idle_time": idle.total,
        "idle_fraction": idle.fraction,
        "idle_per_processor": idle.per_processor,
    }
