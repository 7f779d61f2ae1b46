"""Hostile use of graphs (issue 10, items 5, 17, 23): re-entrant and concurrent runs, streams
whose frames iterator fails or whose graph changes, bad stream/delay/verify arguments,
strided inputs, the GPU role on Warp's CPU device; and empty Warp arrays counting as
contiguous. Every case that used to hang runs on a daemon thread with a time limit, so a
regression fails its test instead of hanging the session."""

from __future__ import annotations

import threading
import warnings

import numpy as np
import pytest

import warpvx
import warpvx.backend
from tests.parity import on_device
from warpvx.arrays import is_contiguous, to_numpy
from warpvx.backend import init_warp
from warpvx.errors import GraphError, NodeExecutionError
from warpvx.graph import NoCudaWarning, costs

pytestmark = pytest.mark.timeout(120)

LIMIT = 30.0  # seconds a call that used to hang may take before the test fails


def within(fn, limit: float = LIMIT):
    """``fn()``'s result (or exception), run on a daemon thread; fails if it takes over
    ``limit`` seconds (a deadlock), without blocking the session on it."""
    box = {}

    def run():
        try:
            box["value"] = fn()
        except BaseException as exc:  # noqa: BLE001 - handed to the test thread
            box["error"] = exc

    th = threading.Thread(target=run, daemon=True)
    th.start()
    th.join(limit)
    if th.is_alive():
        pytest.fail(f"still running after {limit} s (deadlock)")
    if "error" in box:
        raise box["error"]
    return box["value"]


def plus_one_graph(fn=None, *, target=None):
    """x (float32[3]) -> y = fn(x) (default x + 1) in one user node ``f``."""
    g = warpvx.Graph("hostile")
    x = g.input("x", shape=(3,), dtype=np.float32)
    g.output("y", g.user(fn or (lambda v: v + 1), [x], "y", name="f", target=target))
    return g


def frame(i: float) -> dict:
    return {"x": np.full(3, i, np.float32)}


def test_process_from_inside_own_node_raises_and_graph_stays_usable():
    """Item 5: it deadlocked forever and blocked every later process()."""
    call = []

    def node(v):
        if call:
            call[0]()
        return v + 1

    g = plus_one_graph(node)
    g.schedule("baseline", gpu=False)
    for nested in (lambda: g.process(frame(0)), lambda: list(g.stream([frame(0)])),
                   lambda: g.reset()):
        call[:] = [nested]
        with pytest.raises(NodeExecutionError) as info:
            within(lambda: g.process(frame(1)))
        cause = info.value.__cause__
        assert isinstance(cause, GraphError) and "inside its own node 'f'" in str(cause)
        call.clear()
        assert float(within(lambda: g.process(frame(2)))["y"][0]) == 3.0
    g.close()


def test_process_from_inside_own_node_during_verify_raises():
    """The dry run runs the node on the calling thread (which holds the run lock)."""
    g = plus_one_graph(lambda v: (g.process(frame(0)), v)[1])
    with pytest.raises(GraphError, match="inside its own node 'f'"):
        within(g.verify)


def test_changing_the_graph_from_inside_own_node_is_refused():
    g = plus_one_graph(lambda v: (g.add("gaussian_blur", g.inputs["x"]), v)[1])
    with pytest.raises(GraphError, match="inside its own node 'f'"):
        within(g.verify)
    assert list(g.nodes) == ["f"]


def test_other_graph_may_run_inside_a_node():
    inner = plus_one_graph()
    outer = plus_one_graph(lambda v: inner.process({"x": v})["y"] * 2)
    assert float(within(lambda: outer.process(frame(1)))["y"][0]) == 4.0
    inner.close()
    outer.close()


def test_process_while_a_stream_is_suspended():
    """Item 5: another thread's process() blocked until the generator was collected; it now
    waits at most ``stream_wait`` s and names the stream. This thread's is refused at once."""
    g = plus_one_graph()
    g.stream_wait = 0.3
    gen = g.stream(frame(i) for i in range(5))
    assert float(next(gen)["y"][0]) == 1.0
    with pytest.raises(GraphError, match=r"waited 0.3 s for the stream\(\) generator of graph 'hostile'"):
        within(lambda: g.process(frame(9)))
    with pytest.raises(GraphError, match="is live in this thread"):
        g.process(frame(9))
    # The stream was not disturbed: every frame comes, in order.
    assert [float(o["y"][0]) for o in gen] == [2.0, 3.0, 4.0, 5.0]
    assert float(within(lambda: g.process(frame(9)))["y"][0]) == 10.0
    gen = g.stream(frame(i) for i in range(5))
    next(gen)
    gen.close()  # closing frees the graph at once
    assert float(within(lambda: g.process(frame(1)))["y"][0]) == 2.0
    g.close()


