"""Running graphs: parity with the functional API for every policy, delays, pinning, stream
order, failing nodes (no hangs), outputs' kind, and thread-safe data access."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

import warpvx
from warpvx.errors import GraphError, NodeExecutionError
from warpvx.graph.data import zeros_like

from .helpers import homography

pytestmark = pytest.mark.timeout(120)

POLICIES = ["baseline", "heft", "xeft", "best"]


def build(frames):
    g = warpvx.Graph("parity")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
    pyr = g.gaussian_pyramid(gray, levels=3, name="pyr")
    kps = g.fast_corners(gray, threshold=20, name="fast", target="gpu")
    pts = g.harris_corners(gray, max_corners=60, quality_level=0.01, min_distance=5, name="harris")
    prev_pyr, prev_pts = g.delay(pyr), g.delay(pts)
    nxt, status, _ = g.optical_flow_pyr_lk(prev_pyr[-1], pyr, prev_pts[-1], max_level=2, name="lk")
    H = g.user(homography, [prev_pts[-1], nxt, status], "H", name="H")
    for name, d in [("gray", gray), ("pyr", pyr), ("kps", kps), ("pts", pts), ("next", nxt),
                    ("status", status), ("H", H)]:
        g.output(name, d)
    g.verify({"frame": frames[0]})
    return g


def expected(placement, frames, pts_init, gpu="warp-cpu"):
    """The functional API on each node's placed backend, frame after frame (``gpu``: the GPU
    role's backend); ``placement`` is node -> processor, or a callable frame -> that."""
    def be(node):
        where = placement(i)[node] if callable(placement) else placement[node]
        return gpu if where == "gpu" else "cpu"

    outs, prev_pyr, prev_pts = [], None, pts_init
    for i, frame in enumerate(frames):
        gray = warpvx.color_convert(frame, "BGR2GRAY", backend=be("gray"))
        pyr = warpvx.gaussian_pyramid(gray, 3, backend=be("pyr"))
        kps = warpvx.fast_corners(gray, 20, backend=be("fast"))
        pts = warpvx.harris_corners(gray, 60, 0.01, 5, backend=be("harris"))
        if prev_pyr is None:
            prev_pyr = zeros_like(pyr)
        nxt, status, _ = warpvx.optical_flow_pyr_lk(prev_pyr, pyr, prev_pts, max_level=2,
                                                    backend=be("lk"))
        H = homography(prev_pts, nxt, status)
        outs.append(dict(gray=gray, pyr=pyr, kps=kps, pts=pts, next=nxt, status=status, H=H))
        prev_pyr, prev_pts = pyr, pts
    return outs


def assert_same(got, want, where):
    if isinstance(want, warpvx.Keypoints):
        assert isinstance(got, warpvx.Keypoints), where
        for field in ("x", "y", "response", "size", "angle", "octave"):
            np.testing.assert_array_equal(getattr(got, field), getattr(want, field), err_msg=where)
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        for i, (a, b) in enumerate(zip(got, want)):
            assert_same(a, b, f"{where}[{i}]")
    else:
        assert isinstance(got, np.ndarray), f"{where}: {type(got)}"
        np.testing.assert_array_equal(got, want, err_msg=where)


@pytest.fixture(scope="module")
def parity_graph(frames):
    g = build(frames)
    yield g
    g.close()


@pytest.mark.parametrize("policy", POLICIES)
def test_process_equals_functional_api(parity_graph, frames, policy):
    g = parity_graph
    pts_init = zeros_like(g.data["harris.out"].sample)
    plan = g.schedule(policy, n_cpus=2, gpu="warp-cpu")
    assert plan.placement["gray"] == "gpu" and plan.placement["fast"] == "gpu"  # pinned
    assert plan.placement["H"].startswith("cpu")  # CPU-only user node
    if policy == "baseline":  # VisionWorks: every node with a GPU implementation on the GPU
        assert {n for n, p in plan.placement.items() if p == "gpu"} == {
            "gray", "pyr", "fast", "harris", "lk"}
    g.reset()  # delays persist across runs: start each policy from the initial values
    want = expected(plan.placement, frames[:3], pts_init)
    for i, frame in enumerate(frames[:3]):
        got = g.process({"frame": frame})
        for key in want[i]:
            assert_same(got[key], want[i][key], f"{policy} frame {i} {key}")
    assert plan.last_run and set(plan.last_run[-1].timeline) == set(g.nodes)


def test_stream_equals_functional_api_in_order(frames):
    g = build(frames)
    plan = g.schedule("best", n_cpus=2, gpu="warp-cpu")
    want = expected(plan.placement, frames, zeros_like(g.data["harris.out"].sample))
    got = list(g.stream(({"frame": f} for f in frames), depth=3))
    assert len(got) == len(frames)
    for i in range(len(frames)):
        for key in want[i]:
            assert_same(got[i][key], want[i][key], f"stream frame {i} {key}")
    g.close()


