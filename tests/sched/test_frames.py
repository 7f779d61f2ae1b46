"""Frames in flight: unrolling, frame-major order of every policy, validity, latency, period."""

import networkx as nx
import pytest

from warpvx.errors import ScheduleError, WarpvxValueError
from warpvx.sched import (
    POLICIES, cpu_gpu_dag, frame_times, heft, random_dag, schedule, unroll, validate_schedule,
    xeft_order,
)

from .dags import fig51_dag, topcuoglu_dag

# (kind, nodes, p_single, n_cpus, seed): a spread of generated DAGs, the delay from the last
# task to the root of the next frame (state carried between frames) or none.
CASES = [("tree", 30, 0.5, 2, 1), ("linear", 45, 0.8, 3, 2), ("tree", 60, 0.2, 4, 3),
         ("linear", 25, 0.5, 1, 4), ("tree", 40, 0.8, 2, 5)]


def _case(kind, n, p_single, n_cpus, seed):
    dag = random_dag(n, kind, p_single=p_single, n_cpus=n_cpus, seed=seed)
    delays = [(n - 1, 0)] if seed % 2 else []
    return dag, delays


def test_unroll_copies_and_links_frames():
    dag = fig51_dag()
    u = unroll(dag, 3, {(7, 0): 1.5})
    assert u.number_of_nodes() == 3 * dag.number_of_nodes()
    assert u.number_of_edges() == 3 * dag.number_of_edges() + 2
    assert u.nodes[(4, 2)]["frame"] == 2 and u.nodes[(4, 2)]["cost"] == dag.nodes[4]["cost"]
    assert u.edges[(7, 1), (0, 2)]["comm"] == 1.5
    assert not u.has_edge((7, 2), (0, 0)) and u.graph["frames"] == 3


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("policy", sorted(POLICIES))
def test_frames_valid_and_never_longer_than_back_to_back(case, policy):
    dag, delays = _case(*case)
    k = 4
    s = schedule(dag, policy, frames=k, delays=delays)
    validate_schedule(s.info["dag"], s)  # each copy's precedence, inter-frame edges, no overlap
    single = POLICIES[policy](dag).makespan
    assert s.makespan <= k * single * (1 + 1e-12)
    assert len(s.info["latency"]) == k and s.info["period"] > 0


@pytest.mark.parametrize("case", CASES)
@pytest.mark.parametrize("policy", ["heft", "xeft", "best", "baseline"])
def test_priority_is_frame_major(case, policy):
    dag, delays = _case(*case)
    u = unroll(dag, 3, delays)
    frames = [u.nodes[v]["frame"] for v in POLICIES[policy](u).priority]
    assert frames == sorted(frames)


def test_frames_overlap_beats_back_to_back_on_a_pipeline():
    # A CPU stage then a GPU stage: frames in flight overlap them, period = the slower stage.
    dag = cpu_gpu_dag({"a": (4, None), "b": (None, 3)}, [("a", "b", 0)], n_cpus=1)
    s = schedule(dag, "heft", frames=5)
    assert s.makespan == pytest.approx(4 * 5 + 3)
    assert s.info["period"] == pytest.approx(4) and s.info["latency"][0] == pytest.approx(7)


def test_frame_zero_is_scheduled_as_a_single_frame():
    dag = topcuoglu_dag()
    u = unroll(dag, 3, [(10, 1)])
    one, many = heft(dag), heft(u)
    for v in dag:
        assert (many[(v, 0)].processor, many[(v, 0)].finish) == (one[v].processor, one[v].finish)


def test_xeft_clusters_stay_in_one_frame():
    u = unroll(fig51_dag(), 2)
    frames = [u.nodes[v]["frame"] for v in xeft_order(u)]
    assert frames == sorted(frames)


def test_frame_times_match_the_schedule():
    dag, delays = _case(*CASES[1])
    u = unroll(dag, 3, delays)
    s = heft(u)
    t = frame_times(u, s)
    for f in range(3):
        mine = [s[v] for v in u if u.nodes[v]["frame"] == f]
        assert t.start[f] == min(x.start for x in mine) and t.finish[f] == max(x.finish for x in mine)
        assert t.latency[f] == pytest.approx(t.finish[f] - t.start[f])
    assert t.period == pytest.approx((t.finish[2] - t.finish[0]) / 2)


def test_bad_frames_raise():
    dag = fig51_dag()
    with pytest.raises(WarpvxValueError, match="frames"):
        unroll(dag, 0)
    with pytest.raises(ScheduleError, match="unknown task"):
        unroll(dag, 2, [(7, "nope")])
    with pytest.raises(ScheduleError, match="already unrolled"):
        unroll(unroll(dag, 2), 2)
    bad = unroll(dag, 2)
    bad.add_edge((1, 1), (4, 0))
    with pytest.raises(ScheduleError, match="back"):
        heft(bad)
    half = nx.DiGraph(dag)
    half.nodes[0]["frame"] = 0
    with pytest.raises(ScheduleError, match="no 'frame'"):
        heft(half)
    half.nodes[0]["frame"] = -1
    with pytest.raises(ScheduleError, match="int >= 0"):
        heft(half)