def test_stream_moved_to_another_thread_frees_the_graph():
    """The stream holds a token, not a thread's lock, between frames: finished, closed or
    collected on another thread than the one that started it, it frees the graph."""
    g = plus_one_graph()
    gen = g.stream(frame(i) for i in range(4))
    next(gen)
    assert [float(o["y"][0]) for o in within(lambda: list(gen))] == [2.0, 3.0, 4.0]
    assert float(within(lambda: g.process(frame(1)))["y"][0]) == 2.0
    for end in (lambda gen: gen.close(), lambda gen: gen.__del__()):
        gen = g.stream(frame(i) for i in range(4))
        next(gen)
        within(lambda: end(gen))
        assert float(g.process(frame(1))["y"][0]) == 2.0
        assert float(within(lambda: g.process(frame(2)))["y"][0]) == 3.0
    g.close()


def test_process_from_another_thread_waits_for_a_running_process():
    """A process() in flight (not a stream) is waited for, however long: it is bounded."""
    started, release = threading.Event(), threading.Event()

    def slow(v):
        if v[0] == 7:
            started.set()
            release.wait(5)
        return v + 1

    g = plus_one_graph(slow)
    g.stream_wait = 0.05
    g.schedule("baseline", gpu=False)
    t = threading.Thread(target=g.process, args=(frame(7),), daemon=True)
    t.start()
    assert started.wait(10)
    threading.Timer(0.3, release.set).start()  # longer than stream_wait
    assert float(within(lambda: g.process(frame(1)))["y"][0]) == 2.0
    t.join(10)
    g.close()


@pytest.mark.parametrize("depth", [1, 3])
def test_frames_iterator_that_raises_yields_the_submitted_frames_first(depth):
    """Item 5: the frame already submitted was dropped; now every frame the iterator gave is
    yielded, then its exception is raised."""
    def frames():
        for i in range(4):
            yield frame(i)
        raise KeyError("camera unplugged")

    g = plus_one_graph()
    got = []
    with pytest.raises(KeyError, match="camera unplugged"):
        for out in within(lambda: g.stream(frames(), depth=depth)):
            got.append(float(out["y"][0]))
    assert got == [1.0, 2.0, 3.0, 4.0]
    assert float(within(lambda: g.process(frame(5)))["y"][0]) == 6.0  # the graph is free
    g.close()


def test_bad_frame_in_a_stream_yields_the_frames_before_it():
    g = plus_one_graph()
    frames = [frame(0), frame(1), {"x": np.zeros(4, np.float32)}, frame(3)]
    got = []
    with pytest.raises(GraphError, match=r"input 'x': expected shape \(3,\)"):
        for out in g.stream(frames, depth=3):
            got.append(float(out["y"][0]))
    assert got == [1.0, 2.0]
    g.close()


def test_changing_the_graph_while_a_stream_is_live_is_refused():
    """Item 5: adding a node lost the frames in flight with a bare RuntimeError."""
    g = plus_one_graph()
    gen = g.stream((frame(i) for i in range(6)), depth=3)
    got = [float(next(gen)["y"][0])]
    changes = [lambda: g.add("gaussian_blur", g.inputs["x"]),
               lambda: g.user(lambda v: v, [g.inputs["x"]]),
               lambda: g.input("z", shape=(3,), dtype=np.float32),
               lambda: g.output("x_again", g.inputs["x"]),
               lambda: g.delay(g.inputs["x"]),
               lambda: setattr(g.node("f"), "target", "cpu")]
    for change in changes:
        for run in (change, lambda: within(change)):  # this thread and another one
            with pytest.raises(GraphError, match=r"while the stream\(\) generator of graph "
                                                 r"'hostile' .* is live"):
                run()
    assert list(g.nodes) == ["f"] and list(g.inputs) == ["x"] and g.node("f").target is None
    got += [float(o["y"][0]) for o in gen]
    assert got == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    g.user(lambda v: v, [g.inputs["x"]], name="after")  # the stream is over: allowed again
    g.close()


@pytest.mark.parametrize("frames", [5, None, 2.5, {"x": np.zeros(3, np.float32)}])
def test_stream_of_a_non_iterable_names_frames(frames):
    """Item 17: raised TypeError: not iterable (at the first next())."""
    g = plus_one_graph()
    with pytest.raises(GraphError, match="^frames: expected an iterable"):
        g.stream(frames)  # at the call, not at the first frame


