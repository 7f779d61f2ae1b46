"""HEFT: Topcuoglu et al. 2002's example, and the memory-space communication model."""

import pytest

from warpvx.sched import POLICIES, cpu_gpu_dag, heft, schedule, upward_rank, validate_schedule

from .dags import TOPCUOGLU_ORDER, TOPCUOGLU_RANK, spans, topcuoglu_dag


def test_smoke():
    s = heft(topcuoglu_dag())
    assert s.policy == "heft"
    assert set(s.tasks) == set(range(1, 11))


def test_topcuoglu_upward_ranks():
    ranks = upward_rank(topcuoglu_dag())
    assert ranks == pytest.approx(TOPCUOGLU_RANK, abs=1e-3)


def test_topcuoglu_priority_list():
    # n3 and n4 tie at 80.000; the paper lists n3 first (node order breaks the tie).
    assert heft(topcuoglu_dag()).priority == TOPCUOGLU_ORDER


def test_topcuoglu_makespan_is_80():
    dag = topcuoglu_dag()
    s = heft(dag)
    validate_schedule(dag, s)
    assert s.makespan == pytest.approx(80.0)


def test_topcuoglu_schedule_of_the_paper():
    # Fig. 4(a) of the paper: HEFT's schedule of the Fig. 2 DAG.
    expected = {
        1: ("P3", 0, 9), 3: ("P3", 9, 28), 4: ("P2", 18, 26), 2: ("P1", 27, 40),
        5: ("P3", 28, 38), 6: ("P2", 26, 42), 9: ("P2", 56, 68), 7: ("P3", 38, 49),
        8: ("P1", 57, 62), 10: ("P2", 73, 80),
    }
    assert spans(heft(topcuoglu_dag())) == expected


def test_memory_model_rank_uses_share_of_cross_space_pairs():
    # a runs on cpu0 only, b on cpu0 or gpu. Pairs (cpu0, cpu0) share memory, (cpu0, gpu) do
    # not: mean comm = 5 * 1/2 = 2.5. rank(b) = mean(10, 2) = 6, rank(a) = 1 + 2.5 + 6 = 9.5.
    dag = cpu_gpu_dag({"a": (1, None), "b": (10, 2)}, {("a", "b"): 5}, n_cpus=1)
    assert upward_rank(dag) == pytest.approx({"a": 9.5, "b": 6.0})


@pytest.mark.parametrize(
    "transfer, expected_b",
    [
        # b on gpu: ready 1 + 5 = 6, finish 8 < 11 on cpu0.
        (5, ("gpu", 6, 8)),
        # b on gpu: ready 1 + 10 = 11, finish 13 > 11 on cpu0 (no transfer within host memory).
        (10, ("cpu0", 1, 11)),
    ],
)
def test_transfer_paid_only_across_memory_spaces(transfer, expected_b):
    dag = cpu_gpu_dag({"a": (1, None), "b": (10, 2)}, {("a", "b"): transfer}, n_cpus=1)
    s = heft(dag)
    validate_schedule(dag, s)
    assert spans(s)["b"] == expected_b


def test_no_transfer_between_cpus_sharing_host_memory():
    # All tasks CPU-only: every processor pair shares host memory, so mean comm is 0 and no
    # transfer is paid. Ranks a=4+6=10, b=6, c=3. a: cpu0 0..4; b: cpu0 4..10 (tie with cpu1,
    # first wins); c: cpu1 4..7 despite comm 100 (it would start at 104 in Topcuoglu's model).
    dag = cpu_gpu_dag({"a": (4, None), "b": (6, None), "c": (3, None)},
                      {("a", "b"): 100, ("a", "c"): 100}, n_cpus=2)
    s = heft(dag)
    validate_schedule(dag, s)
    assert spans(s) == {"a": ("cpu0", 0, 4), "b": ("cpu0", 4, 10), "c": ("cpu1", 4, 7)}


def test_schedule_by_name_and_callable():
    dag = topcuoglu_dag()
    assert schedule(dag, "HEFT").makespan == pytest.approx(80.0)
    assert schedule(dag, heft).makespan == pytest.approx(80.0)
    assert set(POLICIES) == {"baseline", "heft", "xeft", "best"}
