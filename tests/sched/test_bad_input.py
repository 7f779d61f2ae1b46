"""Bad task graphs and schedules raise warpvx errors that name the problem."""

import math

import networkx as nx
import pytest

from warpvx.errors import ScheduleError, UnsupportedError, WarpvxTypeError, WarpvxValueError
from warpvx.sched import (
    POLICIES, Schedule, ScheduledTask, cpu_gpu_dag, heft, metrics, random_dag, schedule,
    upward_rank, validate_schedule,
)

from .dags import fig51_dag


def two_task_dag(cost_a=None, comm=1.0):
    dag = nx.DiGraph(processors=["cpu0", "gpu"])
    dag.add_node("a", cost={"cpu0": 1.0} if cost_a is None else cost_a)
    dag.add_node("b", cost={"cpu0": 2.0, "gpu": 1.0})
    dag.add_edge("a", "b", comm=comm)
    return dag


@pytest.mark.parametrize("policy", list(POLICIES))
def test_cycle(policy):
    dag = two_task_dag()
    dag.add_edge("b", "a", comm=0.0)
    with pytest.raises(ScheduleError, match="cycle"):
        schedule(dag, policy)


def test_self_loop_is_a_cycle():
    dag = two_task_dag()
    dag.add_edge("b", "b")
    with pytest.raises(ScheduleError, match="cycle.*'b'"):
        heft(dag)


@pytest.mark.parametrize("policy", list(POLICIES))
def test_task_no_processor_can_run(policy):
    with pytest.raises(ScheduleError, match="'a'.*no processor can run"):
        schedule(two_task_dag(cost_a={}), policy)


def test_cost_on_unknown_processor():
    with pytest.raises(ScheduleError, match="'a'.*unknown processor 'tpu'"):
        heft(two_task_dag(cost_a={"tpu": 1.0}))


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf, "3"])
def test_bad_cost(bad):
    with pytest.raises(ScheduleError, match="task 'a': cost on 'cpu0'"):
        heft(two_task_dag(cost_a={"cpu0": bad}))


@pytest.mark.parametrize("bad", [-0.5, math.nan])
def test_bad_comm(bad):
    with pytest.raises(ScheduleError, match=r"edge \('a', 'b'\): comm"):
        heft(two_task_dag(comm=bad))


def test_missing_cost_attribute():
    dag = two_task_dag()
    dag.add_node("c")
    with pytest.raises(ScheduleError, match="'c' has no 'cost'"):
        heft(dag)


@pytest.mark.parametrize("policy", list(POLICIES))
def test_empty_graph(policy):
    with pytest.raises(ScheduleError, match="empty graph"):
        schedule(nx.DiGraph(processors=["cpu0"]), policy)


def test_missing_processors():
    dag = nx.DiGraph()
    dag.add_node("a", cost={"cpu0": 1})
    with pytest.raises(ScheduleError, match="processors"):
        upward_rank(dag)


def test_memory_missing_a_processor():
    dag = two_task_dag()
    dag.graph["memory"] = {"cpu0": "host"}
    with pytest.raises(ScheduleError, match="memory.*'gpu'"):
        heft(dag)


def test_not_a_digraph():
    with pytest.raises(WarpvxTypeError, match="dag"):
        heft(nx.Graph())
    with pytest.raises(WarpvxTypeError, match="dag"):
        heft({"a": 1})


def test_unknown_policy():
    with pytest.raises(UnsupportedError, match="policy.*'fastest'"):
        schedule(fig51_dag(), "fastest")
    with pytest.raises(WarpvxTypeError, match="policy"):
        schedule(fig51_dag(), 3)


