"""Scheduling policies: VisionWorks baseline, HEFT, XEFT and best-of.

Every policy is a plain function ``policy(dag) -> Schedule`` over the task-DAG model of
:mod:`warpvx.sched.dag`. HEFT follows Topcuoglu, Hariri and Wu, "Performance-effective and
low-complexity task scheduling for heterogeneous computing", IEEE TPDS 13(3), 2002; XEFT is
Algorithm 1 of the thesis (§5.2); the baseline is the VisionWorks policy of thesis §5.1.
"""

from __future__ import annotations

import math
from bisect import bisect_left
from collections.abc import Callable

import networkx as nx

from ..errors import UnsupportedError, WarpvxTypeError
from .dag import DEVICE, GPU, Problem, prepare
from .frames import frame_times, unroll
from .schedule import Schedule, ScheduledTask


# --------------------------------------------------------------------------- ranking


def _mean_costs(problem: Problem) -> list:
    return [sum(row[k] for k in runs) / len(runs) for row, runs in zip(problem.cost, problem.can)]


def _best_costs(problem: Problem) -> list:
    return [min(row[k] for k in runs) for row, runs in zip(problem.cost, problem.can)]


def _upward_rank(problem: Problem, node_cost: list | None = None) -> list:
    """rank(t) = mean_w(t) + max over successors q of (mean_c(t, q) + rank(q)) (thesis eq. 1).

    mean_w: mean cost over the processors that can run t. mean_c: without a memory model the
    edge's ``comm`` (Topcuoglu's edge weights are already the average cost); with one, ``comm``
    times the share of processor pairs (p able to run t, q able to run the successor, p == q
    included) that lie in different memory spaces. In a DAG with frames only successors of the
    same frame count: the order is frame-major anyway, and a frame's rank list is then the one
    of that frame alone (inter-frame edges would inflate the ranks of a frame's sources).
    ``node_cost`` (task -> cost) replaces mean_w, e.g. by the best cost (:func:`_best_costs`).
    """
    mean_cost = _mean_costs(problem) if node_cost is None else node_cost
    n = len(mean_cost)
    rank = [0.0] * n
    succs = problem.succs
    frame = problem.frame
    if frame is not None:
        succs = [[(q, c) for q, c in sq if frame[q] == frame[v]] for v, sq in enumerate(succs)]
    if not problem.memory_model:
        for v in reversed(problem.topo):
            best = 0.0
            for q, c in succs[v]:
                x = c + rank[q]
                if x > best:
                    best = x
            rank[v] = mean_cost[v] + best
        return rank
    # Tasks fall into few patterns of runnable processors (CPU-only, GPU-only, both): the share
    # of cross-space pairs is computed once per pair of patterns.
    space = problem.space
    pattern_of, patterns = [], {}
    for runs in problem.can:
        pattern_of.append(patterns.setdefault(runs, len(patterns)))
    counts = []
    for runs in patterns:
        c = [0] * problem.n_spaces
        for k in runs:
            c[space[k]] += 1
        counts.append((c, len(runs)))
    share = [
        [1.0 - sum(a * b for a, b in zip(ca, cb)) / (na * nb) for cb, nb in counts] for ca, na in counts
    ]
    for v in reversed(problem.topo):
        best = 0.0
        sv = share[pattern_of[v]]
        for q, c in succs[v]:
            x = c * sv[pattern_of[q]] + rank[q]
            if x > best:
                best = x
        rank[v] = mean_cost[v] + best
    return rank


def _rank_order(problem: Problem, rank: list) -> list:
    # Decreasing rank; ranks equal up to round-off (1e-9 of the largest) fall back to the
    # topological order, which keeps insertion order among independent tasks and keeps the
    # list a valid topological order when zero-cost tasks tie with their successors. With
    # frames, frame-major first: every edge goes to the same or a later frame, so the list
    # stays topological, and frame f never waits behind frame f+1 for a processor.
    pos = [0] * len(rank)
    for i, v in enumerate(problem.topo):
        pos[v] = i
    frame = problem.frame or [0] * len(rank)
    unit = 1e-9 * max(rank)
    if unit > 0:
        return sorted(range(len(rank)), key=lambda v: (frame[v], -round(rank[v] / unit), pos[v]))
    return sorted(range(len(rank)), key=lambda v: (frame[v], pos[v]))


