"""The task-DAG model every policy and metric reads, its validation, and a CPU/GPU builder.

A task graph is a :class:`networkx.DiGraph`:

- node attribute ``cost``: ``{processor: time}``; a processor absent from the dict cannot run
  the task. Times are finite and >= 0.
- edge attribute ``comm``: time to move the edge's data between two processors that do not
  share memory (missing means 0).
- graph attribute ``processors``: list of processor names, e.g. ``["cpu0", "cpu1", "gpu"]``.
- optional graph attribute ``memory``: ``{processor: memory space}``, e.g. every ``"cpuN"`` ->
  ``"host"``, ``"gpu"`` -> ``"device"``. Communication is paid only between processors in
  different memory spaces; without ``memory`` it is paid between any two different processors
  (the model of Topcuoglu et al. 2002).
- optional node attribute ``frame``: an int >= 0, the frame a task belongs to in a DAG
  unrolled over several frames (:func:`warpvx.sched.frames.unroll`). When one task has it,
  every task must, and no edge may go from a later frame to an earlier one; every policy then
  schedules frame-major (frame f's tasks before frame f+1's in the priority list).

All costs and transfers of one DAG must sum to at most :data:`MAX_TOTAL_TIME` (1e300): every
rank, start and finish time, makespan and metric (overlaps included) is then a finite float.

*Kind* of a processor: its memory space when ``memory`` is given, else its name without trailing
digits (``"cpu3"`` -> ``"cpu"``, ``"gpu"`` -> ``"gpu"``). A task is *exclusive* (thesis §5.1)
when every processor that can run it is of one kind while the system has more than one kind:
with :func:`cpu_gpu_dag`, CPU-only tasks are exclusive to ``"host"``, GPU-only tasks to
``"device"``.
"""

from __future__ import annotations

import heapq
import math
import numbers
import re
from collections.abc import Iterable, Mapping, Sequence

import networkx as nx

from ..check import check_int
from ..errors import ScheduleError, WarpvxTypeError

HOST = "host"
DEVICE = "device"
GPU = "gpu"

#: Largest sum of every task's largest cost and every edge's transfer that a DAG may have. No
#: schedule is longer than that sum, and the overlap metrics are at most (tasks - 1) / 2 times
#: it, so the headroom up to the largest float (1.8e308) keeps every result finite.
MAX_TOTAL_TIME = 1e300


def cpu_gpu_dag(tasks: Mapping, edges=(), n_cpus: int = 1) -> nx.DiGraph:
    """Build a task DAG for ``n_cpus`` CPU workers and one GPU.

    Parameters
    ----------
    tasks : dict
        task name -> ``(cpu_time, gpu_time)``; ``None`` for a missing implementation (an
        exclusive task). Times in any unit (ms in warpvx), finite and >= 0.
    edges : dict or iterable
        ``{(u, v): transfer}`` or an iterable of ``(u, v, transfer)`` (or ``(u, v)`` for 0):
        ``transfer`` is the time to move ``u``'s output between host and device memory.
    n_cpus : int
        Number of CPU workers (>= 1), named ``cpu0`` ... ``cpu{n-1}``; the GPU is ``gpu``.

    Returns
    -------
    networkx.DiGraph
        With node ``cost``, edge ``comm`` and graph ``processors`` and ``memory`` (CPUs in
        ``"host"``, the GPU in ``"device"``).

    Raises
    ------
    ScheduleError
        A task that is not a ``(cpu_time, gpu_time)`` pair or has neither implementation, a
        negative/NaN/inf time, an edge that is not ``(u, v)`` or ``(u, v, transfer)``, an edge
        to an unknown task, a cycle, times summing over :data:`MAX_TOTAL_TIME`.
    WarpvxTypeError
        ``tasks`` is not a dict, ``edges`` neither a dict nor an iterable.
    """
    n_cpus = check_int(n_cpus, "n_cpus", min_value=1)
    cpus = [f"cpu{i}" for i in range(n_cpus)]
    if not isinstance(tasks, Mapping):
        raise WarpvxTypeError(
            f"tasks: expected a dict name -> (cpu_time, gpu_time), got {type(tasks).__name__}"
        )
    dag = nx.DiGraph()
    dag.graph["processors"] = cpus + [GPU]
    dag.graph["memory"] = {**{c: HOST for c in cpus}, GPU: DEVICE}
    for name, times in tasks.items():
        try:
            cpu_t, gpu_t = times
        except (TypeError, ValueError):
            raise ScheduleError(
                f"tasks[{name!r}]: expected (cpu_time or None, gpu_time or None), got {times!r}"
            ) from None
        if cpu_t is None and gpu_t is None:
            raise ScheduleError(f"tasks[{name!r}]: no processor can run it (both times are None)")
        cost = {}
        if cpu_t is not None:
            t = _time(cpu_t, f"tasks[{name!r}] cpu_time")
            cost.update((c, t) for c in cpus)
        if gpu_t is not None:
            cost[GPU] = _time(gpu_t, f"tasks[{name!r}] gpu_time")
        dag.add_node(name, cost=cost)
    total = sum(max(cost.values()) for _, cost in dag.nodes(data="cost"))
    for u, v, transfer in _edge_triples(edges):
        for end in (u, v):
            if end not in dag:
                raise ScheduleError(f"edges: edge ({u!r}, {v!r}) names unknown task {end!r}")
        comm = _time(transfer, f"edges[({u!r}, {v!r})] transfer")
        total += comm
        dag.add_edge(u, v, comm=comm)
    _check_total(total, "tasks and edges")
    if not nx.is_directed_acyclic_graph(dag):
        raise ScheduleError(f"edges: the graph has a cycle: {_cycle_text(dag)}")
    return dag


