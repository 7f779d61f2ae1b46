"""K frames in flight: the executor runs a schedule of a DAG unrolled over K frames
(:func:`warpvx.sched.frames.unroll`) cyclically, frame i with the placement of frame i mod K.

Executor tests build Programs and K-frame Schedules by hand; graph tests schedule real graphs
with ``Graph.schedule(..., frames=K)`` and hold the outputs to the functional API on each
frame's placed backend (real clip frames, a graph with delays). Which processor ran a task is
recorded by the task itself (its thread's name), not read back from the executor.
"""

from __future__ import annotations

import threading

import networkx as nx
import numpy as np
import pytest

import warpvx
from warpvx.errors import NodeExecutionError, ScheduleError, WarpvxValueError
from warpvx.graph.data import zeros_like
from warpvx.runtime import HOST, Executor, ExecTask, InputRef, Program, Ring
from warpvx.sched.schedule import Schedule, ScheduledTask
from tests.images import clip_frames

from .test_run import _accumulator, _add_kernel, _failing_graph, assert_same, build, expected

pytestmark = pytest.mark.timeout(120)

PROCS = ["cpu0", "cpu1", "gpu"]


class Recorder:
    """(task, frame) -> the processor whose thread ran it (executor threads are named
    ``warpvx-<name>-<processor>``); a task learns its frame from its input ``x``."""

    def __init__(self):
        self.ran = {}
        self._lock = threading.Lock()

    def __call__(self, task, x):
        proc = threading.current_thread().name.rsplit("-", 1)[-1]
        with self._lock:
            self.ran[task, int(np.asarray(x).reshape(-1)[0])] = proc


def ksched(order: list) -> Schedule:
    """A K-frame schedule: ``(task, frame, processor)`` in order (times only order them)."""
    return Schedule({(t, f): ScheduledTask((t, f), p, i, i + 1) for i, (t, f, p) in enumerate(order)},
                    PROCS)


def accumulator(rec: Recorder, fail_at: int | None = None) -> Program:
    """a = x + a[-1] (init 100), b = 2 a; both record where they ran; ``a`` raises when
    ``x == fail_at``."""
    import warp as wp

    def a_cpu(x, prev):
        rec("a", x)
        if fail_at is not None and int(x[0]) == fail_at:
            raise KeyError(f"frame {fail_at}")
        return x + prev

    def a_gpu(x, prev):
        rec("a", x.numpy())
        return wp.array(x.numpy() + prev.numpy(), dtype=wp.float32, device=x.device)

    def b_cpu(x, a):
        rec("b", x)
        return a * 2

    tasks = {
        "a": ExecTask("a", (InputRef("x"), InputRef("a", -1)), ("a",), a_cpu, a_gpu),
        "b": ExecTask("b", (InputRef("x"), InputRef("a")), ("b",), b_cpu),
    }
    return Program(tasks, ("x",), {"a": "a", "b": "b"}, {"a": Ring(1, np.full(3, 100, np.float32))})


#: Frame 0: a on the GPU, b on cpu0; frame 1: a on cpu1, b on cpu0 before it; the delay
#: (a of frame 0 -> a of frame 1) crosses from the device to the host.
ALTERNATING = [("a", 0, "gpu"), ("b", 0, "cpu0"), ("a", 1, "cpu1"), ("b", 1, "cpu0")]


def _x(i):
    return {"x": (np.full(3, i, np.float32), HOST)}


def _sums(n):
    return 100 + np.cumsum(np.arange(n))


@pytest.mark.parametrize("together", [True, False], ids=["K-in-flight", "one-at-a-time"])
def test_alternating_placement_is_followed_and_delays_cross_processors(together):
    rec = Recorder()
    ex = Executor(ksched(ALTERNATING), accumulator(rec), gpu_device="cpu", name="alt")
    assert ex.frames == 2 and not ex.capture
    try:
        n = 7  # not a multiple of K: the last cycle is partial
        if together:
            frames = [ex.submit(i, _x(i)) for i in range(n)]
            results = [ex.wait(f) for f in frames]
        else:
            results = [ex.wait(ex.submit(i, _x(i))) for i in range(n)]
    finally:
        ex.close()
    sums = _sums(n)
    for i, r in enumerate(results):
        np.testing.assert_array_equal(r.outputs["a"], np.full(3, sums[i], np.float32))
        np.testing.assert_array_equal(r.outputs["b"], np.full(3, 2 * sums[i], np.float32))
        want = {t: p for t, f, p in ALTERNATING if f == i % 2}
        assert {t: rec.ran[t, i] for t in "ab"} == want, i
        assert {t: s.processor for t, s in r.timeline.items()} == want, i