def test_cpu_gpu_dag_bad_input():
    with pytest.raises(ScheduleError, match=r"tasks\['x'\]: no processor"):
        cpu_gpu_dag({"x": (None, None)})
    with pytest.raises(ScheduleError, match=r"tasks\['x'\] cpu_time"):
        cpu_gpu_dag({"x": (-1, None)})
    with pytest.raises(ScheduleError, match="unknown task 'y'"):
        cpu_gpu_dag({"x": (1, None)}, {("x", "y"): 1})
    with pytest.raises(ScheduleError, match="cycle"):
        cpu_gpu_dag({"x": (1, None), "y": (1, 1)}, [("x", "y", 0), ("y", "x", 0)])
    with pytest.raises(WarpvxValueError, match="n_cpus"):
        cpu_gpu_dag({"x": (1, None)}, n_cpus=0)


def test_random_dag_bad_input():
    with pytest.raises(WarpvxValueError, match="n_nodes"):
        random_dag(1)
    with pytest.raises(UnsupportedError, match="kind"):
        random_dag(20, "star")
    with pytest.raises(WarpvxValueError, match="p_single"):
        random_dag(20, p_single=1.5)
    with pytest.raises(WarpvxValueError, match="gpu_speedup"):
        random_dag(20, gpu_speedup=(0, 2))
    with pytest.raises(WarpvxValueError, match="cpu_range"):
        random_dag(20, cpu_range=(50, 10))


def _valid():
    dag = fig51_dag()
    return dag, heft(dag)


def _with(s, task, **changes):
    t = s.tasks[task]
    fields = {"task": t.task, "processor": t.processor, "start": t.start, "finish": t.finish, **changes}
    tasks = dict(s.tasks)
    tasks[task] = ScheduledTask(**fields)
    return Schedule(tasks, s.processors, s.policy, s.priority)


def test_validate_catches_precedence():
    dag = cpu_gpu_dag({"a": (2, None), "b": (1, None)}, [("a", "b")], n_cpus=2)
    s = Schedule({"a": ScheduledTask("a", "cpu0", 0, 2), "b": ScheduledTask("b", "cpu1", 1, 2)},
                 ["cpu0", "cpu1", "gpu"])
    with pytest.raises(ScheduleError, match="task 'b' on 'cpu1' starts at 1, before its input from 'a'"):
        validate_schedule(dag, s)


def test_validate_catches_transfer_delay():
    dag = cpu_gpu_dag({"a": (1, None), "b": (5, 1)}, {("a", "b"): 3})
    s = Schedule({"a": ScheduledTask("a", "cpu0", 0, 1), "b": ScheduledTask("b", "gpu", 2, 3)},
                 ["cpu0", "gpu"])
    with pytest.raises(ScheduleError, match="transfer 3"):
        validate_schedule(dag, s)


def test_validate_catches_overlap():
    dag, s = _valid()  # 7 on cpu0 17-22; moved to 16-21 it overlaps 4 (10-17)
    with pytest.raises(ScheduleError, match="overlap on 'cpu0'"):
        validate_schedule(dag, _with(s, 7, start=16.0, finish=21.0))


def test_validate_catches_wrong_duration():
    dag, s = _valid()
    with pytest.raises(ScheduleError, match="task 7 on 'cpu0' runs 4.0"):
        validate_schedule(dag, _with(s, 7, finish=21.0))


def test_validate_catches_processor_that_cannot_run_the_task():
    dag, s = _valid()
    with pytest.raises(ScheduleError, match="task 7 is on 'gpu', which cannot run it"):
        validate_schedule(dag, _with(s, 7, processor="gpu"))


def test_validate_catches_missing_and_extra_tasks():
    dag, s = _valid()
    tasks = dict(s.tasks)
    del tasks[7]
    with pytest.raises(ScheduleError, match="task 7 of the dag is not scheduled"):
        validate_schedule(dag, Schedule(tasks, s.processors))
    tasks[7] = s.tasks[7]
    tasks[99] = ScheduledTask(99, "cpu0", 30, 31)
    with pytest.raises(ScheduleError, match="task 99 is not in the dag"):
        validate_schedule(dag, Schedule(tasks, s.processors))


def test_metrics_need_a_schedule():
    with pytest.raises(WarpvxTypeError, match="schedule"):
        metrics(fig51_dag(), {"a": 1})