# --------------------------------------------------------------------------- delays


def _accumulator(gpu_node: bool, slots: int = 1):
    import warp as wp

    g = warpvx.Graph("acc")
    x = g.input("x", shape=(3,), dtype=np.float32)
    acc = g.virtual("acc")
    d = g.delay(acc, slots=slots, init=np.full(3, 100, np.float32))

    def add_warp(a, b):  # a + b on the GPU role, through Warp
        out = wp.empty_like(a)
        wp.launch(_add_kernel, dim=a.shape, inputs=[a, b], outputs=[out], device=a.device)
        return out

    g.user(lambda a, b: a + b, [x, d[-1]], [acc], warp_fn=add_warp if gpu_node else None,
           name="sum", target="gpu" if gpu_node else None)
    # A slow CPU node after the sum, so frames overlap when pipelined.
    g.user(lambda a: (time.sleep(0.002), a * 1)[1], [acc], "slow", name="slow")
    g.output("acc", acc)
    outs = [g.user(lambda v: v, [d[-k]], name=f"past{k}") for k in range(1, slots + 1)]
    for k, o in enumerate(outs, 1):
        g.output(f"past{k}", o)
    return g, d


def _add_kernel_def():
    import warp as wp

    @wp.kernel
    def add_arrays(a: wp.array(dtype=wp.float32), b: wp.array(dtype=wp.float32),
                   out: wp.array(dtype=wp.float32)):
        i = wp.tid()
        out[i] = a[i] + b[i]

    return add_arrays


_add_kernel = _add_kernel_def()


@pytest.mark.parametrize("gpu_node", [False, True], ids=["cpu", "warp-cpu"])
def test_delay_accumulates_in_frame_order_when_pipelined(gpu_node):
    g, d = _accumulator(gpu_node, slots=2)
    g.schedule("heft", n_cpus=2, gpu="warp-cpu")
    xs = [np.full(3, i, np.float32) for i in range(1, 7)]
    got = [o for o in g.stream(({"x": x} for x in xs), depth=4)]
    sums = np.cumsum([1, 2, 3, 4, 5, 6]) + 100
    assert [float(o["acc"][0]) for o in got] == list(map(float, sums))
    # delay[-1] before frame 0 and delay[-2] before frames 0, 1: the init value.
    assert [float(o["past1"][0]) for o in got] == [100.0] + list(map(float, sums[:-1]))
    assert [float(o["past2"][0]) for o in got] == [100.0, 100.0] + list(map(float, sums[:-2]))
    # The communication wrapper: aged values, and a write seen by the next frame.
    assert float(d.read(0)[0]) == sums[-1] and float(d.read(-1)[0]) == sums[-2]
    d.write(np.zeros(3, np.float32), -1)
    out = g.process({"x": np.ones(3, np.float32)})
    assert float(out["acc"][0]) == 1.0
    g.close()


def test_pinning_is_respected_by_every_policy(frames):
    g = warpvx.Graph("pins")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray")
    g.gaussian_pyramid(gray, levels=2, name="pyr", target="cpu")
    g.output("gray", gray)
    gray.node.target = "gpu"
    for policy in POLICIES:
        plan = g.schedule(policy, n_cpus=1, gpu="warp-cpu")
        assert plan.placement == {"gray": "gpu", "pyr": "cpu0"}
        assert set(plan.dag.nodes["gray"]["cost"]) == {"gpu"}
        assert set(plan.dag.nodes["pyr"]["cost"]) == {"cpu0"}
    out = g.process({"frame": frames[0]})
    np.testing.assert_array_equal(out["gray"], cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY))
    g.close()


# --------------------------------------------------------------------------- errors


def _failing_graph(fail_on, *, gpu_fail=False, frames=1):
    g = warpvx.Graph("fail")
    x = g.input("x", shape=(4,), dtype=np.float32)

    def check(v):
        if float(v[0]) == fail_on:
            raise ValueError(f"bad frame {float(v[0])}")
        return v + 1

    def slow(v):
        time.sleep(0.003)
        return v * 2

    a = g.user(slow, [x], name="slow")  # other branch keeps a CPU worker busy
    if gpu_fail:
        b = g.user(None, [x], warp_fn=lambda v: check(v.numpy()), name="check")
    else:
        b = g.user(check, [x], name="check")
    c = g.user(lambda p, q: p + q, [a, b], name="join")
    g.output("y", c)
    g.schedule("heft", n_cpus=2, gpu="warp-cpu", frames=frames)
    return g


@pytest.mark.timeout(30)
@pytest.mark.parametrize("gpu_fail", [False, True], ids=["cpu", "gpu"])
def test_failing_node_surfaces_from_process(gpu_fail):
    g = _failing_graph(3.0, gpu_fail=gpu_fail)
    with pytest.raises(NodeExecutionError, match="node 'check'") as info:
        g.process({"x": np.full(4, 3, np.float32)})
    assert isinstance(info.value.__cause__, ValueError)
    assert "bad frame 3.0" in str(info.value.__cause__)
    out = g.process({"x": np.full(4, 1, np.float32)})  # the graph still runs
    np.testing.assert_array_equal(out["y"], np.full(4, 4, np.float32))
    g.close()