def test_k_frame_order_interleaves_frames_on_a_processor():
    """cpu0 runs b of frame 1 before b of frame 0 when the schedule says so (b of frame 1
    reads nothing of frame 0)."""
    order = [("a", 0, "cpu1"), ("a", 1, "cpu1"), ("b", 1, "cpu0"), ("b", 0, "cpu0")]
    seen = []
    prog = accumulator(Recorder())
    b = prog.tasks["b"].cpu
    prog.tasks["b"].cpu = lambda x, a: (seen.append(int(x[0])), b(x, a))[1]
    ex = Executor(ksched(order), prog, gpu_device="cpu", name="order")
    try:
        frames = [ex.submit(i, _x(i)) for i in range(4)]
        outs = [float(ex.wait(f).outputs["b"][0]) for f in frames]
    finally:
        ex.close()
    assert seen == [1, 0, 3, 2]
    assert outs == list(map(float, 2 * _sums(4)))


def test_one_frame_unrolled_schedule_is_the_plain_one():
    plain = Schedule({t: ScheduledTask(t, p, i, i + 1) for i, (t, _, p) in
                      enumerate([("a", 0, "gpu"), ("b", 0, "cpu0")])}, PROCS)
    runs = []
    for s in (plain, ksched([("a", 0, "gpu"), ("b", 0, "cpu0")])):
        ex = Executor(s, accumulator(Recorder()), gpu_device="cpu", name="k1", capture=True)
        try:
            assert ex.frames == 1 and ex.capture
            runs.append(([[t.name for t in ex.queues[p]] for p in PROCS],
                         [float(ex.wait(ex.submit(i, _x(i))).outputs["b"][0]) for i in range(3)]))
        finally:
            ex.close()
    assert runs[0] == runs[1]
    assert runs[0][1] == list(map(float, 2 * _sums(3)))


def test_bad_k_frame_schedules_are_refused():
    prog = accumulator(Recorder())
    with pytest.raises(ScheduleError, match=r"\('b', 1\)\] are not scheduled"):
        Executor(ksched(ALTERNATING[:3]), prog, gpu_device="cpu")
    with pytest.raises(ScheduleError, match=r"\('b', 0\) is placed on 'gpu' but has no GPU"):
        Executor(ksched([("a", 0, "cpu0"), ("b", 0, "gpu"), ("a", 1, "cpu1"), ("b", 1, "cpu0")]),
                 prog, gpu_device="cpu")
    # a of frame 1 reads a of frame 0 through the delay: running it first on cpu0 would wait forever.
    with pytest.raises(ScheduleError, match="deadlock"):
        Executor(ksched([("a", 1, "cpu0"), ("a", 0, "cpu0"), ("b", 0, "cpu1"), ("b", 1, "cpu1")]),
                 prog, gpu_device="cpu")


@pytest.mark.timeout(30)
def test_failure_cancels_later_frames_and_earlier_ones_complete():
    rec = Recorder()
    order = [("a", 0, "cpu0"), ("b", 0, "cpu1"), ("a", 1, "cpu1"), ("b", 1, "cpu0")]
    ex = Executor(ksched(order), accumulator(rec, fail_at=3), gpu_device="cpu", name="fail")
    try:
        frames = [ex.submit(i, _x(i)) for i in range(6)]
        sums = _sums(3)
        for i in range(3):
            np.testing.assert_array_equal(ex.wait(frames[i]).outputs["a"], np.full(3, sums[i]))
        with pytest.raises(NodeExecutionError, match=r"node 'a' on cpu1 failed in frame 3") as info:
            ex.wait(frames[3])
        assert isinstance(info.value.__cause__, KeyError)
        for f in frames[4:]:
            with pytest.raises(NodeExecutionError, match="cancelled after frame 3"):
                ex.wait(f)
        ex.abort()
        assert ex.in_flight == 0
        # The executor runs on: frame 6 reads the last completed value (frame 2's).
        out = ex.wait(ex.submit(6, _x(6))).outputs["a"]
        np.testing.assert_array_equal(out, np.full(3, sums[2] + 6, np.float32))
    finally:
        ex.close()


