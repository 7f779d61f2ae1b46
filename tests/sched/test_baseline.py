"""The VisionWorks baseline (thesis §5.1): GPU when possible, serial, no overlap."""

from warpvx.sched import baseline, cpu_gpu_dag, overlap, validate_schedule

from .dags import TOPCUOGLU_COST, fig51_dag, spans, topcuoglu_dag


def test_smoke():
    s = baseline(fig51_dag())
    assert s.policy == "baseline"


def test_fig51_by_hand():
    # Rank order 0,2,5,1,3,6,4,7; GPU for every task with a GPU implementation (1, 2, 3, 5, 6),
    # CPU for 0, 4, 7; each starts when the previous one ends: makespan = 2+2+2+10+2+2+7+5 = 32
    # (cf. thesis Fig. 5.2(a)).
    dag = fig51_dag()
    s = baseline(dag)
    validate_schedule(dag, s)
    assert spans(s) == {
        0: ("cpu0", 0, 2), 2: ("gpu", 2, 4), 5: ("gpu", 4, 6), 1: ("gpu", 6, 16),
        3: ("gpu", 16, 18), 6: ("gpu", 18, 20), 4: ("cpu0", 20, 27), 7: ("cpu0", 27, 32),
    }
    assert overlap(s) == 0


def test_gpu_even_when_slower_and_pays_the_transfer():
    # b is faster on the CPU (1 vs 5) but has a GPU implementation: the baseline takes the GPU
    # and waits for a's data: a cpu0 0-1, b gpu 1+3=4 .. 9.
    dag = cpu_gpu_dag({"a": (1, None), "b": (1, 5)}, {("a", "b"): 3}, n_cpus=2)
    s = baseline(dag)
    validate_schedule(dag, s)
    assert spans(s) == {"a": ("cpu0", 0, 1), "b": ("gpu", 4, 9)}


def test_without_gpu_each_task_on_its_fastest_processor():
    dag = topcuoglu_dag()
    s = baseline(dag)
    validate_schedule(dag, s)
    assert overlap(s) == 0
    for t, costs in TOPCUOGLU_COST.items():
        assert s[t].finish - s[t].start == min(costs)
    assert s.makespan >= sum(min(costs) for costs in TOPCUOGLU_COST.values())