@pytest.mark.timeout(30)
def test_failing_node_in_stream_yields_earlier_frames_then_raises():
    g = _failing_graph(3.0)
    xs = [np.full(4, i, np.float32) for i in range(8)]
    got = []
    with pytest.raises(NodeExecutionError, match="node 'check'") as info:
        for out in g.stream(({"x": x} for x in xs), depth=4):
            got.append(float(out["y"][0]))
    assert got == [i * 2 + i + 1 for i in range(3)]
    assert isinstance(info.value.__cause__, ValueError)
    assert g.plan.executor().in_flight == 0
    # And the next stream runs from a clean state.
    assert len(list(g.stream(({"x": x} for x in xs[4:]), depth=2))) == 4
    g.close()


@pytest.mark.timeout(30)
def test_closing_a_stream_early_cancels_in_flight_frames():
    g = _failing_graph(-1.0)
    it = g.stream(({"x": np.full(4, i, np.float32)} for i in range(100)), depth=4)
    next(it)
    it.close()
    assert g.plan.executor().in_flight == 0
    g.close()


# --------------------------------------------------------------------------- inputs and outputs


def test_input_errors_and_written_inputs():
    g = warpvx.Graph("inputs")
    x = g.input("x", shape=(2, 3), dtype=np.float32)
    g.output("y", g.user(lambda v: v * 2, [x], name="double"))
    g.schedule("heft", n_cpus=1, gpu=False)
    with pytest.raises(GraphError, match="input 'x': missing"):
        g.process()
    with pytest.raises(GraphError, match=r"input 'x': expected shape"):
        g.process({"x": np.zeros((3, 2), np.float32)})
    with pytest.raises(GraphError, match="input 'x': expected dtype"):
        g.process({"x": np.zeros((2, 3), np.float64)})
    with pytest.raises(GraphError, match="unknown input"):
        g.process({"x": np.zeros((2, 3), np.float32), "z": 1})
    x.write(np.ones((2, 3), np.float32))
    np.testing.assert_array_equal(g.process()["y"], np.full((2, 3), 2, np.float32))
    np.testing.assert_array_equal(g.outputs["y"].read(), np.full((2, 3), 2, np.float32))
    with pytest.raises(GraphError, match="only graph input"):
        g.outputs["y"].write(1)
    g.close()


def test_device_outputs_stay_on_device_when_asked(frames):
    import warp as wp

    g = warpvx.Graph("dev")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    g.output("gray", g.color_convert(f, code="BGR2GRAY", target="gpu"))
    g.schedule("heft", n_cpus=1, gpu="warp-cpu")
    out = g.process({"frame": frames[0]}, host=False)
    assert isinstance(out["gray"], wp.array) and str(out["gray"].device) == "cpu"
    dev_in = wp.array(frames[0], dtype=wp.uint8, device="cpu")
    out = g.process({"frame": dev_in})  # device in -> device out
    assert isinstance(out["gray"], wp.array)
    np.testing.assert_array_equal(out["gray"].numpy(), cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY))
    g.close()


# --------------------------------------------------------------------------- communication wrapper


@pytest.mark.timeout(60)
def test_concurrent_readers_and_writers_while_streaming():
    g = warpvx.Graph("wrapper")
    x = g.input("x", shape=(64,), dtype=np.float32)
    y = g.user(lambda v: v * 2, [x], name="double")
    d = g.delay(y, slots=1)
    g.output("y", y)
    g.schedule("heft", n_cpus=2, gpu=False)
    stop = threading.Event()
    seen, errors = [], []

    def reader():
        while not stop.is_set():
            try:
                for v in (g.outputs["y"].read(), d.read(0), d.read(-1)):
                    if v is not None:
                        # A value is one frame's, never torn: all 64 entries equal, even.
                        assert np.all(v == v[0]) and float(v[0]) % 2 == 0
                        seen.append(float(v[0]))
                with x.lock:  # holding the lock delays the executor, never breaks it
                    time.sleep(0.0005)
            except Exception as exc:  # noqa: BLE001 - reported below
                errors.append(exc)
                return

    threads = [threading.Thread(target=reader) for _ in range(3)]
    for t in threads:
        t.start()
    try:
        outs = [o["y"][0] for o in g.stream(({"x": np.full(64, i, np.float32)} for i in range(60)),
                                            depth=3)]
    finally:
        stop.set()
        for t in threads:
            t.join(5)
    assert not errors, errors
    assert outs == [2.0 * i for i in range(60)]
    assert seen and float(g.outputs["y"].read()[0]) == 118.0
    g.close()
