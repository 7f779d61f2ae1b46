"""The executor on hand-built schedules: order, cross-queue edges, pipelining, errors, deadlock
detection. No graph involved: Programs and Schedules are built by hand."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from warpvx.backend import cuda_available
from warpvx.errors import NodeExecutionError, ScheduleError
from warpvx.runtime import (
    DEVICE,
    HOST,
    Executor,
    ExecTask,
    InputRef,
    Program,
    Ring,
    run_schedule,
)
from warpvx.sched.schedule import Schedule, ScheduledTask

pytestmark = pytest.mark.timeout(60)

PROCS = ["cpu0", "cpu1", "gpu"]


#: Scheduled task durations (ms): long ones run on their own processor's thread, short ones
#: may run inline on the thread whose output they waited for (Executor.INLINE_MAX_MS).
LONG, SHORT = 1.0, 0.001


def sched(placement: dict, order=None, ms: float = LONG) -> Schedule:
    """A schedule placing tasks in the given order, each ``ms`` long (times only order them,
    and say which tasks may run inline)."""
    order = order or list(placement)
    return Schedule({t: ScheduledTask(t, placement[t], i * ms, (i + 1) * ms)
                     for i, t in enumerate(order)}, PROCS)


def _wp_add(a, b):
    import warp as wp

    return wp.array(a.numpy() + b.numpy(), dtype=wp.float32, device=a.device)


def diamond():
    """x -> a (x+1), b (x*2) -> c (a+b) -> d (c-1)."""
    import warp as wp

    def on_gpu(fn):
        return lambda *vs: wp.array(fn(*[v.numpy() for v in vs]), dtype=wp.float32, device=vs[0].device)

    fa, fb, fc, fd = (lambda x: x + 1), (lambda x: x * 2), (lambda a, b: a + b), (lambda c: c - 1)
    tasks = {
        "a": ExecTask("a", (InputRef("x"),), ("a",), fa, on_gpu(fa)),
        "b": ExecTask("b", (InputRef("x"),), ("b",), fb, on_gpu(fb)),
        "c": ExecTask("c", (InputRef("a"), InputRef("b")), ("c",), fc, on_gpu(fc)),
        "d": ExecTask("d", (InputRef("c"),), ("d",), fd, on_gpu(fd)),
    }
    return Program(tasks, ("x",), {"out": "d", "a": "a"})


@pytest.mark.parametrize("placement", [
    {"a": "cpu0", "b": "cpu1", "c": "cpu0", "d": "cpu1"},
    {"a": "gpu", "b": "cpu0", "c": "gpu", "d": "cpu1"},
    {"a": "gpu", "b": "gpu", "c": "gpu", "d": "gpu"},
    {"a": "cpu1", "b": "gpu", "c": "cpu0", "d": "gpu"},
])
def test_hand_built_schedule_runs_and_records_times(placement):
    x = np.arange(5, dtype=np.float32)
    res = run_schedule(sched(placement), diamond(), {"x": (x, HOST)}, gpu_device="cpu")
    np.testing.assert_array_equal(res.outputs["out"], (x + 1) + (x * 2) - 1)
    assert isinstance(res.outputs["out"], np.ndarray)
    tl = res.timeline
    assert {t: s.processor for t, s in tl.items()} == placement
    for u, v in [("a", "c"), ("b", "c"), ("c", "d")]:
        assert tl[v].start >= tl[u].finish - 1e-6, (u, v, tl)
    assert all(0 <= s.start <= s.finish for s in tl.values())
    assert res.makespan == max(s.finish for s in tl.values())


def test_device_input_reaches_gpu_and_cpu_consumers():
    import warp as wp

    x = np.arange(4, dtype=np.float32)
    xd = wp.array(x, dtype=wp.float32, device="cpu")
    res = run_schedule(sched({"a": "gpu", "b": "cpu0", "c": "cpu1", "d": "gpu"}), diamond(),
                       {"x": (xd, DEVICE)}, gpu_device="cpu")
    np.testing.assert_array_equal(res.outputs["out"], 3 * x)


def test_orders_contradicting_dependencies_are_refused():
    # c before a on cpu0, but c needs a: running it would wait forever.
    s = sched({"a": "cpu0", "b": "cpu1", "c": "cpu0", "d": "cpu1"}, order=["c", "b", "a", "d"])
    with pytest.raises(ScheduleError, match="deadlock"):
        Executor(s, diamond(), gpu_device="cpu")


def test_bad_schedules_are_refused():
    prog = diamond()
    s = sched({"a": "cpu0", "b": "cpu1", "c": "cpu0"})
    with pytest.raises(ScheduleError, match=r"tasks \['d'\] are not scheduled"):
        Executor(s, prog, gpu_device="cpu")
    prog.tasks["d"].gpu = None
    s = sched({"a": "cpu0", "b": "cpu1", "c": "cpu0", "d": "gpu"})
    with pytest.raises(ScheduleError, match="'d' is placed on 'gpu' but has no GPU"):
        Executor(s, prog, gpu_device="cpu")
    prog = diamond()
    with pytest.raises(ScheduleError, match="no gpu_device"):
        Executor(s, prog)
    s = sched({"a": "cpu0", "b": "cpu1", "c": "cpu0", "d": "cpu1", "e": "cpu0"})
    with pytest.raises(ScheduleError, match="unknown task 'e'"):
        Executor(s, prog)


@pytest.mark.timeout(20)
@pytest.mark.parametrize("ms", [LONG, SHORT])
@pytest.mark.parametrize("where", ["cpu0", "gpu"])
def test_error_cancels_frame_and_consumers_on_other_processors_do_not_hang(where, ms):
    prog = diamond()

    def boom(x):
        raise KeyError("nope")

    if where == "gpu":
        prog.tasks["a"].gpu = boom
    else:
        prog.tasks["a"].cpu = boom
    placement = {"a": where, "b": "cpu1", "c": "cpu1", "d": "cpu1"}
    ex = Executor(sched(placement, ms=ms), prog, gpu_device="cpu")
    x = np.zeros(3, np.float32)
    f0 = ex.submit(0, {"x": (x, HOST)})
    f1 = ex.submit(1, {"x": (x, HOST)})
    with pytest.raises(NodeExecutionError, match=rf"node 'a' on {where} failed in frame 0") as info:
        ex.wait(f0)
    assert isinstance(info.value.__cause__, KeyError)
    # Frame 1 failed too (its own 'a' raises) or was cancelled; either way no hang.
    with pytest.raises(NodeExecutionError):
        ex.wait(f1)
    ex.abort()
    assert ex.in_flight == 0
    ex.close()


def test_pipelined_frames_overlap_across_processors():
    """Stage A (cpu0) of frame i+1 runs while stage B (cpu1) of frame i does."""
    def stage(v):
        time.sleep(0.02)  # releases the GIL, as OpenCV does
        return v + 1

    prog = Program({
        "A": ExecTask("A", (InputRef("x"),), ("a",), stage),
        "B": ExecTask("B", (InputRef("a"),), ("b",), stage),
    }, ("x",), {"b": "b"})
    ex = Executor(sched({"A": "cpu0", "B": "cpu1"}), prog)
    frames = [ex.submit(i, {"x": (np.float32(i), HOST)}) for i in range(4)]
    results = [ex.wait(f) for f in frames]
    ex.close()
    assert [float(r.outputs["b"]) for r in results] == [2.0, 3.0, 4.0, 5.0]

    def absolute(r, task):
        t = r.timeline[task]
        return r.t0 + t.start / 1e3, r.t0 + t.finish / 1e3

    for prev, nxt in zip(results, results[1:]):
        a_start, _ = absolute(nxt, "A")
        _, b_finish = absolute(prev, "B")
        assert a_start < b_finish  # overlap: the pipeline, not one frame after another


@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_ring_reads_wait_for_the_previous_frames_producer(ms):
    """acc_i = acc_{i-1} + x_i with a slow producer: frame i's read waits for frame i-1."""
    def slow_add(x, prev):
        time.sleep(0.005)
        return x + prev

    ring = Ring(1, np.float32(0))
    prog = Program({
        "acc": ExecTask("acc", (InputRef("x"), InputRef("acc", -1)), ("acc",), slow_add),
        "copy": ExecTask("copy", (InputRef("acc"),), ("out",), lambda v: v),
    }, ("x",), {"out": "out"}, rings={"acc": ring})
    ex = Executor(sched({"acc": "cpu0", "copy": "cpu1"}, ms=ms), prog)
    frames = [ex.submit(i, {"x": (np.float32(i + 1), HOST)}) for i in range(6)]
    got = [float(ex.wait(f).outputs["out"]) for f in frames]
    ex.close()
    assert got == [1.0, 3.0, 6.0, 10.0, 15.0, 21.0]
    assert float(ring.get(ring.last_aged).value) == 21.0