def _edge_triples(edges):
    """``edges`` of :func:`cpu_gpu_dag` as ``(u, v, transfer)`` triples, shapes checked."""
    if isinstance(edges, Mapping):
        for key, transfer in edges.items():
            if not (isinstance(key, tuple) and len(key) == 2):
                raise ScheduleError(f"edges: key {key!r}; expected a (u, v) pair of task names")
            yield (*key, transfer)
        return
    if isinstance(edges, (str, bytes)) or not isinstance(edges, Iterable):
        raise WarpvxTypeError(
            f"edges: expected a dict {{(u, v): transfer}} or an iterable of (u, v[, transfer]), "
            f"got {type(edges).__name__}"
        )
    for i, item in enumerate(edges):
        if isinstance(item, (str, bytes)) or not (isinstance(item, Sequence) and len(item) in (2, 3)):
            raise ScheduleError(f"edges[{i}]: expected (u, v) or (u, v, transfer), got {item!r}")
        yield (*item, 0.0) if len(item) == 2 else tuple(item)


def _check_total(total: float, name: str) -> None:
    if not total <= MAX_TOTAL_TIME:
        raise ScheduleError(
            f"{name}: the costs and transfers sum to {total:.3g}, over the limit "
            f"{MAX_TOTAL_TIME:.0e} that keeps schedules and metrics finite; use a larger time unit"
        )


def processor_kinds(dag: nx.DiGraph) -> dict:
    """processor -> kind: its memory space with ``memory``, else its name without trailing digits."""
    procs = _processors(dag)
    memory = dag.graph.get("memory")
    if memory is not None:
        return {p: memory[p] for p in procs}
    return {p: _name_kind(p) for p in procs}


def exclusive_kind(dag: nx.DiGraph, task):
    """The kind a task is exclusive to, or ``None`` when it can run on several kinds."""
    kinds = processor_kinds(dag)
    if len(set(kinds.values())) < 2:
        return None
    own = {kinds[p] for p in dag.nodes[task]["cost"]}
    return next(iter(own)) if len(own) == 1 else None


def _name_kind(name: str) -> str:
    stripped = re.sub(r"\d+$", "", name)
    return stripped or name


def _time(v, name: str) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise ScheduleError(f"{name}: expected a number, got {type(v).__name__} {v!r}")
    v = float(v)
    if not math.isfinite(v) or v < 0:
        raise ScheduleError(f"{name}: expected a finite time >= 0, got {v}")
    return v


def _cycle_text(dag) -> str:
    cyc = nx.find_cycle(dag)
    return " -> ".join(repr(u) for u, _ in cyc) + f" -> {cyc[0][0]!r}"


