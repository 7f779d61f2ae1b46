"""Graph construction and verify(): one GraphError naming the node and the port per mistake."""

from __future__ import annotations

import numpy as np
import pytest

import warpvx
from warpvx.errors import GraphError
from warpvx.graph import Data, Delay, DelayRef

pytestmark = pytest.mark.timeout(60)

H, W = 96, 128


def _frame_graph():
    g = warpvx.Graph("t")
    f = g.input("frame", shape=(H, W, 3), dtype=np.uint8)
    return g, f


# --------------------------------------------------------------------------- building


def test_smoke_sugar_and_add_are_one_style():
    g, f = _frame_graph()
    a = g.color_convert(f, code="BGR2GRAY")
    b = g.add("color_convert", f, code="BGR2GRAY", name="gray2")
    assert isinstance(a, Data) and isinstance(b, Data)
    assert a.node.kind == b.node.kind == "color_convert"
    assert a.node.name == "color_convert_0" and b.node.name == "gray2"
    assert a.name == "color_convert_0.out"
    assert a.node.inputs == {"src": f}
    assert "color_convert" in dir(g)


def test_multi_output_primitive_returns_one_data_per_port():
    g, f = _frame_graph()
    gray = g.color_convert(f, code="BGR2GRAY")
    pts = g.harris_corners(gray, max_corners=50)
    prev = g.delay(gray)
    nxt, status, err = g.optical_flow_pyr_lk(prev[-1], gray, pts, max_level=1)
    assert [d.port for d in (nxt, status, err)] == ["next_pts", "status", "err"]
    assert nxt.node is status.node
    assert set(nxt.node.inputs) == {"prev", "next", "prev_pts"}


def test_user_node_ports_and_outputs():
    g, f = _frame_graph()

    def split(frame):
        return frame[..., 0], frame[..., 1]

    b, gch = g.user(split, [f], ["blue", "green"], name="split")
    assert g.node("split").inputs == {"frame": f}
    assert (b.port, gch.port) == ("blue", "green")
    one = g.user(lambda a, c: a, {"a": b, "c": gch})
    assert one.port == "out" and set(one.node.inputs) == {"a", "c"}
    assert g.node("split").implementations == frozenset({"cpu"})
    assert g.node("split").exclusive


def test_unknown_primitive_is_a_graph_error():
    g, f = _frame_graph()
    with pytest.raises(GraphError, match="unknown primitive 'colour_convert'"):
        g.add("colour_convert", f, code="BGR2GRAY")
    with pytest.raises(AttributeError):
        g.colour_convert(f)


def test_unknown_argument_names_node_and_port():
    g, f = _frame_graph()
    with pytest.raises(GraphError, match=r"node 'cc' \(color_convert\), port 'bogus'"):
        g.color_convert(f, code="BGR2GRAY", bogus=1, name="cc")
    with pytest.raises(GraphError, match="port 'code'"):
        g.color_convert(f, name="cc2")  # missing required argument


def test_runtime_owned_arguments_are_refused():
    g, f = _frame_graph()
    with pytest.raises(GraphError, match="port 'backend'"):
        g.color_convert(f, code="BGR2GRAY", backend="cpu")


def test_data_of_another_graph_is_refused():
    g, f = _frame_graph()
    g2, _ = _frame_graph()
    with pytest.raises(GraphError, match="another graph"):
        g2.color_convert(f, code="BGR2GRAY")


def test_duplicate_names_are_refused():
    g, f = _frame_graph()
    g.color_convert(f, code="BGR2GRAY", name="gray")
    with pytest.raises(GraphError, match="'gray'"):
        g.color_convert(f, code="BGR2GRAY", name="gray")
    with pytest.raises(GraphError, match="'frame'"):
        g.input("frame")


def test_delay_indexing():
    g, f = _frame_graph()
    gray = g.color_convert(f, code="BGR2GRAY")
    d = g.delay(gray, slots=2)
    assert isinstance(d, Delay) and d[0] is gray
    assert isinstance(d[-1], DelayRef) and d[-2].offset == -2
    with pytest.raises(GraphError, match="outside"):
        d[-3]
    with pytest.raises(GraphError, match="outside"):
        d[1]
    with pytest.raises(GraphError, match="slots"):
        g.delay(f, slots=0)
    with pytest.raises(GraphError, match="already has a delay"):
        g.delay(gray)


def test_pinning_validates_target():
    g, f = _frame_graph()
    gray = g.color_convert(f, code="BGR2GRAY", target="gpu")
    assert gray.node.target == "gpu" and gray.node.processing_elements == {"gpu"}
    u = g.user(lambda x: x, [gray], name="u")
    with pytest.raises(GraphError, match=r"node 'u' \(user\), port 'target'"):
        u.node.target = "gpu"  # no warp_fn: CPU only
    with pytest.raises(GraphError, match="port 'target'"):
        gray.node.target = "tpu"


# --------------------------------------------------------------------------- verify


def test_verify_passes_and_infers_samples(frames):
    g, f = _frame_graph()
    gray = g.color_convert(f, code="BGR2GRAY")
    pyr = g.gaussian_pyramid(gray, levels=3)
    kps = g.fast_corners(gray, threshold=20)
    g.output("kps", kps)
    assert g.verify({"frame": frames[0]}) is g and g.verified
    assert gray.sample.shape == (H, W) and gray.sample.dtype == np.uint8
    assert [lvl.shape for lvl in pyr.sample] == [(96, 128), (48, 64), (24, 32)]
    assert isinstance(kps.sample, warpvx.Keypoints) and len(kps.sample) > 0


