"""Synthetic CPU/GPU task DAGs for the scheduling study (thesis §5.3).

Two classes, by the amount of topological constraint between tasks:

- ``"tree"``: high average degree, small diameter. A single root, then about log2(n) levels
  of growing width; each task has one parent on the previous level plus up to three more from
  the two previous levels.
- ``"linear"``: low degree, long diameter. A single root feeding 1-4 parallel chains of
  consecutive tasks, with a few cross edges (10% of the tasks) from one chain to a later
  position of another.

Task costs follow the generator of the thesis authors' simulator (SPEC §7): with probability
``p_single`` a task has one implementation, CPU-only with probability ``p_cpu_only``, else
GPU-only; its time is uniform in ``cpu_range``. Otherwise it has both, the CPU time uniform in
``cpu_range`` and the GPU time that over a speed-up uniform in ``gpu_speedup``. Each edge's
host-device transfer time is uniform in ``comm_range``. Times are rounded to 0.01.
"""

from __future__ import annotations

import math
import random

import networkx as nx

from ..check import check_choice, check_float, check_int
from ..errors import WarpvxTypeError, WarpvxValueError
from .dag import cpu_gpu_dag

CLASSES = ("tree", "linear")


def _range(r, name, *, positive=False):
    try:
        lo, hi = r
    except (TypeError, ValueError):
        raise WarpvxTypeError(f"{name}: expected a (low, high) pair, got {r!r}") from None
    lo = check_float(lo, f"{name}[0]", min_value=0.0, strict_min=positive)
    hi = check_float(hi, f"{name}[1]", min_value=0.0, strict_min=positive)
    if hi < lo:
        raise WarpvxValueError(f"{name}: expected low <= high, got {r!r}")
    return lo, hi


def _tree_edges(n, rng):
    depth = max(2, round(math.log2(n)))
    # Level of each non-root task: widths grow like a tree's, every level non-empty.
    weights = [1.6**lvl for lvl in range(1, depth)]
    levels = [[0]]
    counts = [1] * (depth - 1)
    for _ in range(n - depth):
        counts[rng.choices(range(depth - 1), weights)[0]] += 1
    v = 1
    for c in counts:
        levels.append(list(range(v, v + c)))
        v += c
    edges = set()
    for lvl in range(1, len(levels)):
        prev = levels[lvl - 1]
        older = prev + (levels[lvl - 2] if lvl >= 2 else [])
        for t in levels[lvl]:
            edges.add((rng.choice(prev), t))
            for _ in range(rng.randint(0, 3)):
                edges.add((rng.choice(older), t))
    return sorted(edges)


def _linear_edges(n, rng):
    n_chains = min(n - 1, rng.randint(1, 4))
    chains = [[] for _ in range(n_chains)]
    for t in range(1, n):
        chains[(t - 1) % n_chains].append(t)
    edges = set()
    for chain in chains:
        edges.add((0, chain[0]))
        edges.update(zip(chain, chain[1:]))
    # Cross edges go from position i of one chain to a later position of another: acyclic.
    for _ in range(n // 10 if n_chains > 1 else 0):
        a, b = rng.sample(range(n_chains), 2)
        i = rng.randrange(len(chains[a]))
        later = [j for j in range(i + 1, len(chains[b]))]
        if later:
            edges.add((chains[a][i], chains[b][rng.choice(later)]))
    return sorted(edges)


def random_dag(
    n_nodes: int,
    kind: str = "tree",
    p_single: float = 0.5,
    p_cpu_only: float = 0.5,
    cpu_range=(10.0, 90.0),
    gpu_speedup=(1.0, 4.0),
    comm_range=(0.0, 10.0),
    n_cpus: int = 3,
    seed=None,
) -> nx.DiGraph:
    """A random CPU/GPU task DAG of class ``kind`` (see the module docstring).

    Parameters
    ----------
    n_nodes : int
        Number of tasks, >= 2 (the thesis' study uses 20 to 250).
    kind : {"tree", "linear"}
    p_single : float
        Probability that a task has a single implementation (an exclusive task).
    p_cpu_only : float
        Probability that a single-implementation task is CPU-only (else GPU-only).
    cpu_range : (float, float)
        CPU time range (and GPU-only time range), e.g. ms.
    gpu_speedup : (float, float)
        Range of CPU time / GPU time for tasks with both implementations (> 0).
    comm_range : (float, float)
        Range of each edge's host-device transfer time.
    n_cpus : int
        CPU workers beside the GPU.
    seed : int or random.Random or None

    Returns
    -------
    networkx.DiGraph
        As :func:`warpvx.sched.cpu_gpu_dag` builds; tasks are the integers ``0 .. n-1`` in a
        topological order, task 0 the single root. ``dag.graph["class"]`` holds ``kind`` and
        ``dag.graph["params"]`` the generator's arguments.
    """
    n = check_int(n_nodes, "n_nodes", min_value=2)
    kind = check_choice(kind, "kind", CLASSES)
    p_single = check_float(p_single, "p_single", min_value=0.0, max_value=1.0)
    p_cpu_only = check_float(p_cpu_only, "p_cpu_only", min_value=0.0, max_value=1.0)
    cpu_lo, cpu_hi = _range(cpu_range, "cpu_range")
    sp_lo, sp_hi = _range(gpu_speedup, "gpu_speedup", positive=True)
    cm_lo, cm_hi = _range(comm_range, "comm_range")
    n_cpus = check_int(n_cpus, "n_cpus", min_value=1)
    rng = seed if isinstance(seed, random.Random) else random.Random(seed)

    edges = _tree_edges(n, rng) if kind == "tree" else _linear_edges(n, rng)
    tasks = {}
    for t in range(n):
        cpu_t = round(rng.uniform(cpu_lo, cpu_hi), 2)
        if rng.random() < p_single:
            tasks[t] = (cpu_t, None) if rng.random() < p_cpu_only else (None, cpu_t)
        else:
            tasks[t] = (cpu_t, round(cpu_t / rng.uniform(sp_lo, sp_hi), 2))
    comm = {e: round(rng.uniform(cm_lo, cm_hi), 2) for e in edges}
    dag = cpu_gpu_dag(tasks, comm, n_cpus)
    dag.graph["class"] = kind
    dag.graph["params"] = {
        "n_nodes": n,
        "p_single": p_single,
        "p_cpu_only": p_cpu_only,
        "cpu_range": (cpu_lo, cpu_hi),
        "gpu_speedup": (sp_lo, sp_hi),
        "comm_range": (cm_lo, cm_hi),
        "n_cpus": n_cpus,
    }
    return dag
