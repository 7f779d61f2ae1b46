"""Extreme costs and malformed ``cpu_gpu_dag`` arguments (issue 10, item 16).

Costs whose sum overflows a float made every policy fail with ``cannot convert float NaN to
integer``; wrong-length edge tuples raised bare unpacking errors. Both are warpvx errors now,
and costs anywhere in range schedule exactly as small ones do.
"""

import math

import networkx as nx
import pytest

from warpvx.errors import ScheduleError, WarpvxTypeError
from warpvx.sched import (
    POLICIES, cpu_gpu_dag, metrics, min_critical_path, schedule, serial_time, upward_rank,
    validate_schedule,
)
from warpvx.sched.dag import MAX_TOTAL_TIME

from .dags import fig51_dag, topcuoglu_dag


def _scaled(dag: nx.DiGraph, factor: float) -> nx.DiGraph:
    out = dag.copy()
    for _, attrs in out.nodes(data=True):
        attrs["cost"] = {p: t * factor for p, t in attrs["cost"].items()}
    for _, _, attrs in out.edges(data=True):
        attrs["comm"] = attrs.get("comm", 0.0) * factor
    return out


def _huge_dag(cost: float) -> nx.DiGraph:
    dag = nx.DiGraph(processors=["cpu0", "gpu"])
    dag.add_node("a", cost={"cpu0": cost, "gpu": cost})
    dag.add_node("b", cost={"cpu0": cost})
    dag.add_edge("a", "b", comm=1.0)
    return dag


@pytest.mark.parametrize("policy", list(POLICIES))
def test_costs_summing_past_float_max_raise_schedule_error(policy):
    with pytest.raises(ScheduleError, match=r"dag: the costs and transfers sum to inf"):
        schedule(_huge_dag(1e308), policy)


@pytest.mark.parametrize(
    "fn", [upward_rank, min_critical_path, serial_time], ids=lambda f: f.__name__
)
def test_costs_over_the_limit_raise_in_every_entry(fn):
    # Finite sum (3e300) but over the limit: refused, not computed with overflow later.
    with pytest.raises(ScheduleError, match=r"over the limit 1e\+300"):
        fn(_huge_dag(1.5e300))


def test_cpu_gpu_dag_refuses_costs_over_the_limit():
    with pytest.raises(ScheduleError, match=r"tasks and edges: the costs and transfers sum to inf"):
        cpu_gpu_dag({"a": (1e308, 1e308), "b": (1e308, None)}, [("a", "b", 1.0)])
    with pytest.raises(ScheduleError, match="tasks and edges"):
        cpu_gpu_dag({"a": (1.0, None), "b": (1.0, None)}, {("a", "b"): 2 * MAX_TOTAL_TIME})


@pytest.mark.parametrize("policy", list(POLICIES))
def test_dag_at_the_limit_gives_finite_valid_schedules_and_metrics(policy):
    # 40 independent tasks and a chain, every cost as large as the limit allows: the overlap
    # metrics (up to (n - 1) / 2 times the total) must stay finite too.
    n = 40
    cost = MAX_TOTAL_TIME / (2 * n)
    tasks = {i: (cost, cost) for i in range(n)}
    edges = [(i, i + 1, 0.0) for i in range(n // 2 - 1)]
    dag = cpu_gpu_dag(tasks, edges, n_cpus=8)
    sched = schedule(dag, policy)
    validate_schedule(dag, sched)
    for name, value in metrics(dag, sched).items():
        if name != "idle_per_processor" and name != "xo_efficiency":
            assert math.isfinite(value), name


@pytest.mark.parametrize("factor", [2.0**-1000, 2.0**-20, 2.0**40, 2.0**980])
@pytest.mark.parametrize("make", [topcuoglu_dag, fig51_dag])
@pytest.mark.parametrize("policy", list(POLICIES))
def test_schedule_scales_exactly_with_costs(policy, make, factor):
    # A power of two scales every float exactly, so each start and finish must scale exactly
    # and the placement and priority list must not change, from tiny to huge costs.
    dag = make()
    base = schedule(dag, policy)
    big_dag = _scaled(dag, factor)
    big = schedule(big_dag, policy)
    validate_schedule(big_dag, big)
    assert big.priority == base.priority
    for v, t in base.tasks.items():
        s = big.tasks[v]
        assert (s.processor, s.start, s.finish) == (t.processor, t.start * factor, t.finish * factor)


# --------------------------------------------------------------------------- cpu_gpu_dag shapes

TASKS = {"a": (1.0, 2.0), "b": (1.0, None)}


@pytest.mark.parametrize(
    "edges, match",
    [
        ([("a",)], r"edges\[0\]: expected \(u, v\) or \(u, v, transfer\), got \('a',\)"),
        ([("a", "b", 1.0, 2.0)], r"edges\[0\]: .*got \('a', 'b', 1.0, 2.0\)"),
        ([("a", "b"), 5], r"edges\[1\]: .*got 5"),
        ([("a", "b"), "ab"], r"edges\[1\]: .*got 'ab'"),
        ({("a",): 1.0}, r"edges: key \('a',\); expected a \(u, v\) pair"),
        ({"ab": 1.0}, r"edges: key 'ab'; expected a \(u, v\) pair"),
        ({("a", "b", "c"): 1.0}, r"edges: key \('a', 'b', 'c'\)"),
        ([("a", "b", "x")], r"edges\[\('a', 'b'\)\] transfer: expected a number"),
        ([("a", "b", math.inf)], r"edges\[\('a', 'b'\)\] transfer: expected a finite time"),
    ],
)
def test_cpu_gpu_dag_bad_edge_shapes(edges, match):
    with pytest.raises(ScheduleError, match=match):
        cpu_gpu_dag(TASKS, edges)


@pytest.mark.parametrize("edges", [5, None, "ab"])
def test_cpu_gpu_dag_edges_not_iterable(edges):
    with pytest.raises(WarpvxTypeError, match="edges: expected a dict"):
        cpu_gpu_dag(TASKS, edges)


@pytest.mark.parametrize(
    "times, match",
    [
        ((1.0,), r"tasks\['a'\]: expected \(cpu_time or None, gpu_time or None\)"),
        ((1.0, 2.0, 3.0), r"tasks\['a'\]: expected"),
        (3.0, r"tasks\['a'\]: expected"),
        ((1e308 * 10, None), r"tasks\['a'\] cpu_time: expected a finite time"),
        ((-1.0, None), r"tasks\['a'\] cpu_time: expected a finite time >= 0"),
    ],
)
def test_cpu_gpu_dag_bad_task_times(times, match):
    with pytest.raises(ScheduleError, match=match):
        cpu_gpu_dag({"a": times, "b": (1.0, None)}, [("a", "b")])


def test_cpu_gpu_dag_accepts_every_documented_edge_form():
    forms = [{("a", "b"): 0.5}, [("a", "b", 0.5)], [["a", "b", 0.5]], (("a", "b", 0.5),)]
    for edges in forms:
        dag = cpu_gpu_dag(TASKS, edges)
        assert dag.edges["a", "b"]["comm"] == 0.5
    assert cpu_gpu_dag(TASKS, [("a", "b")]).edges["a", "b"]["comm"] == 0.0