def _heft_order(problem: Problem) -> list:
    """HEFT's priority list: tasks by decreasing upward rank (see :func:`_rank_order`)."""
    return _rank_order(problem, _upward_rank(problem))


def upward_rank(dag: nx.DiGraph) -> dict:
    """HEFT's upward rank of every task (Topcuoglu et al. 2002, eq. 8; thesis eq. 1).

    Parameters
    ----------
    dag : networkx.DiGraph
        A task DAG (:mod:`warpvx.sched.dag`).

    Returns
    -------
    dict
        task -> rank: mean computation cost over the processors that can run the task plus the
        largest (mean communication cost + rank) over its successors. The mean communication
        cost is the edge's ``comm`` without a ``memory`` attribute (as in the paper), else
        ``comm`` times the share of (processor of the task, processor of the successor) pairs
        in different memory spaces.
    """
    problem = prepare(dag)
    rank = _upward_rank(problem)
    return {problem.names[i]: r for i, r in enumerate(rank)}


# --------------------------------------------------------------------------- placement


def _place(problem: Problem, order: list):
    """:func:`_place_eft`, and for a DAG with frames the shorter of it and frames back to back.

    Greedy list scheduling has anomalies: letting frame f+1 fill frame f's gaps can, rarely,
    end later than running the frames one after the other. The back-to-back placement is the
    guarantee that frames in flight never cost more than K single-frame schedules in a row.
    """
    placed = _place_eft(problem, order)
    if problem.frame is None:
        return placed
    serial = _place_eft(problem, order, barrier=True)
    return serial if max(serial[2]) < max(placed[2]) else placed


def _place_eft(problem: Problem, order: list, barrier: bool = False):
    """Insertion-based earliest-finish-time placement of tasks in ``order`` (Topcuoglu §4.1).

    Each processor keeps its free intervals as two sorted lists (starts, ends; the last one is
    open-ended); a task takes, on each processor that can run it, the first free interval that
    holds it after its data-ready time, and goes to the processor where it finishes first
    (ties: the first in ``processors`` order). ``barrier`` (a frame-major order of a DAG with
    frames): each frame starts when every earlier task has finished, frames back to back.
    """
    n = len(problem.names)
    P = len(problem.procs)
    inf = math.inf
    gap_s = [[0.0] for _ in range(P)]
    gap_e = [[inf] for _ in range(P)]
    start = [0.0] * n
    finish = [0.0] * n
    proc = [-1] * n
    pspace = [-1] * n  # memory space of each placed task's processor
    space = problem.space
    cost = problem.cost
    preds = problem.preds
    can = problem.can
    frame = problem.frame if barrier else None
    current, end = -1, 0.0
    for v in order:
        if frame is not None and frame[v] != current:
            current = frame[v]
            gap_s = [[end] for _ in range(P)]
            gap_e = [[inf] for _ in range(P)]
        pv = preds[v]
        row = cost[v]
        best_f = inf
        best_k = best_g = -1
        best_st = 0.0
        ready_of = {}
        for k in can[v]:
            sp = space[k]
            ready = ready_of.get(sp)
            if ready is None:
                ready = 0.0
                for u, c in pv:
                    t = finish[u] if pspace[u] == sp else finish[u] + c
                    if t > ready:
                        ready = t
                ready_of[sp] = ready
            duration = row[k]
            starts = gap_s[k]
            ends = gap_e[k]
            g = bisect_left(ends, ready + duration)
            while True:
                s = starts[g]
                if s <= ready:
                    st = ready
                    break
                if s + duration <= ends[g]:
                    st = s
                    break
                g += 1
            f = st + duration
            if f < best_f:
                best_f, best_k, best_g, best_st = f, k, g, st
        k, g = best_k, best_g
        s, e = gap_s[k][g], gap_e[k][g]
        new_s, new_e = [], []
        if best_st > s:
            new_s.append(s)
            new_e.append(best_st)
        if e > best_f:
            new_s.append(best_f)
            new_e.append(e)
        gap_s[k][g : g + 1] = new_s
        gap_e[k][g : g + 1] = new_e
        start[v], finish[v], proc[v], pspace[v] = best_st, best_f, k, space[k]
        end = max(end, best_f)
    return proc, start, finish


