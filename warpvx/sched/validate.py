"""Check that a schedule is feasible for its task DAG."""

from __future__ import annotations

import math

import networkx as nx

from ..errors import ScheduleError, WarpvxTypeError
from .dag import prepare
from .schedule import Schedule


def validate_schedule(dag: nx.DiGraph, schedule: Schedule) -> None:
    """Raise :class:`ScheduleError` unless ``schedule`` is a feasible schedule of ``dag``.

    Checks, with a tolerance of 1e-9 times max(1, makespan) for float round-off:

    - every task of ``dag`` is scheduled once, and nothing else is;
    - each task runs on a processor of ``dag.graph["processors"]`` that is in its cost dict,
      starts at a finite time >= 0, and ``finish - start`` equals its cost there;
    - no two tasks overlap on one processor;
    - precedence with communication: a task starts no earlier than each predecessor's finish,
      plus the edge's ``comm`` when the two processors do not share memory (different memory
      spaces with a ``memory`` attribute, different processors without).

    Parameters
    ----------
    dag : networkx.DiGraph
        The task DAG (:mod:`warpvx.sched.dag`).
    schedule : Schedule

    Raises
    ------
    ScheduleError
        The first violation found, naming the task(s) and processor.
    WarpvxTypeError
        ``schedule`` is not a :class:`Schedule`.
    """
    if not isinstance(schedule, Schedule):
        raise WarpvxTypeError(f"schedule: expected a Schedule, got {type(schedule).__name__}")
    problem = prepare(dag)
    pindex = {p: k for k, p in enumerate(problem.procs)}
    tasks = schedule.tasks
    index = {v: i for i, v in enumerate(problem.names)}
    missing = [v for v in problem.names if v not in tasks]
    if missing:
        raise ScheduleError(
            f"schedule: task {missing[0]!r} of the dag is not scheduled ({len(missing)} missing)"
        )
    extra = [v for v in tasks if v not in index]
    if extra:
        raise ScheduleError(f"schedule: task {extra[0]!r} is not in the dag")
    span = max((t.finish for t in tasks.values()), default=0.0)
    tol = 1e-9 * max(1.0, abs(span) if math.isfinite(span) else 1.0)
    n = len(problem.names)
    proc = [0] * n
    start = [0.0] * n
    finish = [0.0] * n
    for v, i in index.items():
        st = tasks[v]
        if st.task != v:
            raise ScheduleError(f"schedule: entry for task {v!r} describes task {st.task!r}")
        k = pindex.get(st.processor)
        if k is None:
            raise ScheduleError(
                f"schedule: task {v!r} is on unknown processor {st.processor!r} "
                f"(processors: {problem.procs})"
            )
        c = problem.cost[i][k]
        if not math.isfinite(c):
            raise ScheduleError(f"schedule: task {v!r} is on {st.processor!r}, which cannot run it")
        if not (math.isfinite(st.start) and math.isfinite(st.finish)):
            raise ScheduleError(f"schedule: task {v!r} has non-finite times {st.start}..{st.finish}")
        if st.start < -tol:
            raise ScheduleError(f"schedule: task {v!r} starts at {st.start} < 0")
        if abs((st.finish - st.start) - c) > tol * max(1.0, c):
            raise ScheduleError(
                f"schedule: task {v!r} on {st.processor!r} runs {st.finish - st.start} "
                f"({st.start}..{st.finish}), but its cost there is {c}"
            )
        proc[i], start[i], finish[i] = k, st.start, st.finish
    for k, name in enumerate(problem.procs):
        on = sorted((start[i], finish[i], i) for i in range(n) if proc[i] == k)
        for (s0, f0, i0), (s1, f1, i1) in zip(on, on[1:]):
            if s1 < f0 - tol:
                raise ScheduleError(
                    f"schedule: tasks {problem.names[i0]!r} ({s0}..{f0}) and {problem.names[i1]!r} "
                    f"({s1}..{f1}) overlap on {name!r}"
                )
    space, names, procs = problem.space, problem.names, problem.procs
    for v in range(n):
        for u, c in problem.preds[v]:
            delay = 0.0 if space[proc[u]] == space[proc[v]] else c
            if start[v] < finish[u] + delay - tol:
                raise ScheduleError(
                    f"schedule: task {names[v]!r} on {procs[proc[v]]!r} starts at {start[v]}, "
                    f"before its input from {names[u]!r} on {procs[proc[u]]!r} is ready at "
                    f"{finish[u] + delay} (finish {finish[u]} + transfer {delay})"
                )