def _processors(dag) -> list:
    if not isinstance(dag, nx.DiGraph) or dag.is_multigraph():
        raise WarpvxTypeError(f"dag: expected a networkx.DiGraph, got {type(dag).__name__}")
    procs = dag.graph.get("processors")
    if procs is None:
        raise ScheduleError(
            "dag: graph attribute 'processors' is missing; expected a list of processor names "
            "(e.g. dag.graph['processors'] = ['cpu0', 'cpu1', 'gpu'])"
        )
    if isinstance(procs, str) or not isinstance(procs, Iterable):
        raise ScheduleError(f"dag: graph attribute 'processors' must be a list of names, got {procs!r}")
    procs = list(procs)
    if not procs:
        raise ScheduleError("dag: graph attribute 'processors' is empty; expected at least one processor")
    if not all(isinstance(p, str) for p in procs) or len(set(procs)) != len(procs):
        raise ScheduleError(f"dag: 'processors' must be distinct strings, got {procs!r}")
    memory = dag.graph.get("memory")
    if memory is not None:
        if not isinstance(memory, Mapping):
            raise ScheduleError(
                f"dag: graph attribute 'memory' must be a dict processor -> space, got {memory!r}"
            )
        missing = [p for p in procs if p not in memory]
        if missing:
            raise ScheduleError(f"dag: graph attribute 'memory' has no memory space for {missing!r}")
    return procs


class Problem:
    """A validated task DAG as flat Python lists indexed by task and processor number.

    The policies' inner loops run on these lists, not on networkx views (HEFT+XEFT on a
    250-node DAG must take milliseconds). Build it with :func:`prepare`.

    Attributes
    ----------
    names : list
        task index -> node of the DAG.
    procs : list of str
        processor index -> name.
    cost : list of list of float
        ``cost[i][k]``: time of task ``i`` on processor ``k`` (``inf`` when it cannot run there).
    can : list of tuple of int
        Processors that can run each task, in ``procs`` order.
    preds, succs : list of list of (int, float)
        Neighbours with the edge's ``comm``.
    topo : list of int
        The topological order that follows node insertion order where precedence allows.
    space : list of int
        processor -> memory-space id; without a ``memory`` attribute each processor is its own
        space, so communication is paid between any two different processors.
    kind : list of int
        processor -> kind id (see the module docstring); ``kinds`` names them, ``kind_size``
        counts their processors.
    excl : list of int
        task -> the kind it is exclusive to, or -1.
    memory_model : bool
        Whether the graph gave ``memory``.
    frame : list of int or None
        task -> its ``frame`` attribute; ``None`` when the DAG has no frames.
    """

    __slots__ = (
        "names", "procs", "cost", "can", "preds", "succs", "topo", "space", "kind", "kinds",
        "kind_size", "excl", "memory_model", "n_spaces", "frame",
    )