def _to_schedule(problem: Problem, proc, start, finish, policy: str, order) -> Schedule:
    names, procs = problem.names, problem.procs
    tasks = {
        names[i]: ScheduledTask(names[i], procs[proc[i]], start[i], finish[i])
        for i in range(len(names))
    }
    return Schedule(tasks, list(procs), policy, [names[i] for i in order])


# --------------------------------------------------------------------------- policies


def heft(dag: nx.DiGraph) -> Schedule:
    """HEFT: upward-rank order, insertion-based earliest finish time.

    Parameters
    ----------
    dag : networkx.DiGraph
        A task DAG (:mod:`warpvx.sched.dag`).

    Returns
    -------
    Schedule
        ``policy="heft"``, ``priority`` the rank list (decreasing upward rank, ties in
        topological order).

    Raises
    ------
    ScheduleError
        Bad DAG (see :func:`warpvx.sched.dag.prepare`).

    References
    ----------
    Topcuoglu, Hariri, Wu, IEEE TPDS 13(3):260-274, 2002.
    """
    problem = prepare(dag)
    order = _heft_order(problem)
    return _to_schedule(problem, *_place(problem, order), "heft", order)


def xeft(dag: nx.DiGraph) -> Schedule:
    """XEFT: HEFT's rank list reordered by thesis Algorithm 1, then HEFT's placement.

    The reordering builds clusters of mutually independent exclusive tasks that are adjacent
    in the list, so tasks that cannot compete for one processor kind run side by side
    (exclusive overlap, thesis §5.2). See :func:`xeft_order` for the exact rules and for the
    second rank list (best costs) tried besides HEFT's.

    Returns
    -------
    Schedule
        ``policy="xeft"``, ``priority`` the reordered list.
    """
    problem = prepare(dag)
    order, placed = _xeft(problem, _heft_order(problem))
    return _to_schedule(problem, *placed, "xeft", order)


def xeft_order(dag: nx.DiGraph) -> list:
    """XEFT's priority list: HEFT's rank list reordered by thesis Algorithm 1.

    Walking the list, each exclusive task ``a`` at position ``i`` collects *candidates*: ``a``
    and every later exclusive task not reachable from a candidate collected before it (rows
    5-11). With ``load[K] = sum(mean cost of the candidates exclusive to kind K) / number of
    processors of kind K``, the kind with the smallest load (ties: the kind of the earliest
    processor in ``processors``, i.e. the CPUs for :func:`cpu_gpu_dag`) gives the cluster
    all its candidates; candidates of each other kind, in list order, join while each brings
    that kind's load closer to the smallest one (rows 16-26). Candidates of fewer than two
    kinds make no cluster. APPLY (row 27, thesis Fig. 5.3) makes the cluster contiguous: of
    the tasks between its first and last member, those that reach a later member move before
    the cluster, the others after it (the member moves up); the walk goes on after the
    cluster. A cluster of fewer than two tasks changes nothing and the walk goes on at
    ``i + 1``. Paths between cluster members are impossible (row 9), so the list stays a
    topological order. In a DAG with frames the candidates come from ``a``'s frame only, so
    the list stays frame-major.

    With two kinds (CPUs and one GPU) this is the thesis' algorithm: ``total_gpu <
    total_cpu / n_cores`` picks the GPU tasks, else the CPU tasks.

    The rank list walked is HEFT's (mean costs) or the one of ranks from each task's best
    cost, whichever list, once reordered and placed, ends first (ties: HEFT's). The rank
    function is a free choice of HEFT (Zhao and Sakellariou, "An experimental investigation
    into the rank function of the heterogeneous earliest finish time scheduling algorithm",
    Euro-Par 2003); the best cost suits tasks whose CPU and GPU costs differ by an order of
    magnitude, where the mean overstates a task that will run on its fast processor.
    """
    problem = prepare(dag)
    order, _ = _xeft(problem, _heft_order(problem))
    return [problem.names[i] for i in order]