@pytest.mark.timeout(30)
def test_wait_and_abort_release_processors_waiting_for_frames_that_never_come():
    # cpu0 runs b of frame 1 before b of frame 0: frame 0 alone finishes only because
    # waiting for it (or aborting) closes its cycle.
    order = [("a", 0, "cpu1"), ("a", 1, "cpu1"), ("b", 1, "cpu0"), ("b", 0, "cpu0")]
    ex = Executor(ksched(order), accumulator(Recorder()), gpu_device="cpu", name="abort")
    try:
        np.testing.assert_array_equal(ex.wait(ex.submit(0, _x(0))).outputs["b"], np.full(3, 200))
        f2 = ex.submit(2, _x(2))
        ex.abort()
        assert f2.finished.is_set() and ex.in_flight == 0
        out = ex.wait(ex.submit(4, _x(4))).outputs
        np.testing.assert_array_equal(out["b"], 2 * out["a"])
    finally:
        ex.close()


# --------------------------------------------------------------------------- graphs


@pytest.fixture(scope="module")
def clip():
    return clip_frames(7, size=(160, 96))


def alternating(dag):
    """A policy: a node of an even frame on cpu0 (or the GPU if it cannot run there), of an
    odd frame on the GPU (or cpu1), one task at a time: placements alternate every frame."""
    tasks, clock = {}, 0.0
    for v in nx.topological_sort(dag):
        cost = dag.nodes[v]["cost"]
        first, other = ("gpu", "cpu1") if dag.nodes[v].get("frame", 0) % 2 else ("cpu0", "gpu")
        p = first if first in cost else other
        start = max([clock] + [tasks[u].finish + dag.edges[u, v].get("comm", 0.0)
                               for u in dag.predecessors(v)])
        tasks[v] = ScheduledTask(v, p, start, start + cost[p])
        clock = tasks[v].finish
    return Schedule(tasks, list(dag.graph["processors"]), policy="alternating")


@pytest.mark.parametrize("policy", ["heft", "baseline", alternating], ids=["heft", "baseline", "alternating"])
def test_stream_of_k_frame_plan_equals_functional_api(clip, warp_backend, policy):
    g = build(clip)
    try:
        k = 3
        plan = g.schedule(policy, n_cpus=2, gpu=warp_backend, frames=k)
        ksch = plan.frame_schedule
        assert set(ksch.tasks) == {(v, f) for v in g.nodes for f in range(k)}
        assert len(ksch.info["latency"]) == k and ksch.info["period"] > 0

        def placement(i):
            return {v: ksch.tasks[v, i % k].processor for v in g.nodes}

        want = expected(placement, clip, zeros_like(g.data["harris.out"].sample), gpu=warp_backend)
        if policy is alternating:  # the backends of a node change from frame to frame
            assert placement(0)["lk"] == "cpu0" and placement(1)["lk"] == "gpu"
        got = list(g.stream({"frame": f} for f in clip))  # depth defaults to K
        assert len(got) == len(clip)
        for i in range(len(clip)):
            for key in want[i]:
                assert_same(got[i][key], want[i][key], f"frame {i} {key}")
        runs = list(plan.last_run)
        assert [r.index for r in runs] == list(range(len(clip)))
        for i, r in enumerate(runs):
            assert {v: t.processor for v, t in r.timeline.items()} == placement(i)
        # process() runs the same plan, one frame at a time; frame numbers run on across
        # reset(), so these frames take the slots after the stream's.
        g.reset()
        outs = [g.process({"frame": frame}) for frame in clip[:3]]
        first = plan.last_run[-1].index - 2
        want = expected(lambda i: placement(first + i), clip[:3],
                        zeros_like(g.data["harris.out"].sample), gpu=warp_backend)
        for i, out in enumerate(outs):
            for key in want[i]:
                assert_same(out[key], want[i][key], f"process {i} {key}")
    finally:
        g.close()


