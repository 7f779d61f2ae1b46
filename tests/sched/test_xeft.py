"""XEFT (thesis Algorithm 1) and best-of, on hand-checked DAGs."""

import pytest

from warpvx.sched import (
    best, cpu_gpu_dag, heft, random_dag, validate_schedule, xeft, xeft_order,
)
from warpvx.sched.dag import prepare
from warpvx.sched.policies import _heft_order, _place, _xeft_order

from .dags import fig51_dag, spans


def test_smoke():
    s = xeft(fig51_dag())
    assert s.policy == "xeft"
    assert len(s.tasks) == 8


def test_fig51_heft_order_is_the_thesis_one():
    assert heft(fig51_dag()).priority == [0, 2, 5, 1, 3, 6, 4, 7]


def test_fig51_xeft_order_is_the_thesis_one():
    # Anchor 0 (CPU-only): every task descends from it, candidates {0} hold one kind: no cluster.
    # Anchor 1 (GPU-only): candidates 1, 4, 7 (mutually independent). GPU load 10/1 < CPU load
    # (7+5)/1 = 12, so the cluster starts with {1}; 4 joins (|10-7| < |10-0|), 7 joins
    # (|10-12| < |10-7|). APPLY over 1, 3, 6, 4, 7: 3 reaches 4 and 6 reaches 7, so they move
    # before the cluster: 0, 2, 5, 3, 6, 1, 4, 7 (thesis Fig. 5.2(c) and 5.3(d)).
    assert xeft_order(fig51_dag()) == [0, 2, 5, 3, 6, 1, 4, 7]


def test_fig51_heft_schedule_by_hand():
    # Order 0,2,5,1,3,6,4,7 (ties go to cpu0):
    # 0 cpu0 0-2; 2 gpu 2-4 (cpu0 would end at 6); 5 gpu 4-6 (cpu0: 10); 1 gpu 6-16 (the
    # 0-2 hole is too short); 3 cpu0 2-5 (gpu: 18); 6 cpu0 6-10 (gpu: 18); 4 cpu0 10-17 (the
    # 5-6 hole is too short); 7 cpu0 17-22. Makespan 22, GPU idle 16-22 (cf. Fig. 5.2(b)).
    dag = fig51_dag()
    s = heft(dag)
    validate_schedule(dag, s)
    assert spans(s) == {
        0: ("cpu0", 0, 2), 2: ("gpu", 2, 4), 5: ("gpu", 4, 6), 1: ("gpu", 6, 16),
        3: ("cpu0", 2, 5), 6: ("cpu0", 6, 10), 4: ("cpu0", 10, 17), 7: ("cpu0", 17, 22),
    }


def test_fig51_xeft_schedule_by_hand():
    # Order 0,2,5,3,6,1,4,7: 0 cpu0 0-2; 2 gpu 2-4; 5 gpu 4-6; 3 cpu0 2-5 (gpu: 8);
    # 6 gpu 6-8 (cpu0: 10); 1 gpu 8-18; 4 cpu0 5-12; 7 cpu0 12-17 (6 done at 8).
    # Makespan 18: 18% shorter than HEFT's 22 thanks to 1 overlapping 4 and 7.
    dag = fig51_dag()
    s = xeft(dag)
    validate_schedule(dag, s)
    assert spans(s) == {
        0: ("cpu0", 0, 2), 2: ("gpu", 2, 4), 5: ("gpu", 4, 6), 3: ("cpu0", 2, 5),
        6: ("gpu", 6, 8), 1: ("gpu", 8, 18), 4: ("cpu0", 5, 12), 7: ("cpu0", 12, 17),
    }
    assert s.makespan == 18


def test_best_picks_the_shorter():
    dag = fig51_dag()
    s = best(dag)
    validate_schedule(dag, s)
    assert (s.policy, s.info["chosen"], s.makespan) == ("best", "xeft", 18)


def gpu_heavy_dag():
    """Root r (both impls, 1 each) feeding independent sinks, 2 CPUs + 1 GPU, no transfers.

    (cpu, gpu): a (-, 9), b (8, 8), c (7, -), m (6, 6), d (5, -), e (-, 4); ranks are the mean
    costs (sinks): r 1+9=10, a 9, b 8, c 7, m 6, d 5, e 4, so HEFT's list is r a b c m d e.
    """
    tasks = {"r": (1, 1), "a": (None, 9), "b": (8, 8), "c": (7, None), "m": (6, 6),
             "d": (5, None), "e": (None, 4)}
    return cpu_gpu_dag(tasks, [("r", t) for t in "abcmde"], n_cpus=2)


def test_xeft_cpu_cluster_branch():
    # Anchor a: candidates a, c, d, e. GPU load (9+4)/1 = 13 >= CPU load (7+5)/2 = 6, so the
    # cluster is C = {c, d} (rows 22-26); a joins (|6-9| < |6-0|), e does not
    # (|6-13| > |6-9|). APPLY over a b c m d: b and m reach no member, they move after:
    # r a c d b m e. Anchor e (after the cluster): candidates {e}, one kind: no change.
    dag = gpu_heavy_dag()
    assert heft(dag).priority == ["r", "a", "b", "c", "m", "d", "e"]
    assert xeft_order(dag) == ["r", "a", "c", "d", "b", "m", "e"]