def _xeft(problem: Problem, heft_order: list):
    """XEFT's (order, placement) from HEFT's rank list, see :func:`xeft_order`."""
    order = _xeft_order(problem, heft_order)
    placed = _place(problem, order)
    if all(e < 0 for e in problem.excl):
        return order, placed  # no clusters: XEFT is HEFT
    alt = _xeft_order(problem, _rank_order(problem, _upward_rank(problem, _best_costs(problem))))
    if alt != order:
        alt_placed = _place(problem, alt)
        if max(alt_placed[2]) < max(placed[2]):
            return alt, alt_placed
    return order, placed


def _descendant_bits(problem: Problem) -> list:
    """Reachability as Python-int bitsets: bit j of ``descendants[i]`` is set when task i
    reaches task j (i included)."""
    descendants = [0] * len(problem.names)
    for v in reversed(problem.topo):
        b = 1 << v
        for q, _ in problem.succs[v]:
            b |= descendants[q]
        descendants[v] = b
    return descendants


def _xeft_order(problem: Problem, rank_order: list) -> list:
    excl = problem.excl
    if all(e < 0 for e in excl):
        return list(rank_order)
    order = list(rank_order)
    n = len(order)
    descendants = _descendant_bits(problem)
    mean_cost = _mean_costs(problem)
    kind_size = problem.kind_size
    frame = problem.frame or [0] * n
    # Tie rule for the smallest load: the kind whose first processor comes first.
    kind_first = {}
    for k, kd in enumerate(problem.kind):
        kind_first.setdefault(kd, k)
    i = 0
    while i < n:
        a = order[i]
        if excl[a] < 0:
            i += 1
            continue
        cand = [a]
        reach = descendants[a]
        # With frames a cluster stays inside one frame, so the list stays frame-major.
        fa = frame[a]
        for b in [b for b in order[i + 1 :] if excl[b] >= 0 and frame[b] == fa]:
            if not (reach >> b) & 1:
                cand.append(b)
                reach |= descendants[b]
        cluster = _balance(cand, excl, mean_cost, kind_size, kind_first)
        if len(cluster) < 2:
            i += 1
            continue
        order, end = _apply(order, cluster, descendants)
        i = end + 1
    return order


def _balance(cand, excl, mean_cost, kind_size, kind_first) -> list:
    """Rows 12-26 of Algorithm 1: the cluster chosen among the candidates (list order kept)."""
    by_kind = {}
    for c in cand:
        by_kind.setdefault(excl[c], []).append(c)
    if len(by_kind) < 2:
        return []
    load = {kd: sum(mean_cost[c] for c in cs) / kind_size[kd] for kd, cs in by_kind.items()}
    base = min(load, key=lambda kd: (load[kd], kind_first[kd]))
    target = load[base]
    chosen = set(by_kind[base])
    for kd, cs in by_kind.items():
        if kd == base:
            continue
        m = kind_size[kd]
        t = 0.0
        for c in cs:
            if abs(target - (t + mean_cost[c]) / m) < abs(target - t / m):
                chosen.add(c)
                t += mean_cost[c]
    return [c for c in cand if c in chosen]


def _apply(order, cluster, descendants):
    """APPLY(rank, cluster): make the cluster contiguous; return (new order, cluster end)."""
    members = set(cluster)
    bits = 0
    for c in cluster:
        bits |= 1 << c
    pos = [i for i, v in enumerate(order) if v in members]
    first, last = pos[0], pos[-1]
    before, inside, after = [], [], []
    for v in order[first : last + 1]:
        if v in members:
            inside.append(v)
        elif descendants[v] & bits:
            before.append(v)  # an ancestor of a later member: the cluster moves down past it
        else:
            after.append(v)  # independent of the members after it: they move up past it
    new = order[:first] + before + inside + after + order[last + 1 :]
    return new, first + len(before) + len(inside) - 1


def _is_gpu(problem: Problem, k: int) -> bool:
    name = problem.procs[k]
    return name.lower().startswith(GPU) or (
        problem.memory_model and problem.kinds[problem.kind[k]] == DEVICE)