def test_graph_follows_an_alternating_k_frame_schedule(warp_backend):
    import warp as wp

    rec = Recorder()
    g = warpvx.Graph("alt")
    x = g.input("x", shape=(3,), dtype=np.float32)
    acc = g.virtual("acc")
    d = g.delay(acc, init=np.full(3, 100, np.float32))

    def sum_cpu(x, prev):
        rec("sum", x)
        return x + prev

    def sum_gpu(x, prev):
        rec("sum", x.numpy())
        out = wp.empty_like(x)
        wp.launch(_add_kernel, dim=x.shape, inputs=[x, prev], outputs=[out], device=x.device)
        return out

    def twice(x, a):
        rec("twice", x)
        return a * 2

    g.user(sum_cpu, [x, d[-1]], [acc], warp_fn=sum_gpu, name="sum")
    g.output("acc", acc)
    g.output("twice", g.user(twice, [x, acc], name="twice"))
    try:
        plan = g.schedule(alternating, n_cpus=2, gpu=warp_backend, frames=2)
        n = 5
        got = list(g.stream(({"x": np.full(3, i, np.float32)} for i in range(n)), depth=2))
    finally:
        g.close()
    sums = _sums(n)
    assert [float(o["acc"][0]) for o in got] == list(map(float, sums))
    assert [float(o["twice"][0]) for o in got] == list(map(float, 2 * sums))
    for i in range(n):
        want = {v: plan.frame_schedule.tasks[v, i % 2].processor for v in ("sum", "twice")}
        assert want == {"sum": "gpu" if i % 2 else "cpu0", "twice": f"cpu{i % 2}"}
        assert {v: rec.ran[v, i] for v in ("sum", "twice")} == want, i


@pytest.mark.parametrize("gpu_node", [False, True], ids=["cpu", "gpu"])
def test_delays_two_frames_back_read_the_right_frames(gpu_node):
    g, _ = _accumulator(gpu_node, slots=2)
    try:
        g.schedule("heft", n_cpus=2, gpu="warp-cpu", frames=3)
        got = list(g.stream({"x": np.full(3, i, np.float32)} for i in range(1, 8)))
    finally:
        g.close()
    sums = 100 + np.cumsum(np.arange(1, 8))
    assert [float(o["acc"][0]) for o in got] == list(map(float, sums))
    assert [float(o["past1"][0]) for o in got] == [100.0] + list(map(float, sums[:-1]))
    assert [float(o["past2"][0]) for o in got] == [100.0, 100.0] + list(map(float, sums[:-2]))


@pytest.mark.timeout(60)
def test_k_frame_stream_errors_and_closing_reach_the_caller():
    g = _failing_graph(3.0, frames=2)
    xs = [np.full(4, i, np.float32) for i in range(8)]
    got = []
    with pytest.raises(NodeExecutionError, match="node 'check'") as info:
        for out in g.stream({"x": x} for x in xs):
            got.append(float(out["y"][0]))
    assert got == [i * 2 + i + 1 for i in range(3)]
    assert isinstance(info.value.__cause__, ValueError)
    assert g.plan.executor().in_flight == 0
    assert len(list(g.stream({"x": x} for x in xs[4:]))) == 4  # runs on from a clean state
    it = g.stream({"x": np.full(4, i, np.float32)} for i in range(100))
    next(it)
    it.close()
    assert g.plan.executor().in_flight == 0
    with pytest.raises(NodeExecutionError, match="node 'check'"):
        g.process({"x": np.full(4, 3, np.float32)})
    g.close()


def test_frames_argument_is_checked_and_one_frame_is_the_plain_plan():
    g = _failing_graph(-1.0)
    assert g.plan.frame_schedule is None and g.plan.executor().frames == 1
    with pytest.raises(WarpvxValueError, match="frames"):
        g.schedule("heft", n_cpus=2, gpu="warp-cpu", frames=0)
    g.close()
