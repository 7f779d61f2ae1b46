"""Frames in flight: a task DAG unrolled over K frames, and a frame's latency and period.

:func:`unroll` makes K copies of a one-frame DAG, task ``v`` of frame ``f`` named ``(v, f)``
with node attribute ``frame = f``, and adds the inter-frame edges that delays imply: a delay
``(u, v)`` feeds ``u``'s output of frame f to ``v`` of frame f+1 (an OpenVX ``vx_delay`` aged
once per frame). Every policy schedules a DAG with frames frame-major (see
:mod:`warpvx.sched.dag`), so frame f is never held up by frame f+1 while frames overlap on
the processors. :func:`frame_times` reads a frame's latency and the steady-state period
(one over the throughput) off the schedule.
"""

from __future__ import annotations

from dataclasses import dataclass

import networkx as nx

from ..check import check_int
from ..errors import ScheduleError
from .dag import _edge_triples, _time, prepare
from .metrics import _check
from .schedule import Schedule


def unroll(dag: nx.DiGraph, frames: int, delays=()) -> nx.DiGraph:
    """Copy a one-frame task DAG ``frames`` times, with the inter-frame edges of ``delays``.

    Parameters
    ----------
    dag : networkx.DiGraph
        A one-frame task DAG (:mod:`warpvx.sched.dag`), without ``frame`` attributes.
    frames : int
        Number of frames K >= 1.
    delays : dict or iterable
        ``{(u, v): transfer}`` or ``(u, v[, transfer])`` items: ``v`` of frame f+1 needs ``u``
        of frame f (``transfer`` as an edge's ``comm``, default 0).

    Returns
    -------
    networkx.DiGraph
        Tasks ``(v, f)`` for f in 0..K-1 with the attributes of ``v`` plus ``frame = f``, the
        DAG's edges inside each frame, the delay edges between consecutive frames, and the
        graph attributes of ``dag`` plus ``frames = K``.

    Raises
    ------
    ScheduleError
        A bad DAG (see :func:`warpvx.sched.dag.prepare`), one that already has frames, a delay
        naming an unknown task or with a bad transfer.
    WarpvxValueError
        ``frames`` < 1.
    """
    frames = check_int(frames, "frames", min_value=1)
    problem = prepare(dag)
    if problem.frame is not None:
        raise ScheduleError("dag: already unrolled (its tasks have a 'frame' attribute)")
    links = []
    for u, v, transfer in _edge_triples(delays):
        for end in (u, v):
            if end not in dag:
                raise ScheduleError(f"delays: ({u!r}, {v!r}) names unknown task {end!r}")
        links.append((u, v, _time(transfer, f"delays[({u!r}, {v!r})] transfer")))
    out = nx.DiGraph(**dag.graph)
    out.graph["frames"] = frames
    for f in range(frames):
        for v, data in dag.nodes(data=True):
            out.add_node((v, f), **data, frame=f)
        for u, v, data in dag.edges(data=True):
            out.add_edge((u, f), (v, f), **data)
        if f:
            for u, v, c in links:
                out.add_edge((u, f - 1), (v, f), comm=c)
    prepare(out)  # the delay transfers add to the total: keep every time finite
    return out


@dataclass(frozen=True)
class FrameTimes:
    """Per-frame timing of a schedule of a DAG with frames (times in the DAG's unit).

    Attributes
    ----------
    start, finish : list of float
        frame -> first start and last finish of its tasks.
    latency : list of float
        frame -> ``finish - start``: how long a frame is in flight.
    period : float
        Steady-state time between frames, ``(finish[K-1] - finish[0]) / (K - 1)``: one over
        the throughput; the makespan when K == 1.
    """

    start: list
    finish: list
    latency: list
    period: float


def frame_times(dag: nx.DiGraph, schedule: Schedule) -> FrameTimes:
    """A frame's latency and the steady-state period of ``schedule`` (see :class:`FrameTimes`).

    A DAG without ``frame`` attributes is one frame.

    Raises
    ------
    ScheduleError
        A bad DAG, or a task of it missing from the schedule.
    WarpvxTypeError
        ``schedule`` is not a :class:`Schedule`.
    """
    _check(schedule)
    problem = prepare(dag)
    frame = problem.frame or [0] * len(problem.names)
    k = max(frame) + 1
    start = [float("inf")] * k
    finish = [0.0] * k
    for v, f in zip(problem.names, frame):
        t = schedule.tasks.get(v)
        if t is None:
            raise ScheduleError(f"schedule: task {v!r} of the dag is not scheduled")
        start[f] = min(start[f], t.start)
        finish[f] = max(finish[f], t.finish)
    start = [s if s != float("inf") else 0.0 for s in start]  # a frame number with no task
    latency = [f - s for s, f in zip(start, finish)]
    period = (finish[-1] - finish[0]) / (k - 1) if k > 1 else finish[0]
    return FrameTimes(start, finish, latency, period)