def test_stream_of_stacked_frames_array():
    """An array of frames iterates over its first axis, as before."""
    g = plus_one_graph()
    out = [float(o["y"][0]) for o in g.stream(np.arange(12, dtype=np.float32).reshape(4, 3))]
    assert out == [1.0, 4.0, 7.0, 10.0]
    g.close()


def delay_graph(init=None):
    """y = x + d[-1] (float32[3], d a 2-slot delay of x); returns (graph, d)."""
    g = warpvx.Graph("delays")
    x = g.input("x", shape=(3,), dtype=np.float32)
    d = g.delay(x, 2, init=init)
    g.output("y", g.user(lambda a, b: a + b, [x, d[-1]], "y", name="add"))
    return g, d


@pytest.mark.parametrize("call", ["read", "write", "getitem"])
@pytest.mark.parametrize("index", ["x", 1.0, True, None])
def test_delay_index_of_the_wrong_type_names_index(call, index):
    """Item 17: raised a bare TypeError."""
    g, d = delay_graph()
    g.verify()
    with pytest.raises(GraphError, match="^delay 'x', index: expected an int"):
        {"read": lambda: d.read(index), "getitem": lambda: d[index],
         "write": lambda: d.write(np.zeros(3, np.float32), index)}[call]()


@pytest.mark.parametrize("call, index", [("read", 1), ("read", -3), ("write", 0), ("write", -3)])
def test_delay_index_out_of_range_names_index(call, index):
    g, d = delay_graph()
    g.verify()
    with pytest.raises(GraphError, match=f"^delay 'x', index: {index} is outside"):
        d.read(index) if call == "read" else d.write(np.zeros(3, np.float32), index)


@pytest.mark.parametrize("value, why", [
    ("abc", "expected a NumPy array, got str"),
    (np.zeros((3, 1), np.float32), r"expected shape N, got \(3, 1\)"),
    (np.zeros(3, np.float64), "expected dtype float32, got float64"),
    (3.0, "expected a NumPy array, got float"),
])
def test_delay_write_of_the_wrong_type_is_refused_at_write_time(value, why):
    """Item 17: it was accepted and the next frame failed."""
    g, d = delay_graph()
    g.process(frame(1))
    with pytest.raises(GraphError, match=f"^delay 'x', value: {why}"):
        d.write(value)
    out = g.process(frame(2))  # the refused write changed nothing
    np.testing.assert_array_equal(out["y"], np.full(3, 3, np.float32))
    g.close()


def test_delay_write_checks_nested_values():
    g = warpvx.Graph("pyr")
    f = g.input("f", shape=(32, 32), dtype=np.uint8)
    d = g.delay(g.gaussian_pyramid(f, levels=2))
    g.verify()
    good = [np.zeros((32, 32), np.uint8), np.zeros((16, 16), np.uint8)]
    d.write(good)
    with pytest.raises(GraphError, match="^delay .*, value: item 1: expected shape Nx16"):
        d.write([good[0], np.zeros((16, 8), np.uint8)])
    with pytest.raises(GraphError, match="^delay .*, value: expected a list of 2"):
        d.write(good[:1])


def test_delay_read_before_any_frame():
    """Item 17: read(-1) returned None. Defined as the initial value (what the next frame's
    delay[-1] reads, as an OpenVX delay's slots hold their initial contents), and a
    GraphError when none is known yet (before verification, without init=)."""
    g, d = delay_graph()
    with pytest.raises(GraphError, match="no value yet"):
        d.read(-1)
    g.verify()
    np.testing.assert_array_equal(d.read(-1), np.zeros(3, np.float32))
    g2, d2 = delay_graph(init=np.full(3, 7, np.float32))
    np.testing.assert_array_equal(d2.read(-2), np.full(3, 7, np.float32))
    out = g2.process(frame(1))
    np.testing.assert_array_equal(out["y"], np.full(3, 8, np.float32))
    g2.close()


@pytest.mark.parametrize("target", ["cpu", "gpu"])
def test_strided_input_is_copied_once(target):
    """Item 17: a non-contiguous input failed inside the node; it is now copied once at
    process() entry, on every backend of the graph."""
    g = warpvx.Graph("strided")
    f = g.input("f", shape=(24, 32), dtype=np.uint8)
    g.output("b", g.gaussian_blur(f, ksize=(3, 3), sigma=1.0, target=target))
    g.schedule("baseline", gpu="warp-cpu")
    big = np.random.default_rng(0).integers(0, 256, (48, 32), np.uint8)
    view = big[::2]
    assert not view.flags.c_contiguous
    got = g.process({"f": view})["b"]
    be = "warp-cpu" if target == "gpu" else "cpu"
    want = to_numpy(warpvx.gaussian_blur(on_device(np.ascontiguousarray(view), be),
                                                (3, 3), 1.0, backend=be))
    np.testing.assert_array_equal(got, want)
    out = list(g.stream([{"f": view}]))
    np.testing.assert_array_equal(out[0]["b"], want)
    g.close()