def test_closed_executor_refuses_frames():
    ex = Executor(sched({"a": "cpu0", "b": "cpu0", "c": "cpu0", "d": "cpu0"}), diamond())
    ex.close()
    with pytest.raises(RuntimeError, match="closed"):
        ex.submit(0, {"x": (np.zeros(1, np.float32), HOST)})


def test_zero_cost_ties_run_in_dependency_order():
    # a and c both "start" at 0 on cpu0 (zero-cost tasks): c needs a, so a runs first.
    s = Schedule({"a": ScheduledTask("a", "cpu0", 0.0, 0.0), "c": ScheduledTask("c", "cpu0", 0.0, 0.0),
                  "b": ScheduledTask("b", "cpu1", 0.0, 1.0), "d": ScheduledTask("d", "cpu1", 1.0, 2.0)},
                 PROCS)
    s.tasks = {k: s.tasks[k] for k in ("c", "b", "a", "d")}  # the tie listed the wrong way round
    x = np.ones(2, np.float32)
    res = run_schedule(s, diamond(), {"x": (x, HOST)})
    np.testing.assert_array_equal(res.outputs["out"], 3 * x)


def _alternating(n: int):
    """x -> t0 (CPU, +1) -> t1 (GPU, *2) -> t2 (CPU, +1) -> ...; each callable records the
    thread that ran it."""
    import threading

    import warp as wp

    ran = []

    def cpu(v):
        ran.append(("cpu", threading.current_thread()))
        return v + 1

    def gpu(v):
        ran.append(("gpu", threading.current_thread()))
        return wp.array(v.numpy() * 2, dtype=wp.float32, device=v.device)

    tasks, prev = {}, "x"
    for i in range(n):
        tasks[f"t{i}"] = ExecTask(f"t{i}", (InputRef(prev),), (f"v{i}",), cpu, gpu)
        prev = f"v{i}"
    placement = {f"t{i}": "gpu" if i % 2 else "cpu0" for i in range(n)}
    return Program(tasks, ("x",), {"y": prev}), placement, ran


def _expected(x, n):
    for i in range(n):
        x = x * 2 if i % 2 else x + 1
    return x