def prepare(dag: nx.DiGraph) -> Problem:
    """Validate ``dag`` and flatten it into a :class:`Problem`.

    Raises
    ------
    WarpvxTypeError
        ``dag`` is not a networkx DiGraph.
    ScheduleError
        Empty graph, missing/bad ``processors`` or ``memory``, a task without a ``cost`` dict,
        a cost for an unknown processor, a negative/NaN/inf cost or ``comm``, a task no
        processor can run, a cycle, costs and transfers summing over :data:`MAX_TOTAL_TIME`,
        a ``frame`` that is not an int >= 0 or is missing on some tasks only, an edge from a
        later frame to an earlier one. The message names the task, edge or attribute.
    """
    procs = _processors(dag)
    if dag.number_of_nodes() == 0:
        raise ScheduleError("dag: empty graph; expected at least one task")
    pindex = {p: k for k, p in enumerate(procs)}
    P = len(procs)
    memory = dag.graph.get("memory")
    problem = Problem()
    problem.procs = procs
    problem.memory_model = memory is not None
    if memory is not None:
        space_ids = {}
        problem.space = [space_ids.setdefault(memory[p], len(space_ids)) for p in procs]
        problem.n_spaces = len(space_ids)
        kind_names = [memory[p] for p in procs]
    else:
        problem.space = list(range(P))
        problem.n_spaces = P
        kind_names = [_name_kind(p) for p in procs]
    kind_ids = {}
    problem.kind = [kind_ids.setdefault(k, len(kind_ids)) for k in kind_names]
    problem.kinds = list(kind_ids)
    problem.kind_size = [problem.kind.count(k) for k in range(len(problem.kinds))]
    multi_kind = len(problem.kinds) > 1

    names = list(dag.nodes)
    index = {v: i for i, v in enumerate(names)}
    inf = math.inf
    cost, can, excl = [], [], []
    total = 0.0  # every task's largest cost plus every comm: a bound of any makespan
    fast = (float, int)  # exact types skip the slower numbers.Real ABC check
    for v, c in dag.nodes(data="cost"):
        if type(c) is not dict and not isinstance(c, Mapping):
            raise ScheduleError(
                f"dag: task {v!r} has no 'cost' dict (got {c!r}); expected {{processor: time}}"
            )
        if not c:
            raise ScheduleError(f"dag: task {v!r}: no processor can run it (its cost dict is empty)")
        row = [inf] * P
        for p, t in c.items():
            k = pindex.get(p)
            if k is None:
                raise ScheduleError(
                    f"dag: task {v!r} has a cost for unknown processor {p!r} (processors: {procs})"
                )
            if type(t) not in fast and (isinstance(t, bool) or not isinstance(t, numbers.Real)):
                raise ScheduleError(f"dag: task {v!r}: cost on {p!r} is {t!r}; expected a number")
            t = float(t)
            if not (t >= 0.0 and t < inf):
                raise ScheduleError(f"dag: task {v!r}: cost on {p!r} is {t}; expected a finite time >= 0")
            row[k] = t
        runs = tuple([k for k in range(P) if row[k] < inf])
        total += max([row[k] for k in runs])
        cost.append(row)
        can.append(runs)
        own = {problem.kind[k] for k in runs}
        excl.append(next(iter(own)) if multi_kind and len(own) == 1 else -1)
    n = len(names)
    preds = [[] for _ in range(n)]
    succs = [[] for _ in range(n)]
    for u, v, c in dag.edges(data="comm", default=0.0):
        if (type(c) not in fast and (isinstance(c, bool) or not isinstance(c, numbers.Real))) or not (
            0.0 <= float(c) < inf
        ):
            raise ScheduleError(f"dag: edge ({u!r}, {v!r}): comm is {c!r}; expected a finite time >= 0")
        iu, iv = index[u], index[v]
        if iu == iv:
            raise ScheduleError(f"dag: the graph has a cycle: self-loop on task {u!r}")
        c = float(c)
        total += c
        preds[iv].append((iu, c))
        succs[iu].append((iv, c))
    # Kahn's algorithm with a heap: the topological order that keeps node insertion order
    # wherever precedence allows, and a cycle check without networkx's generators.
    indeg = [len(p) for p in preds]
    heap = [i for i in range(n) if indeg[i] == 0]
    topo = []
    while heap:
        i = heapq.heappop(heap)
        topo.append(i)
        for j, _ in succs[i]:
            indeg[j] -= 1
            if indeg[j] == 0:
                heapq.heappush(heap, j)
    if len(topo) != n:
        raise ScheduleError(f"dag: the graph has a cycle: {_cycle_text(dag)}")
    _check_total(total, "dag")
    problem.frame = _frames(dag, names, preds)
    problem.names, problem.cost, problem.can, problem.preds = names, cost, can, preds
    problem.succs, problem.topo, problem.excl = succs, topo, excl
    return problem


def _frames(dag, names, preds):
    """task index -> ``frame`` attribute (checked), or ``None`` when no task has one."""
    raw = [dag.nodes[v].get("frame") for v in names]
    if all(f is None for f in raw):
        return None
    frame = []
    for v, f in zip(names, raw):
        if f is None:
            raise ScheduleError(
                f"dag: task {v!r} has no 'frame' attribute while other tasks have one; "
                "give every task of an unrolled DAG its frame number"
            )
        if isinstance(f, bool) or not isinstance(f, numbers.Integral) or f < 0:
            raise ScheduleError(f"dag: task {v!r}: 'frame' is {f!r}; expected an int >= 0")
        frame.append(int(f))
    for iv, pv in enumerate(preds):
        for iu, _ in pv:
            if frame[iu] > frame[iv]:
                raise ScheduleError(
                    f"dag: edge ({names[iu]!r}, {names[iv]!r}) goes from frame {frame[iu]} back "
                    f"to frame {frame[iv]}; inter-frame edges must go forward in time"
                )
    return frame
