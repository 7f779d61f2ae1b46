"""Properties of every policy over generated DAGs, and of the generator itself."""

import statistics

import networkx as nx
import pytest

from warpvx.sched import (
    POLICIES, heft, min_critical_path, overlap, random_dag, validate_schedule, xeft,
    xeft_order,
)

CASES = [
    (kind, n, p_single, p_cpu, speedup, n_cpus, seed)
    for seed, (kind, n, p_single, p_cpu, speedup, n_cpus) in enumerate(
        [
            ("tree", 20, 0.5, 0.5, (1, 4), 2),
            ("tree", 80, 0.8, 0.2, (4, 9), 3),
            ("tree", 150, 0.2, 0.8, (0.5, 2), 5),
            ("tree", 45, 0.8, 0.8, (1, 4), 4),
            ("tree", 120, 0.5, 0.2, (0.5, 2), 2),
            ("linear", 20, 0.5, 0.5, (1, 4), 2),
            ("linear", 80, 0.8, 0.2, (4, 9), 3),
            ("linear", 150, 0.2, 0.8, (0.5, 2), 5),
            ("linear", 45, 0.8, 0.8, (1, 4), 4),
            ("linear", 120, 0.5, 0.2, (0.5, 2), 2),
        ]
    )
]


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"{c[0]}-{c[1]}-s{c[-1]}")
def generated(request):
    kind, n, p_single, p_cpu, speedup, n_cpus, seed = request.param
    dag = random_dag(n, kind, p_single=p_single, p_cpu_only=p_cpu, gpu_speedup=speedup,
                     n_cpus=n_cpus, seed=seed)
    return dag, {name: fn(dag) for name, fn in POLICIES.items()}


def test_every_schedule_is_valid(generated):
    dag, scheds = generated
    for s in scheds.values():
        validate_schedule(dag, s)


def test_best_is_never_worse_than_heft_or_xeft(generated):
    _, scheds = generated
    assert scheds["best"].makespan <= scheds["heft"].makespan
    assert scheds["best"].makespan == min(scheds["heft"].makespan, scheds["xeft"].makespan)


def test_makespan_at_least_min_critical_path(generated):
    dag, scheds = generated
    cp = min_critical_path(dag)
    for s in scheds.values():
        assert s.makespan >= cp - 1e-9


def test_priority_lists_are_topological_permutations(generated):
    dag, scheds = generated
    for name in ("heft", "xeft"):
        order = scheds[name].priority
        assert sorted(order) == sorted(dag.nodes)
        pos = {v: i for i, v in enumerate(order)}
        assert all(pos[u] < pos[v] for u, v in dag.edges), name


def test_baseline_never_overlaps(generated):
    _, scheds = generated
    assert overlap(scheds["baseline"]) == 0


def test_deterministic(generated):
    dag, scheds = generated
    assert heft(dag).tasks == scheds["heft"].tasks
    assert xeft(dag).tasks == scheds["xeft"].tasks
    assert xeft_order(dag) == scheds["xeft"].priority


def test_generator_reproducible_and_in_range():
    a = random_dag(100, "tree", cpu_range=(10, 50), gpu_speedup=(4, 9), comm_range=(1, 2), seed=7)
    b = random_dag(100, "tree", cpu_range=(10, 50), gpu_speedup=(4, 9), comm_range=(1, 2), seed=7)
    assert nx.utils.graphs_equal(a, b)
    assert nx.is_directed_acyclic_graph(a) and nx.is_weakly_connected(a)
    assert a.graph["processors"] == ["cpu0", "cpu1", "cpu2", "gpu"]
    for _, cost in a.nodes(data="cost"):
        cpu, gpu = cost.get("cpu0"), cost.get("gpu")
        assert cpu is not None or gpu is not None
        single = cpu if gpu is None else gpu if cpu is None else None
        if single is not None:
            assert 10 <= single <= 50  # single implementation: time in cpu_range
        else:
            assert 10 <= cpu <= 50
            assert cpu / 9 - 0.005 <= gpu <= cpu / 4 + 0.005  # speed-up in [4, 9], 0.01 rounding
    assert all(1 <= c <= 2 for *_, c in a.edges(data="comm"))


def test_generator_exclusive_shares():
    dag = random_dag(250, "linear", p_single=0.8, p_cpu_only=0.2, seed=1)
    costs = [c for _, c in dag.nodes(data="cost")]
    single = sum(1 for c in costs if len(c) != 4) / len(costs)
    cpu_only = sum(1 for c in costs if "gpu" not in c) / max(1, sum(1 for c in costs if len(c) != 4))
    assert 0.7 < single < 0.9
    assert 0.1 < cpu_only < 0.32


def test_tree_dags_are_denser_and_shallower_than_linear():
    def shape(kind):
        deg, depth = [], []
        for seed in range(6):
            g = random_dag(150, kind, seed=seed)
            deg.append(2 * g.number_of_edges() / g.number_of_nodes())
            depth.append(nx.dag_longest_path_length(g) + 1)
        return statistics.fmean(deg), statistics.fmean(depth)

    tree_deg, tree_depth = shape("tree")
    lin_deg, lin_depth = shape("linear")
    assert tree_deg > 1.5 * lin_deg
    assert tree_depth * 3 < lin_depth