@pytest.mark.parametrize("device", ["cpu"] + (["cuda:0"] if cuda_available() else []))
@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_alternating_chain_runs_short_tasks_inline_and_long_ones_on_their_threads(ms, device):
    """Short tasks of a CPU/GPU chain run on the thread whose output they wait for (no
    wake-up per hand-off); long ones on their own processor's thread; outputs and the order
    of pipelined frames are the same either way (on CUDA, through staged downloads)."""
    n = 8
    prog, placement, ran = _alternating(n)
    ex = Executor(sched(placement, ms=ms), prog, gpu_device=device)
    try:
        xs = [np.full(3, i, np.float32) for i in range(6)]
        frames = [ex.submit(i, {"x": (x, HOST)}) for i, x in enumerate(xs)]
        for x, f in zip(xs, frames):
            res = ex.wait(f)
            np.testing.assert_array_equal(res.outputs["y"], _expected(x, n))
            assert {t: s.processor for t, s in res.timeline.items()} == placement
        threads = {p: ex._threads[p] for p in ("cpu0", "gpu")}
        if device != "cpu":  # GPU -> CPU edges were staged in the pool, each at most once
            pool = ex._roles["gpu"].state.io.pool
            assert 0 < pool.allocated <= len(xs) * (n // 2) * xs[0].nbytes
    finally:
        ex.close()
    # The caller's thread may run units too, as a role's thread, while it waits for the last
    # frame alone in flight (Executor._help): not "elsewhere".
    caller = threading.current_thread()
    elsewhere = sum(th is not threads["cpu0" if kind == "cpu" else "gpu"] and th is not caller
                    for kind, th in ran)
    if ms == LONG:
        assert elsewhere == 0
    else:  # mostly inline (a thread woken by its wait's time-out may take a task now and then)
        assert elsewhere >= len(ran) // 4


@pytest.mark.timeout(30)
@pytest.mark.parametrize("kind", ["cpu", "gpu"])
@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_alternating_chain_failing_mid_chain_reports_the_node_and_runs_the_next_frames(ms, kind):
    """A task of the alternating chain raising in frame 1 (inline or on its thread): that
    frame's wait names it, the frame behind it in flight is cancelled, and later frames run
    the whole chain again (no role is left holding a token or a stale position)."""
    n = 8
    prog, placement, _ = _alternating(n)
    bad = "t3" if kind == "gpu" else "t4"  # mid-chain: units before it ran inline
    task = prog.tasks[bad]
    good = getattr(task, kind)

    def flaky(v):
        if flaky.frame == 1:
            raise ValueError("frame 1 fails")
        return good(v)

    flaky.frame = 0
    setattr(task, kind, flaky)
    ex = Executor(sched(placement, ms=ms), prog, gpu_device="cpu")
    try:
        x = np.full(3, 2, np.float32)
        res = ex.wait(ex.submit(0, {"x": (x, HOST)}))
        np.testing.assert_array_equal(res.outputs["y"], _expected(x, n))
        flaky.frame = 1
        f1 = ex.submit(1, {"x": (x, HOST)})
        f2 = ex.submit(2, {"x": (x + 1, HOST)})
        with pytest.raises(NodeExecutionError, match=rf"node '{bad}' on {placement[bad]} failed "
                                                     r"in frame 1") as info:
            ex.wait(f1)
        assert isinstance(info.value.__cause__, ValueError)
        with pytest.raises(NodeExecutionError, match="frame 2 was cancelled after frame 1"):
            ex.wait(f2)
        flaky.frame = 3
        for i in (3, 4):  # one at a time (run inline by the caller), then two in flight
            frames = [ex.submit(i * 10 + j, {"x": (x + j, HOST)}) for j in range(i - 2)]
            for j, f in enumerate(frames):
                np.testing.assert_array_equal(ex.wait(f).outputs["y"], _expected(x + j, n))
        assert ex.in_flight == 0
    finally:
        ex.close()


@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_only_a_sole_host_reader_downloads_without_a_copy_lock(ms):
    """Slot.host reads lock-free for a CPU task alone in reading its inputs on the host:
    not a value two CPU tasks read, a graph output (the caller reads it too) or a delay's
    (later frames and user threads do); the results are the same either way."""
    prog = diamond()
    # c reads a (a graph output) and b; d reads c alone.
    ex = Executor(sched({"a": "gpu", "b": "gpu", "c": "cpu0", "d": "cpu1"}, ms=ms), prog,
                  gpu_device="cpu")
    assert ex._host_alone == {"d"}
    # a and b both read x (one value, two CPU readers).
    ex2 = Executor(sched({"a": "cpu0", "b": "cpu1", "c": "gpu", "d": "cpu0"}, ms=ms), diamond(),
                   gpu_device="cpu")
    assert ex2._host_alone == {"d"}
    # t1 reads v0, a delay's value (its ring keeps it for the next frame's t2).
    import warp as wp

    double = lambda v: wp.array(v.numpy() * 2, dtype=wp.float32, device=v.device)  # noqa: E731
    delayed = Program({
        "t0": ExecTask("t0", (InputRef("x"),), ("v0",), lambda v: v * 2, double),
        "t1": ExecTask("t1", (InputRef("v0"),), ("v1",), lambda v: v + 1),
        "t2": ExecTask("t2", (InputRef("v0", -1), InputRef("v1")), ("v2",), lambda a, b: a + b),
    }, ("x",), {"y": "v2"}, {"v0": Ring(1, np.zeros(3, np.float32))})
    ex3 = Executor(sched({"t0": "gpu", "t1": "cpu0", "t2": "cpu1"}, ms=ms), delayed,
                   gpu_device="cpu")
    assert ex3._host_alone == set()
    try:
        for e in (ex, ex2):
            frames = [e.submit(i, {"x": (np.full(3, i, np.float32), HOST)}) for i in range(4)]
            for i, f in enumerate(frames):
                np.testing.assert_array_equal(e.wait(f).outputs["out"], np.full(3, 3 * i))
        frames = [ex3.submit(i, {"x": (np.full(3, i, np.float32), HOST)}) for i in range(4)]
        for i, f in enumerate(frames):  # 2i + 1 + 2(i - 1), frame 0's delay its zeros
            np.testing.assert_array_equal(ex3.wait(f).outputs["y"],
                                          np.full(3, 4 * i - 1 if i else 1))
    finally:
        for e in (ex, ex2, ex3):
            e.close()


class _Device:
    """A stand-in Warp CUDA device: its current stream, the process's default device, and
    a per-thread count of pushed contexts."""

    def __init__(self):
        self.runtime = type("Runtime", (), {"default_device": "user-default"})()
        self.stream = "user-stream"
        self.pushed = threading.local()
        device = self

        class Guard:
            def __enter__(self):
                device.pushed.n = getattr(device.pushed, "n", 0) + 1

            def __exit__(self, *exc):
                device.pushed.n -= 1

        self.context_guard = Guard()

    def set_stream(self, stream, sync=True):
        assert sync is False  # the executor's stream orders its own work only
        self.stream = stream


def test_device_scope_is_shared_by_threads_and_restored_by_the_last_holder():
    """The GPU role's DeviceScope (Warp's device and stream are the process's) may be held by
    a thread running an alternating chain inline and by the GPU role's thread at once: the
    first holder makes them current, the last one restores the user's, and each thread
    pushes and pops its own context."""
    from warpvx.runtime.roles import DeviceScope

    dev = _Device()
    scope = DeviceScope(dev, "executor-stream")
    scope.acquire()
    assert (dev.stream, dev.runtime.default_device, dev.pushed.n) == ("executor-stream", dev, 1)
    other = {}

    def hold():
        with scope:
            other["inside"] = (dev.stream, dev.pushed.n)
        other["after"] = (dev.stream, dev.pushed.n)

    th = threading.Thread(target=hold)
    th.start()
    th.join()
    assert other == {"inside": ("executor-stream", 1), "after": ("executor-stream", 0)}
    assert dev.runtime.default_device is dev  # still held here
    scope.release()
    assert (dev.stream, dev.runtime.default_device, dev.pushed.n) == ("user-stream", "user-default", 0)


@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_gpu_units_run_with_the_gpu_device_current_and_the_default_comes_back(ms):
    """GPU units see the GPU role's device as Warp's default whichever thread runs them
    (inline ones included: the scope is held across short CPU units); after each frame the
    caller's default device is back."""
    import warp as wp

    n = 6
    prog, placement, ran = _alternating(n)
    seen = []
    for name, task in prog.tasks.items():
        if placement[name] == "gpu":
            inner = task.gpu
            task.gpu = lambda v, inner=inner: (seen.append(str(wp.get_device())), inner(v))[1]
    ex = Executor(sched(placement, ms=ms), prog, gpu_device="cpu")
    ex._start()
    dev = ex._scope.device
    saved = dev.runtime.default_device
    dev.runtime.default_device = None  # the caller's: anything but the GPU role's device
    try:
        for i in range(3):
            x = np.full(3, i, np.float32)
            np.testing.assert_array_equal(ex.wait(ex.submit(i, {"x": (x, HOST)})).outputs["y"],
                                          _expected(x, n))
        deadline = time.perf_counter() + 5.0  # a role's thread may still be leaving its run
        while ex._scope.holders and time.perf_counter() < deadline:
            time.sleep(0.001)
        assert ex._scope.holders == 0 and dev.runtime.default_device is None
    finally:
        dev.runtime.default_device = saved
        ex.close()
    assert seen == ["cpu"] * (3 * (n // 2))


@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_caller_runs_units_while_it_waits_for_a_frame_alone_in_flight(ms):
    """One frame at a time, the waiting caller runs the ready units itself as a role's
    thread would (Executor._help): short ones of a serial chain all of them, long ones the
    first role's; with frames of their own in flight the roles' threads still run them."""
    n = 6
    prog, placement, ran = _alternating(n)
    ex = Executor(sched(placement, ms=ms), prog, gpu_device="cpu")
    caller = threading.current_thread()
    try:
        per_frame = []
        for i in range(5):
            x = np.full(3, i, np.float32)
            del ran[:]
            np.testing.assert_array_equal(ex.wait(ex.submit(i, {"x": (x, HOST)})).outputs["y"],
                                          _expected(x, n))
            per_frame.append([th is caller for _, th in ran])
        # The role's thread woken by submit may take the first unit before the caller: some
        # frame, not every one.
        if ms == SHORT:
            assert any(all(on) for on in per_frame)
        else:  # the first CPU unit; the GPU one is long: its own thread, and so on
            assert any(on[0] and not any(on[1:]) for on in per_frame)
        del ran[:]
        xs = [np.full(3, i, np.float32) for i in range(4)]
        frames = [ex.submit(5 + i, {"x": (x, HOST)}) for i, x in enumerate(xs)]
        for x, f in zip(xs[:-1], frames[:-1]):  # others in flight: the caller only waits
            np.testing.assert_array_equal(ex.wait(f).outputs["y"], _expected(x, n))
        assert len(ran) >= 3 * n and not any(th is caller for _, th in ran[:3 * n])
        ex.wait(frames[-1])
    finally:
        ex.close()


# --------------------------------------------------------------------------- flags, buffers, timing


def test_flag_is_a_one_shot_event_for_many_waiters():
    import threading

    from warpvx.runtime import Flag

    f = Flag()
    assert not f.is_set() and f.wait(0.001) is False
    woke = []
    threads = [threading.Thread(target=lambda: woke.append(f.wait(5.0))) for _ in range(4)]
    for t in threads:
        t.start()
    time.sleep(0.01)
    f.set()
    f.set()  # idempotent
    for t in threads:
        t.join(5)
    assert woke == [True] * 4 and f.is_set() and f.wait(0) and f.wait()


def _pooled_program(ring: bool = False, a_output: bool = True):
    """x -> a (GPU, pooled output buffer: x * 2) -> b (CPU: a + 1); a also a graph output
    (unless not ``a_output``)."""
    import warp as wp

    class Made(list):
        written: list  # the buffer each frame's a went into, in order

    made = Made()
    made.written = []

    def new_buffer():
        buf = wp.empty(3, dtype=wp.float32, device="cpu")
        made.append(buf)
        return buf

    def double(x, out=None):  # like a primitive: allocates when given no buffer
        out = new_buffer() if out is None else out
        out.assign(x.numpy() * 2)
        made.written.append(out.ptr)
        return out

    tasks = {
        "a": ExecTask("a", (InputRef("x"),), ("a",), gpu=double, gpu_out=new_buffer),
        "b": ExecTask("b", (InputRef("a"),), ("b",), cpu=lambda a: a + 1),
    }
    rings = {"a": Ring(1, np.zeros(3, np.float32))} if ring else {}
    if ring:  # a task reading a's previous value keeps it alive past its frame
        tasks["c"] = ExecTask("c", (InputRef("a", -1),), ("c",), cpu=lambda p: p.copy())
    outputs = ({"a": "a"} if a_output else {}) | {"b": "b"} | ({"c": "c"} if ring else {})
    return Program(tasks, ("x",), outputs, rings=rings), made


@pytest.mark.parametrize("depth", [1, 3])
def test_gpu_output_buffers_are_reused_across_frames_without_aliasing(depth):
    prog, made = _pooled_program()
    placement = {"a": "gpu", "b": "cpu0"}
    ex = Executor(sched(placement, ["a", "b"]), prog, gpu_device="cpu")
    pending, got = [], []
    for i in range(12):
        pending.append(ex.submit(i, {"x": (np.full(3, i, np.float32), HOST)}))
        if len(pending) >= depth:
            got.append(ex.wait(pending.pop(0)))
    got += [ex.wait(f) for f in pending]
    ex.close()
    # Values are each frame's own, though the buffers are shared between frames.
    assert [float(r.outputs["a"][0]) for r in got] == [2.0 * i for i in range(12)]
    assert [float(r.outputs["b"][0]) for r in got] == [2.0 * i + 1 for i in range(12)]
    assert 1 <= len(made) <= depth + 1  # a steady state allocates nothing


def test_buffers_a_delay_or_the_caller_may_hold_are_not_reused():
    prog, made = _pooled_program(ring=True)
    ex = Executor(sched({"a": "gpu", "b": "cpu0", "c": "cpu1"}, ["a", "b", "c"]), prog,
                  gpu_device="cpu")
    outs = [ex.wait(ex.submit(i, {"x": (np.full(3, i + 1, np.float32), HOST)})) for i in range(5)]
    ex.close()
    assert len(made) == 5  # a delay reads a: every frame gets a new buffer
    assert [float(r.outputs["c"][0]) for r in outs] == [0.0, 2.0, 4.0, 6.0, 8.0]

    prog, made = _pooled_program()
    ex = Executor(sched({"a": "gpu", "b": "cpu0"}, ["a", "b"]), prog, gpu_device="cpu")
    device_outs = [ex.wait(ex.submit(i, {"x": (np.full(3, i, np.float32), HOST)}), host=False)
                   for i in range(4)]
    ex.close()
    assert len(made) == 4  # handed to the caller on the device: never reused
    assert [float(r.outputs["a"].numpy()[0]) for r in device_outs] == [0.0, 2.0, 4.0, 6.0]


@pytest.mark.parametrize("depth", [1, 3])
def test_buffers_a_delay_holds_are_reused_once_the_delay_lets_their_frame_go(depth):
    """A delayed value that is no graph output: its buffer goes back to the pool once the
    delay has aged past its frame (never while a later frame may still read it), so a
    steady stream allocates nothing and every frame reads its predecessor's own value."""
    prog, made = _pooled_program(ring=True, a_output=False)
    ex = Executor(sched({"a": "gpu", "b": "cpu0", "c": "cpu1"}, ["a", "b", "c"]), prog,
                  gpu_device="cpu")
    assert ex._pool_rule["a"] == "ring"
    pending, outs = [], []
    for i in range(16):
        pending.append(ex.submit(i, {"x": (np.full(3, i + 1, np.float32), HOST)}))
        if len(pending) >= depth:
            outs.append(ex.wait(pending.pop(0)))
    outs += [ex.wait(f) for f in pending]
    ex.close()
    assert [float(r.outputs["c"][0]) for r in outs] == [0.0] + [2.0 * i for i in range(1, 16)]
    assert [float(r.outputs["b"][0]) for r in outs] == [2.0 * i + 1 for i in range(1, 17)]
    assert len(made) <= depth + 3  # the ring's frames and those in flight, then reuse
    # (c's host copy of a is cached by b's download, so values alone would not show a buffer
    # reused too early:) no frame writes the buffer its predecessor's value is held in.
    w = made.written
    assert len(w) == 16 and all(w[j] != w[j - 1] for j in range(1, 16))
    assert len(set(w)) < 16  # and buffers are reused


def test_a_delayed_value_passed_on_into_a_delay_keeps_its_buffer():
    """A GPU task that passes an earlier frame's value on as a delay's (a keyframe kept:
    ``k = prev if prev is set else a``) moves the buffer ``a`` made in frame 0 into every
    later frame's slot of the delay: no frame's aging frees it, so ``a``'s buffers are never
    reused (a reused one would be overwritten under the kept keyframe)."""
    import warp as wp

    made = []

    def double(x, out=None):
        out = wp.empty(3, dtype=wp.float32, device="cpu") if out is None else out
        out.assign(x.numpy() * 2)
        return out

    def new_buffer():
        buf = wp.empty(3, dtype=wp.float32, device="cpu")
        made.append(buf)
        return buf

    def keep(a, prev):
        held = prev.numpy() if hasattr(prev, "numpy") else np.asarray(prev)
        return prev if held.any() else a

    tasks = {
        "a": ExecTask("a", (InputRef("x"),), ("a",), gpu=double, gpu_out=new_buffer),
        "k": ExecTask("k", (InputRef("a"), InputRef("k", -1)), ("k",), gpu=keep),
        "c": ExecTask("c", (InputRef("k"),), ("c",), cpu=lambda k: k.copy()),
    }
    prog = Program(tasks, ("x",), {"c": "c"}, rings={"k": Ring(1, np.zeros(3, np.float32))})
    ex = Executor(sched({"a": "gpu", "k": "gpu", "c": "cpu0"}, ["a", "k", "c"]), prog,
                  gpu_device="cpu")
    assert ex._pool_rule["a"] == "never"
    outs = [ex.wait(ex.submit(i, {"x": (np.full(3, i + 1, np.float32), HOST)}))
            for i in range(8)]
    ex.close()
    assert [float(r.outputs["c"][0]) for r in outs] == [2.0] * 8


def test_frame_result_reports_transfers_copies_and_host_times():
    x = np.arange(5, dtype=np.float32)
    res = run_schedule(sched({"a": "gpu", "b": "cpu0", "c": "cpu1", "d": "gpu"}), diamond(),
                       {"x": (x, HOST)}, gpu_device="cpu")
    # a (GPU) uploads x; c (CPU) downloads a; d (GPU) uploads c.
    assert res.copied["a"] == x.nbytes and res.copied["c"] == x.nbytes and res.copied["d"] == x.nbytes
    assert "b" not in res.copied  # x is host data for a CPU task: no copy
    for t in ("a", "c", "d"):
        assert 0 <= res.transfers[t] <= res.timeline[t].finish - res.timeline[t].start + 1e-9
        assert res.compute_ms(t) == pytest.approx(
            res.timeline[t].finish - res.timeline[t].start - res.transfers[t])
    assert set(res.host) == {"a", "d"}  # the GPU thread's own time per GPU task
    for t in ("a", "d"):
        h0, h1 = res.host[t]
        assert 0 <= h0 <= h1


class _Clock:
    """Stand-in CUDA timing events (no GPU here): an event is its device time in ms."""

    def __init__(self, ms):
        self.ms = ms


def test_gpu_events_are_read_with_the_timeline_and_only_then_recycled(monkeypatch):
    """CUDA timelines are read lazily: a frame's events go back to the pool when its
    timeline is first read, when its result is garbage unread, or when MAX_UNREAD newer
    results hold theirs; never before (a re-recorded event would give another time)."""
    import gc

    from warpvx.runtime import timeline as tl

    monkeypatch.setattr(tl, "elapsed_since", lambda start: lambda end: end.ms - start.ms)
    anchor = (100.0, _Clock(0.0))  # host second 100.0 is device ms 0

    def frame(i):
        f = tl.Frame(i, {}, 1)
        a, b = _Clock(2.0 + i), _Clock(5.0 + i)
        f.trace = {"g": ("gpu", a, b, None), "c": ("cpu0", 100.01, 100.02, None)}
        f.t0 = 100.0
        f.events = [a, b]
        return f

    pool = tl.EventPool("cuda:0")
    res = tl.frame_result(frame(0), {}, anchor, pool.put)
    pool.lend(res)
    assert len(pool) == 0  # unread: the events are still the trace's
    assert res.timeline["g"].start == pytest.approx(2.0)  # ms from t0: device ms + anchor
    assert res.timeline["g"].finish == pytest.approx(5.0)
    assert res.timeline["c"].finish == pytest.approx(20.0)
    assert len(pool) == 2
    assert res.makespan == pytest.approx(20.0)  # read again: built once, recycled once
    assert len(pool) == 2

    pool = tl.EventPool("cuda:0")
    res = tl.frame_result(frame(1), {}, anchor, pool.put)
    del res
    gc.collect()
    assert len(pool) == 2  # garbage unread

    pool = tl.EventPool("cuda:0")
    kept = []
    for i in range(pool.MAX_UNREAD + 2):
        kept.append(tl.frame_result(frame(i), {}, anchor, pool.put))
        pool.lend(kept[-1])
    assert len(pool) == 2 * 2  # the two oldest were read to free their events
    assert kept[0].timeline["g"].start == pytest.approx(2.0)
    assert kept[-1].timeline["g"].finish == pytest.approx(5.0 + pool.MAX_UNREAD + 1)


def _blur_program():
    """x (host uint8 16x16) -> a = blur(x), b = blur(a) on the GPU role (one capturable
    segment) -> c = b + 1 on a CPU worker; d reads a one frame late (a delay)."""
    import warp as wp

    import warpvx
    from warpvx.backend import resolve_backend

    be = resolve_backend("warp-cpu")

    def blur(v, out=None):
        return warpvx.gaussian_blur(v, ksize=(3, 3), sigma=0.8, out=out, backend=be)

    def buffer():
        return wp.empty((16, 16), dtype=wp.uint8, device="cpu")

    tasks = {
        "a": ExecTask("a", (InputRef("x"),), ("a",), gpu=blur, gpu_out=buffer, capture=True),
        "b": ExecTask("b", (InputRef("a"),), ("b",), gpu=blur, gpu_out=buffer, capture=True),
        "c": ExecTask("c", (InputRef("b"),), ("c",), cpu=lambda b: b.astype(np.int32) + 1),
        "d": ExecTask("d", (InputRef("a", -1),), ("d",), cpu=lambda p: p.copy()),
    }
    rings = {"a": Ring(1, np.zeros((16, 16), np.uint8))}
    return Program(tasks, ("x",), {"c": "c", "d": "d"}, rings=rings)


@pytest.mark.parametrize("depth", [1, 3])
def test_captured_segment_equals_eager_with_cpu_reader_and_delay(depth):
    """A captured segment's fixed buffers are shared by the frames in flight: what leaves
    it (to a CPU task, to a delay) must be each frame's own copy."""
    import cv2

    rng = np.random.default_rng(3)
    frames = [rng.integers(0, 256, (16, 16), dtype=np.uint8) for _ in range(10)]
    placement = {"a": "gpu", "b": "gpu", "c": "cpu0", "d": "cpu1"}
    results = {}
    for capture in (False, True):
        ex = Executor(sched(placement, ["a", "b", "c", "d"]), _blur_program(), gpu_device="cpu",
                      capture=capture)
        assert [len(s.tasks) for s in ex._segments] == [2]
        pending, got = [], []
        for i, f in enumerate(frames):
            pending.append(ex.submit(i, {"x": (f, HOST)}))
            if len(pending) >= depth:
                got.append(ex.wait(pending.pop(0)))
        got += [ex.wait(f) for f in pending]
        assert ex.captures == (1 if capture else 0)
        ex.close()
        results[capture] = got
    for i, (e, c) in enumerate(zip(results[False], results[True])):
        a = cv2.GaussianBlur(frames[i], (3, 3), 0.8)
        np.testing.assert_array_equal(c.outputs["c"], cv2.GaussianBlur(a, (3, 3), 0.8) + 1)
        np.testing.assert_array_equal(c.outputs["d"], e.outputs["d"])
        prev = cv2.GaussianBlur(frames[i - 1], (3, 3), 0.8) if i else np.zeros((16, 16), np.uint8)
        np.testing.assert_array_equal(c.outputs["d"], prev)
        # Captured tasks share their replay's interval, in order.
        ta, tb = c.timeline["a"], c.timeline["b"]
        assert ta.start <= ta.finish <= tb.start + 1e-9 <= tb.finish + 1e-9


@pytest.mark.parametrize("ms", [LONG, SHORT])
def test_spinning_threads_hand_off_the_same_results(ms):
    """With ``spin`` a waiting thread polls before it sleeps; results and order are the same."""
    n = 6
    prog, placement, _ = _alternating(n)
    ex = Executor(sched(placement, ms=ms), prog, gpu_device="cpu", spin=1e-3)
    try:
        xs = [np.full(2, i, np.float32) for i in range(5)]
        frames = [ex.submit(i, {"x": (x, HOST)}) for i, x in enumerate(xs)]
        for x, f in zip(xs, frames):
            np.testing.assert_array_equal(ex.wait(f).outputs["y"], _expected(x, n))
    finally:
        ex.close()


def _burst_chain(fail_at=None):
    """x -> g1 -> g2 -> g3 (GPU) -> c4 (CPU) -> g5 (GPU, the output): g1..g3 run back to back
    on the GPU role and only g3's value leaves the GPU stream before g5's. ``fail_at``: the
    task that raises."""
    import warp as wp

    def gpu_fn(name, k):
        def fn(v):
            if name == fail_at:
                raise RuntimeError(f"{name} failed")
            return wp.array(v.numpy() * k + 1, dtype=wp.float32, device=v.device)
        return fn

    tasks, prev = {}, "x"
    for name, k in (("g1", 2), ("g2", 3), ("g3", 5), ("c4", 7), ("g5", 11)):
        cpu = (lambda v, k=k: v * k + 1) if name == "c4" else None
        gpu = None if name == "c4" else gpu_fn(name, k)
        tasks[name] = ExecTask(name, (InputRef(prev),), (name,), cpu, gpu)
        prev = name
    return Program(tasks, ("x",), {"y": "g5"})


def test_burst_timing_shares_one_interval_per_run_of_gpu_tasks():
    """timing="bursts" (Warp's CPU device: host times stand in for events): same outputs as
    per-task timing; the GPU tasks run back to back before a CPU reader share one interval
    in proportion to their scheduled durations and tile it; a task after a hand-off starts
    a burst of its own; every node keeps its host time."""
    placement = {"g1": "gpu", "g2": "gpu", "g3": "gpu", "c4": "cpu0", "g5": "gpu"}
    spans = {"g1": 1.0, "g2": 3.0, "g3": 4.0, "c4": 1.0, "g5": 1.0}
    at, placed = 0.0, {}
    for t, p in placement.items():
        placed[t] = ScheduledTask(t, p, at, at + spans[t])
        at += spans[t]
    schedule = Schedule(placed, PROCS)
    x = np.arange(4, dtype=np.float32)
    want = ((((x * 2 + 1) * 3 + 1) * 5 + 1) * 7 + 1) * 11 + 1
    results = {}
    for timing in ("tasks", "bursts"):
        ex = Executor(schedule, _burst_chain(), gpu_device="cpu", timing=timing)
        try:
            results[timing] = [ex.wait(ex.submit(f, {"x": (x, HOST)})) for f in range(3)]
        finally:
            ex.close()
    for r in results["tasks"] + results["bursts"]:
        np.testing.assert_array_equal(r.outputs["y"], want)
    r = results["bursts"][-1]
    tl = r.timeline
    assert set(tl) == set(placement) and set(r.host) == {"g1", "g2", "g3", "g5"}
    a, b = tl["g1"].start, tl["g3"].finish
    assert tl["g1"].finish == pytest.approx(a + (b - a) / 8)
    assert tl["g2"].start == pytest.approx(tl["g1"].finish)
    assert tl["g2"].finish == pytest.approx(a + (b - a) * 4 / 8)
    assert tl["g3"].start == pytest.approx(tl["g2"].finish)
    assert tl["g3"].finish <= tl["c4"].start <= tl["c4"].finish <= tl["g5"].start
    assert r.host["g1"][0] == pytest.approx(a) and r.host["g1"][1] <= r.host["g2"][0]
    # Per-task timing: each interval is the task's own host call.
    t = results["tasks"][-1]
    assert all(t.timeline[n].start == pytest.approx(t.host[n][0]) for n in ("g1", "g2", "g3"))


@pytest.mark.parametrize("fail_at", ["g2", "g5"])
def test_burst_timing_reports_a_failing_task_and_runs_the_next_frame(fail_at):
    placement = {"g1": "gpu", "g2": "gpu", "g3": "gpu", "c4": "cpu0", "g5": "gpu"}
    program = _burst_chain(fail_at)
    ex = Executor(sched(placement, ms=SHORT), program, gpu_device="cpu", timing="bursts")
    x = np.ones(4, np.float32)
    try:
        with pytest.raises(NodeExecutionError, match=fail_at) as info:
            ex.wait(ex.submit(0, {"x": (x, HOST)}))
        assert isinstance(info.value.__cause__, RuntimeError)
        ok = Executor(sched(placement, ms=SHORT), _burst_chain(), gpu_device="cpu",
                      timing="bursts")
        try:
            r = ok.wait(ok.submit(1, {"x": (x, HOST)}))
            assert set(r.timeline) == set(placement)
        finally:
            ok.close()
    finally:
        ex.close()


def test_timing_refuses_unknown_values_by_name():
    from warpvx.errors import WarpvxValueError

    with pytest.raises(WarpvxValueError, match="timing"):
        Executor(sched({"a": "cpu0", "b": "cpu0", "c": "cpu0", "d": "cpu0"}), diamond(),
                 timing="events")


def test_burst_timing_records_one_start_and_one_end_event_per_run_on_cuda_paths():
    """The CUDA bookkeeping of timing="bursts", driven directly with stand-in events (no
    CUDA here): three GPU tasks back to back, the third read by a CPU task, record one start
    event and one end event (per-task timing: one start and three ends); all three tasks
    span that one interval, and only the third's value carries an event."""
    import warp as wp

    from warpvx.runtime.roles import GpuState
    from warpvx.runtime.timeline import Frame
    from warpvx.runtime.transfers import Transfers
    from warpvx.runtime.slots import Slot

    placement = {"g1": "gpu", "g2": "gpu", "g3": "gpu", "c4": "cpu0", "g5": "gpu"}
    program = _burst_chain()
    recorded = {}
    for timing in ("tasks", "bursts"):
        ex = Executor(sched(placement), program, gpu_device="cpu", timing=timing)
        ex.cuda = True  # the CUDA path, with events that are plain objects

        class Pool:
            def get(self):
                return object()

        ex._events, rec = Pool(), []
        ex._record = rec.append
        x = wp.array(np.ones(4, np.float32), dtype=wp.float32, device="cpu")
        slots = {"x": Slot.holding(x, DEVICE), **{k: Slot() for k in placement}}
        frame = Frame(0, slots, 1)
        frame.bursts = timing == "bursts"
        state = GpuState("gpu", Transfers("cpu"))
        for name, src in (("g1", "x"), ("g2", "g1"), ("g3", "g2")):
            ex._run_gpu_task(frame, program.tasks[name], state, [slots[src]])
        recorded[timing] = len(rec)
        if timing == "bursts":
            starts = {frame.trace[n][1] for n in ("g1", "g2", "g3")}
            ends = {frame.trace[n][2] for n in ("g1", "g2", "g3")}
            assert starts == {rec[0]} and ends == {rec[1]} and frame.gpu_last_event is rec[1]
            assert slots["g1"].event is None and slots["g2"].event is None
            assert slots["g3"].event is rec[1]
            assert frame.shares["g1"][0] == 0.0 and frame.shares["g3"][1] == 1.0
    assert recorded == {"tasks": 4, "bursts": 2}
