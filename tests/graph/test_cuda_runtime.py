"""The executor's CUDA paths (run only where CUDA is present): pinned staging uploads, pooled
timing events, events shared between consecutive GPU tasks, device inputs, pooled output
buffers, and calibration through the executor's path. Results are checked against the
functional API on the same backends."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from warpvx.graph.data import zeros_like

from .helpers import homography

pytestmark = [
    pytest.mark.timeout(120),
    pytest.mark.skipif(not warpvx.cuda_available(), reason="needs CUDA"),
]

SIZE = (320, 240)  # a BGR frame of 225 KiB: uploaded through the pinned staging buffers


@pytest.fixture(scope="module")
def big_frames(frames):
    return [cv2.resize(f, SIZE, interpolation=cv2.INTER_LINEAR) for f in frames]


def build(frames):
    """Crossings both ways, a GPU producer read by a CPU consumer through a delay, a pooled
    GPU output (blur) and one that a delay keeps (gray, level 0 of the delayed pyramid)."""
    g = warpvx.Graph("cuda-parity")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
    pyr = g.gaussian_pyramid(gray, levels=3, name="pyr", target="gpu")
    blur = g.gaussian_blur(gray, ksize=(5, 5), sigma=1.5, name="blur", target="gpu")
    kps = g.fast_corners(blur, threshold=20, name="fast", target="cpu")
    pts = g.harris_corners(gray, max_corners=80, quality_level=0.01, min_distance=5, name="harris",
                           target="gpu")
    prev_pyr, prev_pts = g.delay(pyr), g.delay(pts)
    nxt, status, _ = g.optical_flow_pyr_lk(prev_pyr[-1], pyr, prev_pts[-1], max_level=2, name="lk",
                                           target="gpu")
    H = g.user(homography, [prev_pts[-1], nxt, status], "H", name="H")
    for name, d in [("gray", gray), ("kps", kps), ("pts", pts), ("next", nxt), ("H", H)]:
        g.output(name, d)
    g.verify([{"frame": frames[0]}, {"frame": frames[1]}])
    return g


def expected(frames, pts_init):
    outs, prev_pyr, prev_pts = [], None, pts_init
    for frame in frames:
        gray = warpvx.color_convert(frame, "BGR2GRAY", backend="cuda")
        pyr = warpvx.gaussian_pyramid(gray, 3, backend="cuda")
        blur = warpvx.gaussian_blur(gray, (5, 5), 1.5, backend="cuda")
        kps = warpvx.fast_corners(blur, 20, backend="cpu")
        pts = warpvx.harris_corners(gray, 80, 0.01, 5, backend="cuda")
        if prev_pyr is None:
            prev_pyr = zeros_like(pyr)
        nxt, status, _ = warpvx.optical_flow_pyr_lk(prev_pyr, pyr, prev_pts, max_level=2,
                                                    backend="cuda")
        outs.append(dict(gray=gray, kps=kps, pts=pts, next=nxt, H=homography(prev_pts, nxt, status)))
        prev_pyr, prev_pts = pyr, pts
    return outs


def check(got, want, where):
    for key, w in want.items():
        g = got[key]
        if isinstance(w, warpvx.Keypoints):
            for field in ("x", "y", "response"):
                np.testing.assert_array_equal(getattr(g, field), getattr(w, field), err_msg=f"{where} {key}")
        else:
            np.testing.assert_allclose(g, w, rtol=1e-5, atol=1e-4, err_msg=f"{where} {key}")


@pytest.mark.parametrize("depth", [1, 3])
def test_cuda_graph_equals_functional_api(big_frames, depth):
    g = build(big_frames)
    plan = g.schedule("heft", n_cpus=2, gpu="cuda")
    assert plan.placement["gray"] == "gpu" and plan.placement["fast"].startswith("cpu")
    want = expected(big_frames * 2, zeros_like(g.data["harris.out"].sample))
    if depth == 1:
        got = [g.process({"frame": f}) for f in big_frames * 2]
    else:
        got = list(g.stream(({"frame": f} for f in big_frames * 2), depth=depth))
    for i, (a, b) in enumerate(zip(got, want)):
        check(a, b, f"depth {depth} frame {i}")
    ex = plan.executor()
    assert "blur" in ex._out_pools and "gray" not in ex._out_pools  # a delay may hold gray
    assert len(ex._out_pools["blur"]) <= depth + 1
    # A frame's events go back to the pool once its timeline is read (lazily: the results
    # here are all still held): about one per GPU task, not two.
    for run in plan.last_run:
        assert len(run.timeline) > 0  # builds it (a lazy mapping): its events are read
    gpu_tasks = sum(p == "gpu" for p in plan.placement.values())
    assert 0 < len(ex._events) <= (depth + 1) * (2 * gpu_tasks + 2)
    r = plan.last_run[-1]
    assert r.copied["gray"] == big_frames[0].nbytes  # the frame, through pinned staging
    for t in r.timeline.values():
        assert 0 <= t.start <= t.finish < 1e4
    g.close()


def test_device_inputs_and_device_outputs_on_cuda(big_frames):
    import warp as wp

    g = warpvx.Graph("cuda-dev")
    f = g.input("frame", shape=big_frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", target="gpu", name="gray")
    g.output("gray", gray)
    g.output("blur", g.gaussian_blur(gray, ksize=(3, 3), sigma=0.0, target="cpu", name="blur"))
    g.schedule("heft", n_cpus=1, gpu="cuda")
    for frame in big_frames:
        dev = wp.array(frame, dtype=wp.uint8, device="cuda:0")
        out = g.process({"frame": dev})
        assert isinstance(out["gray"], wp.array) and out["gray"].device.is_cuda
        want = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        np.testing.assert_array_equal(out["gray"].numpy(), want)
        np.testing.assert_array_equal(out["blur"], cv2.GaussianBlur(want, (3, 3), 0))
    g.close()


def test_staged_uploads_are_right_while_buffers_rotate():
    import warp as wp

    from warpvx.runtime import Transfers

    io = Transfers("cuda:0")
    stream = wp.Stream("cuda:0")
    rng = np.random.default_rng(1)
    with wp.ScopedDevice("cuda:0"), wp.ScopedStream(stream, sync_enter=False):
        hosts = [rng.integers(0, 255, (300, 400, 3), dtype=np.uint8) for _ in range(10)]
        devs = [io.upload(h) for h in hosts]  # more than STAGING_DEPTH in flight
        wp.synchronize_stream(stream)
    for h, d in zip(hosts, devs):
        np.testing.assert_array_equal(d.numpy(), h)
    assert len(io._staging[(hosts[0].shape, hosts[0].dtype.str)]) <= Transfers.STAGING_DEPTH
    assert io.moved == sum(h.nbytes for h in hosts)


def test_small_copies_round_trip_through_the_native_path():
    import warp as wp

    from warpvx.keypoints import Keypoints
    from warpvx.runtime import Transfers

    io = Transfers("cuda:0")
    smalls = [np.arange(10, dtype=np.float32).reshape(5, 2), np.arange(7, dtype=np.uint8),
              np.zeros((0, 2), np.float32), np.float64([1.5, -2.0]), np.array([True, False])]
    with wp.ScopedDevice("cuda:0"):
        devs = io.upload(smalls)
        wp.synchronize_device("cuda:0")
        assert all(d.device.is_cuda for d in devs)
        back = io.download(devs)
    for h, b in zip(smalls, back):
        assert b.dtype == h.dtype and b.shape == h.shape
        np.testing.assert_array_equal(b, h)
    kp = Keypoints.from_cv([cv2.KeyPoint(3.5, 4.5, 7.0, 30.0, 0.5, 1)]).to("cuda:0")
    got = io.download(kp)
    assert isinstance(got, Keypoints) and float(got.x[0]) == 3.5 and int(got.octave[0]) == 1
    vecs = wp.array(np.ones((4, 2), np.float32), dtype=wp.vec2, device="cuda:0")
    np.testing.assert_array_equal(io.download(vecs), np.ones((4, 2), np.float32))  # Warp's path


def test_calibration_times_gpu_nodes_with_events(big_frames, tmp_path, monkeypatch):
    monkeypatch.setenv("WARPVX_CACHE_DIR", str(tmp_path))
    g = warpvx.Graph("cuda-cal")
    f = g.input("frame", shape=big_frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray")
    g.output("kps", g.fast_corners(gray, threshold=20, name="fast"))
    c = g.calibrate(gpu="cuda", repeats=3)
    for node in ("gray", "fast"):
        t = c.nodes[node]
        assert t["gpu"] > 0 and t["gpu_host"] > 0
        # The device interval spans the call: it cannot end before the host finished
        # enqueueing (up to timer resolution).
        assert t["gpu"] >= 0.5 * t["gpu_host"]
    d = c.dispatch
    assert d["gpu_node"] > 0 and d["handoff"] >= 0
    g.close()


# ----------------------------------------------------------------- pooled uploads (no kernels)


def _plus_one(v):
    return v + np.float32(1)


def _twice(v):
    return v * np.float32(2)


def _upload_chain(seen, *, delayed=False):
    """x -> CPU +1 -> GPU identity (returns the uploaded buffer itself, recording its address
    in ``seen``) -> CPU *2. The GPU node's value is a graph output too (so its upload buffer
    is what the caller gets on the device), or, ``delayed``, read one frame later."""

    def gpu_identity(v):
        seen.append(v.ptr)
        return v

    g = warpvx.Graph("cuda-uploads")
    x = g.input("x", shape=(3, 5), dtype=np.float32)
    a = g.user(_plus_one, [x], name="a", target="cpu")
    b = g.user(None, [a], warp_fn=gpu_identity, name="b", target="gpu")
    if delayed:
        g.output("prev", g.user(_twice, [g.delay(b)[-1]], name="p", target="cpu"))
    else:
        g.output("b", b)
    g.output("c", g.user(_twice, [b], name="c", target="cpu"))
    return g


def _xs(n):
    return [np.arange(15, dtype=np.float32).reshape(3, 5) + 100 * i for i in range(n)]


def test_pooled_uploads_reuse_one_buffer_and_stay_right_when_pipelined():
    seen = []
    g = _upload_chain(seen)
    plan = g.schedule("heft", n_cpus=1, gpu="cuda")
    ex = plan.executor()
    xs = _xs(12)
    seen.clear()
    for x in xs[:4]:  # one frame at a time: the same device buffer every frame
        out = g.process({"x": x})
        np.testing.assert_array_equal(out["b"], x + 1)
        np.testing.assert_array_equal(out["c"], (x + 1) * 2)
    assert len(set(seen)) == 1
    [key] = ex._up_pools
    assert ex._upload_rule[key] == "host"  # the buffer reaches a graph output
    for i, (x, out) in enumerate(zip(xs, g.stream(({"x": x} for x in xs), depth=3))):
        np.testing.assert_array_equal(out["b"], x + 1, err_msg=f"frame {i}")
        np.testing.assert_array_equal(out["c"], (x + 1) * 2, err_msg=f"frame {i}")
    assert 1 <= len(ex._up_pools[key]) <= 4
    g.close()


def test_pooled_uploads_handed_to_the_caller_on_the_device_are_never_reused():
    import warp as wp

    seen = []
    g = _upload_chain(seen)
    g.schedule("heft", n_cpus=1, gpu="cuda")
    xs = _xs(5)
    seen.clear()
    outs = [g.process({"x": x}, host=False) for x in xs]
    assert len(set(seen)) == len(xs)
    for x, out in zip(xs, outs):  # later frames did not write into the earlier outputs
        assert isinstance(out["b"], wp.array)
        np.testing.assert_array_equal(out["b"].numpy(), x + 1)
        np.testing.assert_array_equal(out["c"], (x + 1) * 2)
    g.close()


def test_uploads_a_delay_may_keep_are_reused_only_once_the_delay_lets_their_frame_go():
    seen = []
    g = _upload_chain(seen, delayed=True)
    plan = g.schedule("heft", n_cpus=1, gpu="cuda")
    ex = plan.executor()
    xs = _xs(12)
    seen.clear()
    outs = list(g.stream(({"x": x} for x in xs), depth=3))
    [key] = ex._up_pools
    assert ex._upload_rule[key] == "ring"
    assert len(seen) == len(xs) and len(set(seen)) < len(xs)  # reused...
    # ...never under a value a frame in flight or the delay may hold: frame i's buffer is
    # free once frame i + 2 was waited for (the delay keeps frames i + 1 and i + 2)
    assert all(seen[i] not in seen[max(0, i - 2):i] for i in range(1, len(xs)))
    np.testing.assert_array_equal(outs[0]["prev"], np.zeros((3, 5), np.float32))
    for i in range(1, len(xs)):
        np.testing.assert_array_equal(outs[i]["prev"], (xs[i - 1] + 1) * 2, err_msg=f"frame {i}")
        np.testing.assert_array_equal(outs[i]["c"], (xs[i] + 1) * 2)
    g.close()