def baseline(dag: nx.DiGraph) -> Schedule:
    """The VisionWorks policy (thesis §5.1): GPU when possible, serial, no overlap.

    Each task goes to a GPU when it has a GPU implementation (a processor named ``gpu*`` or in
    memory space ``"device"``; the fastest such), else to its fastest processor (ties: the
    first in ``processors``). Tasks run one at a time in HEFT's rank order (a topological
    order): each starts when the previous one has finished and its inputs, with their
    transfers, are ready.

    Returns
    -------
    Schedule
        ``policy="baseline"``.
    """
    problem = prepare(dag)
    order = _heft_order(problem)
    n = len(problem.names)
    start = [0.0] * n
    finish = [0.0] * n
    proc = [-1] * n
    space = problem.space
    gpus = [k for k in range(len(problem.procs)) if _is_gpu(problem, k)]
    t = 0.0
    for v in order:
        row = problem.cost[v]
        on_gpu = [k for k in gpus if row[k] < math.inf]
        pool = on_gpu or problem.can[v]
        k = min(pool, key=lambda k: row[k])
        ready = t
        for u, c in problem.preds[v]:
            x = finish[u] if space[proc[u]] == space[k] else finish[u] + c
            if x > ready:
                ready = x
        start[v], finish[v], proc[v] = ready, ready + row[k], k
        t = finish[v]
    return _to_schedule(problem, proc, start, finish, "baseline", order)


def best(dag: nx.DiGraph) -> Schedule:
    """Both HEFT and XEFT; the schedule with the shorter makespan (ties: HEFT).

    Never worse than HEFT by construction. The returned schedule has ``policy="best"`` and
    ``info["chosen"]`` set to ``"heft"`` or ``"xeft"``.
    """
    problem = prepare(dag)
    order_h = _heft_order(problem)
    placed_h = _place(problem, order_h)
    order_x, placed_x = _xeft(problem, order_h)
    if order_x != order_h and max(placed_x[2]) < max(placed_h[2]):
        chosen, order, placed = "xeft", order_x, placed_x
    else:
        chosen, order, placed = "heft", order_h, placed_h
    sched = _to_schedule(problem, *placed, "best", order)
    sched.info["chosen"] = chosen
    return sched


POLICIES: dict = {"baseline": baseline, "heft": heft, "xeft": xeft, "best": best}


def schedule(dag: nx.DiGraph, policy="heft", *, frames=None, delays=()) -> Schedule:
    """Schedule ``dag`` with a policy given by name (a key of :data:`POLICIES`) or callable.

    Parameters
    ----------
    dag : networkx.DiGraph
        A task DAG (:mod:`warpvx.sched.dag`).
    policy : str or callable
    frames : int, optional
        Frames in flight K: schedule ``unroll(dag, K, delays)`` (tasks ``(v, f)``,
        :func:`warpvx.sched.frames.unroll`) frame-major, and put the unrolled DAG
        (``info["dag"]``), ``info["latency"]`` (per frame) and ``info["period"]`` (steady
        state) in the result.
    delays : dict or iterable
        Inter-frame edges for ``frames`` (see :func:`~warpvx.sched.frames.unroll`).

    Raises
    ------
    UnsupportedError
        Unknown policy name.
    WarpvxTypeError
        ``policy`` is neither a string nor a callable, or the callable returns no Schedule.
    """
    if isinstance(policy, str):
        fn = POLICIES.get(policy.lower())
        if fn is None:
            opts = ", ".join(repr(p) for p in POLICIES)
            raise UnsupportedError(f"policy: expected one of {opts} or a callable, got {policy!r}")
    elif isinstance(policy, Callable):
        fn = policy
    else:
        raise WarpvxTypeError(f"policy: expected a policy name or a callable, got {type(policy).__name__}")
    if frames is not None:
        dag = unroll(dag, frames, delays)
    result = fn(dag)
    if not isinstance(result, Schedule):
        raise WarpvxTypeError(f"policy: {policy!r} returned {type(result).__name__}, expected a Schedule")
    if frames is not None:
        times = frame_times(dag, result)
        result.info.update(dag=dag, latency=times.latency, period=times.period)
    return result