def test_xeft_cpu_cluster_schedule_by_hand():
    # HEFT, r a b c m d e: r cpu0 0-1; a gpu 1-10; b cpu0 1-9; c cpu1 1-8; m cpu1 8-14
    # (cpu0 15, gpu 16); d cpu0 9-14; e gpu 10-14. Makespan 14.
    # XEFT, r a c d b m e: r cpu0 0-1; a gpu 1-10; c cpu0 1-8; d cpu1 1-6; b cpu1 6-14
    # (cpu0 16, gpu 18); m cpu0 8-14 (gpu 16); e gpu 10-14. Makespan 14: a tie, best keeps HEFT.
    dag = gpu_heavy_dag()
    h, x, b = heft(dag), xeft(dag), best(dag)
    for s in (h, x, b):
        validate_schedule(dag, s)
    assert spans(h) == {"r": ("cpu0", 0, 1), "a": ("gpu", 1, 10), "b": ("cpu0", 1, 9),
                        "c": ("cpu1", 1, 8), "m": ("cpu1", 8, 14), "d": ("cpu0", 9, 14),
                        "e": ("gpu", 10, 14)}
    assert spans(x) == {"r": ("cpu0", 0, 1), "a": ("gpu", 1, 10), "c": ("cpu0", 1, 8),
                        "d": ("cpu1", 1, 6), "b": ("cpu1", 6, 14), "m": ("cpu0", 8, 14),
                        "e": ("gpu", 10, 14)}
    assert b.info["chosen"] == "heft" and b.makespan == 14


def test_no_exclusive_tasks_keeps_heft_order():
    dag = cpu_gpu_dag({"a": (3, 1), "b": (2, 2), "c": (1, 3)}, [("a", "b"), ("a", "c")], n_cpus=2)
    assert xeft_order(dag) == heft(dag).priority
    assert xeft(dag).makespan == heft(dag).makespan


def test_single_kind_candidates_make_no_cluster():
    # Only CPU-only exclusive tasks: Algorithm 1 finds no GPU task to balance with.
    dag = cpu_gpu_dag({"r": (1, 1), "p": (5, None), "q": (4, 4), "s": (3, None)},
                      [("r", "p"), ("r", "q"), ("r", "s")], n_cpus=2)
    assert xeft_order(dag) == heft(dag).priority == ["r", "p", "q", "s"]


def test_xeft_order_moves_dependent_tasks_before_the_cluster_in_order():
    # (cpu, gpu): r (1, 1), g (-, 10), x (0.2, 0.2), y (0.5, 0.5), c (9, -), z (1.5, 1.5);
    # r -> g, x, z; x -> y -> c. Ranks: c 9, y 9.5, x 9.7, g 10, z 1.5, r 1+10 = 11, so HEFT's
    # list is r g x y c z. Anchor g: candidates g, c; GPU load 10 >= CPU load 9, so cluster C =
    # {c}, and g joins (|9-10| < |9-0|). APPLY over g x y c: x and y reach c, so both move
    # before the cluster, x still before y: r x y g c z.
    tasks = {"r": (1, 1), "g": (None, 10), "x": (0.2, 0.2), "y": (0.5, 0.5), "c": (9, None),
             "z": (1.5, 1.5)}
    edges = [("r", "g"), ("r", "x"), ("r", "z"), ("x", "y"), ("y", "c")]
    dag = cpu_gpu_dag(tasks, edges, n_cpus=1)
    assert heft(dag).priority == ["r", "g", "x", "y", "c", "z"]
    assert xeft_order(dag) == ["r", "x", "y", "g", "c", "z"]
    for s in (heft(dag), xeft(dag)):
        validate_schedule(dag, s)


@pytest.mark.parametrize("shape", [
    ("linear", 150, 0.2, 0.8, (0.5, 2), 5, 7),
    ("linear", 45, 0.8, 0.8, (1, 4), 4, 8),
])
def test_xeft_keeps_the_shorter_of_mean_and_best_cost_ranks(shape):
    # On these DAGs Algorithm 1 on ranks from best costs ends first; the thesis' list (mean
    # costs) must lose to it, and the other way round XEFT would never be longer than it.
    kind, n, p_single, p_cpu, speedup, n_cpus, seed = shape
    dag = random_dag(n, kind, p_single=p_single, p_cpu_only=p_cpu, gpu_speedup=speedup,
                     n_cpus=n_cpus, seed=seed)
    problem = prepare(dag)
    thesis = _xeft_order(problem, _heft_order(problem))
    thesis_span = max(_place(problem, thesis)[2])
    s = xeft(dag)
    validate_schedule(dag, s)
    assert s.makespan < thesis_span
    assert s.priority == xeft_order(dag) != [problem.names[i] for i in thesis]
    assert best(dag).makespan == min(s.makespan, heft(dag).makespan)
