"""Metrics (thesis eq. 2-5, Table 5.1; Topcuoglu 2002 SLR and speedup) against hand values."""

import itertools
import math
import random

import pytest

from warpvx.sched import (
    Schedule, ScheduledTask, cpu_gpu_dag, exclusive_overlap, heft, idle_time, makespan,
    max_exclusive_overlap, metrics, min_critical_path, overlap, random_dag, serial_time, slr,
    speedup, xeft, xo_efficiency,
)

from .dags import fig51_dag, topcuoglu_dag


def test_fig51_heft_metrics_by_hand():
    # HEFT (see test_xeft): cpu0 0:0-2 3:2-5 6:6-10 4:10-17 7:17-22; gpu 2:2-4 5:4-6 1:6-16.
    # O: 3&2 2 + 3&5 1 + 6&1 4 + 4&1 6 = 13. XO (CPU-only 0,4,7 vs GPU-only 1): 4&1 = 6.
    # Max XO = min(1 CPU * 10, 1 GPU * (2+7+5)) = 10. Idle: cpu0 22-21 = 1, gpu 22-14 = 8.
    # Critical path with minimum costs 0-2-5-6-7 = 2+2+2+2+5 = 13. No processor runs every
    # task, so the serial time is the sum of minimum costs: 2+10+2+2+7+2+2+5 = 32.
    dag = fig51_dag()
    m = metrics(dag, heft(dag))
    assert m["makespan"] == 22
    assert m["overlap"] == pytest.approx(13)
    assert m["exclusive_overlap"] == pytest.approx(6)
    assert m["max_exclusive_overlap"] == pytest.approx(10)
    assert m["xo_efficiency"] == pytest.approx(0.6)
    assert m["idle_per_processor"] == {"cpu0": 1, "gpu": 8}
    assert m["idle_time"] == 9
    assert m["idle_fraction"] == pytest.approx(9 / 44)
    assert m["min_critical_path"] == 13
    assert m["slr"] == pytest.approx(22 / 13)
    assert m["serial_time"] == 32
    assert m["speedup"] == pytest.approx(32 / 22)


def test_fig51_xeft_metrics_by_hand():
    # XEFT: cpu0 0:0-2 3:2-5 4:5-12 7:12-17; gpu 2:2-4 5:4-6 6:6-8 1:8-18.
    # O: 3&2 2 + 3&5 1 + 4&5 1 + 4&6 2 + 4&1 4 + 7&1 5 = 15; XO: 4&1 4 + 7&1 5 = 9.
    dag = fig51_dag()
    s = xeft(dag)
    assert overlap(s) == pytest.approx(15)
    assert exclusive_overlap(dag, s) == pytest.approx(9)
    assert xo_efficiency(dag, s) == pytest.approx(0.9)
    idle = idle_time(s)
    assert (idle.per_processor, idle.total) == ({"cpu0": 1, "gpu": 2}, 3)
    assert makespan(s) == 18


def test_topcuoglu_slr_and_speedup():
    # Minimum-cost critical path n1 n2 n9 n10: 9+13+12+7 = 41. P1 runs every task in
    # 14+13+11+13+12+13+7+5+18+21 = 127, the best single processor (P2 130, P3 143).
    dag = topcuoglu_dag()
    s = heft(dag)
    assert min_critical_path(dag) == 41
    assert slr(dag, s) == pytest.approx(80 / 41)
    assert serial_time(dag) == 127
    assert speedup(dag, s) == pytest.approx(127 / 80)
    assert math.isnan(xo_efficiency(dag, s))  # one processor kind: nothing is exclusive
    assert max_exclusive_overlap(dag) == 0


@pytest.mark.parametrize("n_cpus, dl, expected", [(2, 15, 30.0), (2, 20, 40.0), (3, 15, 44.1), (5, 25, 44.1)])
def test_max_xo_like_thesis_table_51(n_cpus, dl, expected):
    # Monocular ORB-SLAM+DL rows of Table 5.1: one GPU-only DL node of `dl` ms, CPU-only work
    # of 44.1 ms in total: Max XO = min(n_cpus * dl, 44.1).
    tasks = {"dl": (None, dl), "orb1": (20.0, None), "orb2": (24.1, None), "both": (5, 1)}
    dag = cpu_gpu_dag(tasks, [], n_cpus=n_cpus)
    assert max_exclusive_overlap(dag) == pytest.approx(expected)


def _naive_pairs(schedule, dag=None):
    """Reference: eq. 2 over every unordered pair, eq. 3 for the exclusive pairs."""
    tasks = list(schedule.tasks.values())
    o = xo = 0.0
    for t, q in itertools.combinations(tasks, 2):
        ov = max(0.0, min(t.finish, q.finish) - max(t.start, q.start))
        o += ov
        if dag is not None:
            ct, cq = dag.nodes[t.task]["cost"], dag.nodes[q.task]["cost"]
            t_cpu, t_gpu = any(p.startswith("cpu") for p in ct), "gpu" in ct
            q_cpu, q_gpu = any(p.startswith("cpu") for p in cq), "gpu" in cq
            if (not t_cpu and not q_gpu) or (not t_gpu and not q_cpu):
                xo += ov
    return o, xo


@pytest.mark.parametrize("seed", range(6))
def test_sweep_matches_pairwise_definition(seed):
    dag = random_dag(60, "tree" if seed % 2 else "linear", p_single=0.6, n_cpus=3, seed=seed)
    for s in (heft(dag), xeft(dag)):
        o, xo = _naive_pairs(s, dag)
        assert overlap(s) == pytest.approx(o, rel=1e-9, abs=1e-9)
        assert exclusive_overlap(dag, s) == pytest.approx(xo, rel=1e-9, abs=1e-9)
        assert exclusive_overlap(dag, s) <= max_exclusive_overlap(dag) + 1e-9


def test_overlap_of_random_intervals_matches_pairs():
    rng = random.Random(3)
    tasks = {}
    for i in range(40):
        s = rng.choice([rng.uniform(0, 50), float(rng.randint(0, 10))])  # exact ties too
        tasks[i] = ScheduledTask(i, f"p{i % 7}", s, s + rng.choice([0.0, rng.uniform(0, 20)]))
    sched = Schedule(tasks, [f"p{i}" for i in range(7)])
    assert overlap(sched) == pytest.approx(_naive_pairs(sched)[0], rel=1e-9)


def test_idle_time_within_makespan():
    s = Schedule({"a": ScheduledTask("a", "cpu0", 1.0, 4.0)}, ["cpu0", "cpu1", "gpu"])
    idle = idle_time(s)
    assert idle.per_processor == {"cpu0": 1.0, "cpu1": 4.0, "gpu": 4.0}
    assert idle.total == 9.0 and idle.fraction == pytest.approx(9 / 12)