@pytest.mark.parametrize("call", ["verify", "process"])
def test_misspelled_input_name_is_named(call):
    """Item 17: verify({"img": ...}) passed silently when the input is "frame"."""
    g = warpvx.Graph("names")
    f = g.input("frame", shape=(16, 16), dtype=np.uint8)
    g.output("b", g.gaussian_blur(f, ksize=(3, 3), sigma=1.0))
    with pytest.raises(GraphError, match=r"unknown input\(s\) \['img'\]; the graph has \['frame'\]"):
        getattr(g, call)({"img": np.zeros((16, 16), np.uint8)})
    with pytest.raises(GraphError, match=r"unknown input\(s\) \['img'\]"):
        g.verify([{"frame": np.zeros((16, 16), np.uint8)}, {"img": np.zeros((16, 16), np.uint8)}])


@pytest.fixture
def no_cuda(monkeypatch):
    """A machine without CUDA, and the once-per-process warning not given yet."""
    monkeypatch.setattr(warpvx.backend, "cuda_available", lambda: False)
    monkeypatch.setattr(costs, "_warned_no_cuda", False)


def test_gpu_target_without_cuda_warns_once_and_is_labelled(no_cuda, tmp_path):
    """Item 23: target="gpu" silently ran on Warp's CPU device and was drawn as "gpu"."""
    g = plus_one_graph()
    img = g.input("img", shape=(16, 16), dtype=np.uint8)
    g.output("b", g.gaussian_blur(img, ksize=(3, 3), sigma=1.0, name="blur", target="gpu"))
    with pytest.warns(NoCudaWarning, match=r"no CUDA device.*\['blur'\].*'gpu \(warp-cpu\)'"):
        plan = g.schedule("baseline")
    assert plan.gpu == "warp-cpu" and plan.placement["blur"] == "gpu"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g.schedule("heft")  # once per process
    assert g.plan.summary()["processors"][-1] == "gpu (warp-cpu)"
    g.process({"x": np.zeros(3, np.float32), "img": np.zeros((16, 16), np.uint8)})
    fig = g.plan.gantt()
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.get_yticklabels()]
        assert labels and labels[-1] == "gpu (warp-cpu)" and "gpu" not in labels
    g.close()


def test_explicit_warp_cpu_or_nothing_on_gpu_does_not_warn(no_cuda):
    g = plus_one_graph()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        g.schedule("baseline")  # a CPU-only user node: nothing runs on the GPU role
        g.add("gaussian_blur", g.input("img", shape=(16, 16), dtype=np.uint8), ksize=(3, 3),
              sigma=1.0, target="gpu")
        assert g.schedule("baseline", gpu="warp-cpu").gpu == "warp-cpu"


def test_cuda_gpu_role_is_labelled_gpu():
    g = plus_one_graph()
    plan = g.schedule("baseline", gpu=False)
    assert plan.processor_label("gpu") == "gpu"
    plan.gpu = "cuda:0"
    assert plan.processor_label("gpu") == "gpu" and plan.processor_label("cpu0") == "cpu0"


def empty_points(backend):
    """An empty float32 point set as the backend takes it; on Warp a zero-copy view of an
    empty NumPy array, whose strides Warp reports as non-contiguous."""
    pts = np.zeros((0, 2), np.float32)
    if backend == "cpu":
        return pts
    from warpvx.backend import resolve_backend

    return init_warp().array(pts, device=resolve_backend(backend).device, copy=False)


def test_empty_arrays_are_contiguous(backend):
    """The colleague's bug: Warp said an empty array is not contiguous, so LK on warp-cpu
    refused an empty point set."""
    pts = empty_points(backend)
    assert is_contiguous(pts)
    img = np.random.default_rng(1).integers(0, 256, (32, 32), np.uint8)
    nxt, status, err = warpvx.optical_flow_pyr_lk(on_device(img, backend), on_device(img, backend),
                                                  pts, backend=backend)
    assert [tuple(a.shape) for a in (nxt, status, err)] == [(0, 2), (0,), (0,)]
    if backend != "cpu":  # a strided non-empty view is still refused
        view = init_warp().zeros((4, 4), dtype=float, device=pts.device)[:, 1:3]
        assert not is_contiguous(view)