def test_verify_type_mismatch_names_node_and_port():
    g, f = _frame_graph()
    g.fast_corners(f, threshold=20, name="fast")  # a BGR frame where gray is expected
    with pytest.raises(GraphError, match=r"node 'fast' \(fast_corners\), port 'src'.*channel"):
        g.verify()


def test_verify_shape_mismatch_names_port():
    g = warpvx.Graph()
    a = g.input("a", shape=(H, W), dtype=np.uint8)
    b = g.input("b", shape=(H // 2, W // 2), dtype=np.uint8)
    pts = g.input("pts", value=np.array([[10.0, 10.0]], np.float32))
    g.optical_flow_pyr_lk(a, b, pts, name="lk")
    with pytest.raises(GraphError, match=r"node 'lk' \(optical_flow_pyr_lk\), port 'next'"):
        g.verify()


def test_verify_bad_constant_names_port():
    g, f = _frame_graph()
    g.color_convert(f, code="NOT_A_CODE", name="cc")
    with pytest.raises(GraphError, match=r"node 'cc'.*port 'code'"):
        g.verify()


def test_verify_dtype_mismatch_of_user_output_feeding_primitive():
    g, f = _frame_graph()
    as_float = g.user(lambda x: x.astype(np.float32), [f], name="to_float")
    g.color_convert(as_float, code="BGR2GRAY", name="cc")
    with pytest.raises(GraphError, match=r"node 'cc'.*port 'src'.*dtype"):
        g.verify()


def test_verify_missing_input():
    g, f = _frame_graph()
    v = g.virtual("never")
    g.user(lambda a, b: a, [f, v], name="reader")
    with pytest.raises(GraphError, match=r"node 'reader' \(user\), port 'b'.*missing input"):
        g.verify()


def test_verify_cycle_names_nodes_and_ports():
    g, f = _frame_graph()
    v = g.virtual("loop")
    a = g.user(lambda x, y: x, [f, v], name="a")
    g.user(lambda x: x, [a], [v], name="b")  # b writes what a reads: a cycle
    with pytest.raises(GraphError, match=r"cycle.*node 'a' port 'y'.*node 'b'"):
        g.verify()


def test_delay_breaks_the_cycle():
    g = warpvx.Graph()
    x = g.input("x", shape=(2,), dtype=np.float32)
    acc = g.virtual("acc")
    prev = g.delay(acc, init=np.zeros(2, np.float32))
    g.user(lambda a, b: a + b, [x, prev[-1]], [acc], name="sum")
    g.output("acc", acc)
    g.verify()


def test_feedback_delay_without_init_is_an_error():
    g = warpvx.Graph()
    x = g.input("x", shape=(2,), dtype=np.float32)
    acc = g.virtual("acc")
    prev = g.delay(acc)
    g.user(lambda a, b: a + b, [x, prev[-1]], [acc], name="sum")
    with pytest.raises(GraphError, match=r"node 'sum'.*port 'b'.*init"):
        g.verify()


def test_verify_input_without_shape():
    g = warpvx.Graph()
    x = g.input("x")
    g.user(lambda a: a, [x])
    with pytest.raises(GraphError, match="input 'x'"):
        g.verify()
    g.verify({"x": np.zeros(3, np.float32)})  # a given sample is enough


def test_verify_output_count_mismatch_names_port():
    g, f = _frame_graph()
    g.user(lambda x: x, [f], ["a", "b"], name="two")
    with pytest.raises(GraphError, match=r"node 'two' \(user\), port 'a'.*2 outputs"):
        g.verify()


def test_verify_user_exception_is_reported_with_node():
    g, f = _frame_graph()

    def broken(x):
        raise RuntimeError("boom")

    g.user(broken, [f], name="broken")
    with pytest.raises(GraphError, match=r"node 'broken'.*RuntimeError.*boom"):
        g.verify()


def test_unproduced_output_is_an_error():
    g, f = _frame_graph()
    g.output("nothing", g.virtual("nothing"))
    with pytest.raises(GraphError, match="output 'nothing'"):
        g.verify()


def test_verify_runs_gpu_pinned_nodes_on_the_given_gpu_backend():
    """A node pinned to the GPU runs its verification on ``verify(gpu=...)``'s backend (its
    Warp implementation, on Warp arrays there); without ``gpu`` its CPU implementation runs."""
    import warp as wp

    calls = []

    def double_cpu(x):
        calls.append("cpu")
        return x * 2

    def double_warp(x):
        calls.append(("warp", str(x.device)))
        return wp.array(x.numpy() * 2, device=x.device)

    def build():
        g = warpvx.Graph("pinned")
        x = g.input("x", shape=(4,), dtype=np.float32)
        y = g.user(double_cpu, [x], "y", warp_fn=double_warp, name="double", target="gpu")
        g.output("y", y)
        return g

    sample = {"x": np.arange(4, dtype=np.float32)}
    build().verify(sample)
    assert calls == ["cpu"]
    calls.clear()
    g = build().verify(sample, gpu="warp-cpu")
    assert calls == [("warp", "cpu")]
    np.testing.assert_array_equal(g.outputs["y"].sample, sample["x"] * 2)
    with pytest.raises(GraphError, match="gpu"):
        build().verify(sample, gpu="cpu")
