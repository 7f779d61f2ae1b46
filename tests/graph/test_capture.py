"""Captured GPU segments (warpvx.runtime.capture): the segmenter's rule on hand-built
programs, and captured runs against eager runs on real frames.

Warp 1.19 captures on its CPU device too, so every run test runs on warp-cpu with
``capture=True`` (the default there is off) and, where CUDA is present, on cuda with the
default (on).
"""

from __future__ import annotations


import numpy as np
import pytest

import warpvx
from warpvx.runtime import ExecTask, InputRef, Program, Ring
from warpvx.runtime.capture import segments
from tests.benchmark_scripts import load_bench
from tests.isolated import run_python

pytestmark = pytest.mark.timeout(300)

# --------------------------------------------------------------------------- the segmenter


def _task(name, inputs, *, capture=True, out=True):
    refs = tuple(r if isinstance(r, InputRef) else InputRef(r) for r in inputs)
    return ExecTask(name, refs, (name,), cpu=None, gpu=lambda *v, out=None: v[0],
                    gpu_out=(lambda: None) if out else None, capture=capture)


def _program(tasks, outputs=(), rings=()):
    return Program({t.name: t for t in tasks}, ("x",), {k: k for k in outputs},
                   {k: Ring(1, None) for k in rings})


def _shape(segs):
    return [([t.name for t in s.tasks], s.captured) for s in segs]


def test_segments_gpu_chain_is_one_segment():
    p = _program([_task("a", ["x"]), _task("b", ["a"]), _task("c", ["b"])], outputs=["c"])
    (seg,) = segments(p, ["a", "b", "c"])
    assert _shape([seg]) == [(["a", "b", "c"], True)]
    assert seg.inputs == (InputRef("x"),)
    assert seg.outputs == ("c",)  # a and b stay inside


def test_segments_uncapturable_task_runs_alone_and_cuts():
    p = _program([_task("a", ["x"]), _task("b", ["a"], capture=False), _task("c", ["b"]),
                  _task("d", ["c"], out=False), _task("e", ["d"])], outputs=["e"])
    segs = segments(p, ["a", "b", "c", "d", "e"])
    assert _shape(segs) == [(["a"], True), (["b"], False), (["c"], True), (["d"], False),
                            (["e"], True)]
    assert segs[0].outputs == ("a",)  # read by the eager task b
    assert segs[2].inputs == (InputRef("b"),)


def test_segments_cut_at_cpu_hand_offs():
    cpu = ExecTask("h", (InputRef("a"),), ("h",), cpu=lambda v: v)
    # c reads the CPU task's output (a hand-off): a new segment; d reads it a frame late:
    # also a hand-off.
    p = _program([_task("a", ["x"]), _task("b", ["a"]), cpu, _task("c", ["b", "h"]),
                  _task("d", ["c", InputRef("h", -1)])], outputs=["d"], rings=["h"])
    segs = segments(p, ["a", "b", "c", "d"])
    assert _shape(segs) == [(["a", "b"], True), (["c"], True), (["d"], True)]
    assert segs[0].outputs == ("a", "b")  # a goes to the CPU task, b to the next segment
    assert segs[1].inputs == (InputRef("b"), InputRef("h"))
    assert segs[2].inputs == (InputRef("c"), InputRef("h", -1))


def test_segments_own_delay_stays_in_the_segment_swapped():
    p = _program([_task("a", ["x"]), _task("b", ["a", InputRef("b", -1)]), _task("c", ["b"])],
                 outputs=["a"], rings=["b"])
    (seg,) = segments(p, ["a", "b", "c"])
    assert seg.inputs == (InputRef("x"), InputRef("b", -1))
    # a: a graph output; b: delayed, read only by the segment one frame back, so it stays in
    # the buffer set its frame wrote (no copy out); c is read by nobody.
    assert seg.outputs == ("a",)
    assert seg.swapped == (InputRef("b", -1),)


def test_segments_delayed_values_read_elsewhere_leave_the_segment():
    """A delay read by a task outside the segment, as a graph output, or further back than
    one frame is copied out; the segment's own one-frame-back read is still swapped."""
    for outside, outputs, back in ((["b"], (), -1), ([], ["b"], -1), ([], (), -2)):
        tasks = [_task("a", ["x"]), _task("b", ["a", InputRef("b", back)])]
        tasks += [_task("eager", [InputRef("b", -1)], capture=False) for _ in outside]
        p = _program(tasks, outputs=outputs, rings=["b"])
        seg = segments(p, ["a", "b"] + ["eager"] * bool(outside))[0]
        assert seg.outputs == ("b",), (outside, outputs, back)
        assert seg.swapped == ((InputRef("b", -1),) if back == -1 else ())


# --------------------------------------------------------------------------- runs


def _capture_arg(gpu):
    """warp-cpu captures only when asked; cuda by default."""
    return True if gpu == "warp-cpu" else None


def _same(a, b):
    if isinstance(a, (list, tuple)):  # a pyramid's levels
        return type(a) is type(b) and len(a) == len(b) and all(map(_same, a, b))
    flat = getattr(a, "__warpvx_flatten__", None)
    if flat is not None:
        (xa, _), (xb, _) = flat(), b.__warpvx_flatten__()
        return all(_same(u, v) for u, v in zip(xa, xb))
    ha = a.numpy() if hasattr(a, "numpy") and not isinstance(a, np.ndarray) else np.asarray(a)
    hb = b.numpy() if hasattr(b, "numpy") and not isinstance(b, np.ndarray) else np.asarray(b)
    return ha.shape == hb.shape and ha.dtype == hb.dtype and np.array_equal(ha, hb)


def _camera_frames(frames):
    """Two-camera frames from the real photo: the right camera sees it mirrored."""
    return [{"frameL": f, "frameR": np.ascontiguousarray(f[:, ::-1])} for f in frames]


def _two_cameras(frames, gpu):
    bench = load_bench("graph_bench")
    h, w = frames[0].shape[:2]
    g = bench.build_graph((w, h), max_corners=100)
    g.verify(_camera_frames(frames)[:2])
    g.schedule("baseline", n_cpus=2, gpu=gpu)
    return g


def test_two_cameras_captured_equals_eager(frames, warp_backend):
    """The 16-node graph on real frames: captured segments give the eager run's outputs,
    each segment is captured once and replayed after."""
    cams = _camera_frames(frames) * 2
    g = _two_cameras(frames, warp_backend)
    try:
        eager = [g.process(f, capture=False) for f in cams]
        assert g.plan.executor().captures == 0
        g.reset()
        ex = g.plan.executor()
        ex.instances = 1  # two sets, alternating (the rule this test counts frames by)
        captured_segments = sum(s.captured for s in ex._segments)
        # Every GPU node, data-dependent ones included (corners, keypoints: Counted outputs),
        # and the detector user node that opts in.
        in_captured = {t.name for s in ex._segments if s.captured for t in s.tasks}
        assert in_captured == {t.name for s in ex._segments for t in s.tasks} == \
            {f"{n}{c}" for n in ("gray", "pyramid", "harris", "blur", "fast", "lk")
             for c in "LR"} | {"detectorL"}
        got = [g.process(f, capture=_capture_arg(warp_backend)) for f in cams]
        # Frame 0 reads the delays' initial points (a plain array); from frame 1 on, the
        # corners are Counted (fixed rows): one shape whatever the corner counts. Its two
        # buffer sets (the delays swap between them) run uncaptured (frames 1-3: the first
        # set twice, the second time reading the second set's buffers as its capture
        # will), are captured (frames 4, 5) and replayed (6, 7).
        assert ex.captures == captured_segments
        (seg,) = [s for s in ex._segments if s.captured]
        assert {r.key for r in seg.swapped} == {f"{n}{c}.out" for n in ("pyramid", "harris")
                                                for c in "LR"}
        # The pyramids stay in their buffer set; the corners leave it (a CPU node reads them).
        assert not {"pyramidL.out", "pyramidR.out"} & set(seg.outputs)
        assert {"harrisL.out", "harrisR.out"} <= set(seg.outputs)
        i = ex._segments.index(seg)
        (sg,) = [sg for states in ex._captured.values() for sg in states[i].values()
                 if sg is not None and sg.captured]
        assert all(b.graph is not None for b in sg.sets) and len(sg.sets) == 2
        for e, c in zip(eager, got):
            assert e.keys() == c.keys()
            for k in e:
                assert _same(e[k], c[k]), k
        # Timelines still name every node, captured ones inside their replay's interval.
        assert set(g.plan.last_run[-1].timeline) == set(g.nodes)
    finally:
        g.close()


def test_two_cameras_pyramids_and_flow_are_captured_with_the_grays(frames, warp_backend):
    """Pyramids (a list of levels) and LK (three outputs) join captured segments with their
    neighbours (the grays, the blurs: the schedule's order decides), and are replayed."""
    g = _two_cameras(frames, warp_backend)
    try:
        ex = g.plan.executor()
        captured = {t.name: i for i, s in enumerate(ex._segments) if s.captured
                    for t in s.tasks}
        assert {"pyramidL", "pyramidR", "lkL", "lkR"} <= set(captured)
        assert len(ex._segments[captured["lkL"]].tasks) > 1
        for f in _camera_frames(frames)[:2]:
            g.process(f, capture=_capture_arg(warp_backend))
        states = next(iter(ex._captured.values()))
        for name in ("pyramidL", "lkL"):
            assert any(type(sg).__name__ == "SegmentGraph"
                       for sg in states[captured[name]].values()), name
    finally:
        g.close()


def _flow_graph(frames, gpu, n_points):
    """gray -> pyramid (delayed) -> LK of ``pts`` (a graph input) on the GPU role."""
    g = warpvx.Graph("flow")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    pts = g.input("pts", shape=(None, 2), dtype=np.float32)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
    pyr = g.gaussian_pyramid(gray, levels=3, name="pyr", target="gpu")
    prev = g.delay(pyr, slots=1)
    nxt, status, err = g.optical_flow_pyr_lk(prev[-1], pyr, pts, win_size=(15, 15), max_level=2,
                                             name="lk", target="gpu")
    for name, d in (("next", nxt), ("status", status), ("err", err), ("pyr", pyr)):
        g.output(name, d)
    g.verify([{"frame": frames[0], "pts": n_points}, {"frame": frames[1], "pts": n_points}])
    g.schedule("baseline", n_cpus=1, gpu=gpu)
    return g


def test_eager_frame_between_replays_refills_the_swapped_delay(frames, warp_backend):
    """A frame run eagerly between replays leaves its own pyramid in the delay (same shapes,
    so the next frame replays): that replay copies it into its buffer set instead of reading
    the set the last replay wrote (an older frame's), and every output equals the eager
    run's."""
    rng = np.random.default_rng(5)
    h, w = frames[0].shape[:2]
    pts = (rng.random((24, 2)) * [w - 20, h - 20] + 10).astype(np.float32)
    feed = [{"frame": f, "pts": pts} for f in frames * 3]
    g = _flow_graph(frames, warp_backend, pts)
    try:
        eager = [g.process(x, capture=False) for x in feed]
        g.reset()
        ex = g.plan.executor()
        cap = _capture_arg(warp_backend)
        got = [g.process(x, capture=False if i in (7, 9) else cap) for i, x in enumerate(feed)]
        assert ex.captures == 1 and ex._segments[0].swapped
        for i, (e, c) in enumerate(zip(eager, got)):
            for k in e:
                assert _same(e[k], c[k]), (i, k)
    finally:
        g.close()


def test_segment_inputs_of_another_shape_run_eagerly_then_replay(frames, warp_backend):
    """LK's points change count from frame to frame: a count other than verification's
    runs eagerly (its out= buffers do not fit), verification's count replays its capture;
    every output (LK's three, the pyramid's levels) equals the eager run's."""
    rng = np.random.default_rng(3)
    h, w = frames[0].shape[:2]

    def points(n):
        return (rng.random((n, 2)) * [w - 20, h - 20] + 10).astype(np.float32)

    feed = [{"frame": f, "pts": points(n)} for f, n in zip(frames * 3, [24, 24, 31, 24, 31, 24,
                                                                     24, 24, 17, 24, 24, 24])]
    g = _flow_graph(frames, warp_backend, points(24))
    try:
        eager = [g.process(x, capture=False) for x in feed]
        g.reset()
        ex = g.plan.executor()
        got = [g.process(x, capture=_capture_arg(warp_backend)) for x in feed]
        assert ex.captures == 1  # 24 points only; 31 and 17 do not fit the out= buffers
        for e, c in zip(eager, got):
            for k in e:
                assert _same(e[k], c[k]), k
        # The replay reads the frames' own points: the pyramid's delayed copy and LK tracked
        # as the public function does.
        x = feed[-1]
        prev_pyr = warpvx.gaussian_pyramid(warpvx.color_convert(feed[-2]["frame"],
                                                                code="BGR2GRAY"), 3)
        pyr = warpvx.gaussian_pyramid(warpvx.color_convert(x["frame"], code="BGR2GRAY"), 3)
        ref = warpvx.optical_flow_pyr_lk(prev_pyr, pyr, x["pts"], win_size=(15, 15),
                                         max_level=2, backend=warp_backend)
        for k, r in zip(("next", "status", "err"), ref):
            np.testing.assert_array_equal(got[-1][k], r)
    finally:
        g.close()


@pytest.mark.parametrize("max_corners,min_distance,captured", [
    (30, 5.0, True),
    (10**9, 5.0, False),  # no limit (>= H*W): no capacity, the node runs eagerly
    (50, 1e6, True),      # beyond the diagonal: the strongest corner alone (capacity 1)
])
def test_corners_node_capacity_follows_the_public_limits(frames, warp_backend, max_corners,
                                                        min_distance, captured):
    """A corners node's Counted capacity is the limit harris_corners computes: its outputs,
    captured or not, are the public function's."""
    g = warpvx.Graph("corners")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
    g.output("pts", g.harris_corners(gray, max_corners=max_corners, quality_level=0.01,
                                     min_distance=min_distance, name="corners", target="gpu"))
    g.verify({"frame": frames[0]})
    g.schedule("baseline", n_cpus=1, gpu=warp_backend)
    try:
        for fr in frames:
            want = warpvx.harris_corners(warpvx.color_convert(fr, code="BGR2GRAY"), max_corners,
                                         0.01, min_distance)
            np.testing.assert_array_equal(
                g.process({"frame": fr}, capture=_capture_arg(warp_backend))["pts"], want)
        ex = g.plan.executor()
        assert [s.captured for s in ex._segments] == ([True] if captured else [True, False])
        assert ex.captures == 1  # the gray alone when the corners run eagerly
    finally:
        g.close()


def test_two_cameras_replay_again_after_a_reset(frames, warp_backend):
    """After a reset the first frame reads the delays' initial points (a plain array, unlike
    the Counted corners the captured graph swaps in): that frame runs eagerly and every later
    frame replays again, with the eager run's outputs. (The whole segment used to run eagerly
    from then on: a pipelined captured stream after a reset was no faster than eager.)"""
    cams = _camera_frames(frames) * 2
    g = _two_cameras(frames, warp_backend)
    cap = _capture_arg(warp_backend)
    try:
        eager = [g.process(f, capture=False) for f in cams]
        ex = g.plan.executor()
        for _ in range(2):  # the initial value's shapes sighted twice, the second time
            g.reset()       # against buffers holding the graph's own Counted corners
            got = [g.process(f, capture=cap) for f in cams]
        replays = ex.replays
        g.reset()
        got = list(g.stream(cams, depth=3, capture=cap))
        # Frame 0 eager (initial points), frames 1.. replayed: no new capture needed.
        assert ex.replays - replays == len(cams) - 1
        for e, c in zip(eager, got):
            for k in e:
                assert _same(e[k], c[k]), k
    finally:
        g.close()


def test_two_cameras_pipelined_captured_equals_eager(frames, warp_backend):
    cams = _camera_frames(frames) * 2
    g = _two_cameras(frames, warp_backend)
    try:
        eager = list(g.stream(cams, depth=3, capture=False))
        g.reset()
        got = list(g.stream(cams, depth=3, capture=_capture_arg(warp_backend)))
        assert g.plan.executor().captures > 0
        for e, c in zip(eager, got):
            for k in e:
                assert _same(e[k], c[k]), k
    finally:
        g.close()


def test_delayed_values_buffers_go_back_to_their_pools_once_the_delays_let_go(frames,
                                                                              warp_backend):
    """The copies out of values a delay holds (pyramids, corners) are reused once every
    delay has aged past their frame: a steady captured stream allocates no device buffer,
    and its outputs (which read those delayed values) equal the eager run's, pipelined."""
    cams = _camera_frames(frames) * 4
    g = _two_cameras(frames, warp_backend)
    cap = _capture_arg(warp_backend)
    try:
        eager = list(g.stream(cams, depth=3, capture=False))
        g.reset()
        ex = g.plan.executor()
        got = list(g.stream(cams, depth=3, capture=cap))
        for e, c in zip(eager, got):
            for k in e:
                assert _same(e[k], c[k]), k
        # Frames one at a time: how many buffers are out at once does not depend on thread
        # timing (pipelined, the pools may grow late to a new peak), so none after the first
        # half, against two or more a frame when a delay's buffers are not reused.
        g.reset()
        fresh = []
        for _ in g.stream(cams, depth=1, capture=cap):
            fresh.append(ex.fresh_buffers)
        assert ex.captures > 0 and ex.replays > len(cams)
        warm = len(cams) // 2
        assert fresh[warm] == fresh[-1], fresh
    finally:
        g.close()


def _blur_chain(frames, gpu, shape=None):
    """gray -> blur -> blur on the GPU role (one segment), any frame size (None dims)."""
    g = warpvx.Graph("chain")
    f = g.input("frame", shape=(None, None, 3), dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
    b1 = g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="b1", target="gpu")
    b2 = g.gaussian_blur(b1, ksize=(3, 3), sigma=0.8, name="b2", target="gpu")
    g.output("out", b2)
    g.verify({"frame": frames[0]})
    g.schedule("baseline", n_cpus=1, gpu=gpu)
    return g


def _blur_reference(frame):
    import cv2

    gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    return cv2.GaussianBlur(cv2.GaussianBlur(gray, (5, 5), 1.2), (3, 3), 0.8)


def test_other_shape_runs_eagerly_then_replays(frames, warp_backend):
    """Another frame size is another signature: its nodes' out= buffers are sized by
    verification, so they run eagerly (correct, no error); back at the first size the
    first capture replays without a new one."""
    g = _blur_chain(frames, warp_backend)
    cap = _capture_arg(warp_backend)
    small = [np.ascontiguousarray(f[: f.shape[0] // 2, : f.shape[1] // 2]) for f in frames]
    try:
        ex = g.plan.executor()
        for f in frames[:3]:
            np.testing.assert_array_equal(g.process(f, capture=cap)["out"], _blur_reference(f))
        assert ex.captures == 1
        for f in small * 2:
            np.testing.assert_array_equal(g.process(f, capture=cap)["out"], _blur_reference(f))
        assert ex.captures == 1
        for f in frames:
            np.testing.assert_array_equal(g.process(f, capture=cap)["out"], _blur_reference(f))
        assert ex.captures == 1
    finally:
        g.close()


def test_capture_is_off_by_default_on_warp_cpu(frames):
    g = _blur_chain(frames, "warp-cpu")
    try:
        for f in frames:
            np.testing.assert_array_equal(g.process(f)["out"], _blur_reference(f))
        assert g.plan.executor().captures == 0
    finally:
        g.close()


@pytest.mark.parametrize("bad", ["yes", 1, 0.0])
def test_capture_must_be_a_bool_or_none(frames, bad):
    g = _blur_chain(frames, "warp-cpu")
    try:
        with pytest.raises(warpvx.WarpvxTypeError, match="capture: expected a bool or None"):
            g.process(frames[0], capture=bad)
        with pytest.raises(warpvx.WarpvxTypeError, match="capture"):
            list(g.stream(frames[:2], capture=bad))
        np.testing.assert_array_equal(g.process(frames[0])["out"], _blur_reference(frames[0]))
    finally:
        g.close()


def test_capture_inside_a_callers_capture_falls_back(frames):
    """A frame run while Warp is already capturing on the device: the executor's capture
    fails (nested) and its segments run eagerly: no error, right outputs."""
    wp = warpvx.backend.init_warp()
    g = _blur_chain(frames, "warp-cpu")
    try:
        ex = g.plan.executor()
        g.process(frames[0], capture=True)  # the eager first sighting
        with wp.ScopedCapture(device="cpu"):
            # The GPU thread's capture is refused (one capture at a time on Warp's CPU
            # device); the frame's kernels are recorded into the caller's capture instead.
            g.process(frames[1], capture=True)
        assert ex.captures == 0
    finally:
        g.close()


def test_cancelled_stream_then_captured_frames(frames, warp_backend):
    """Closing a stream with captured frames in flight cancels them without a hang; the
    graph runs (and replays) correctly after."""
    g = _blur_chain(frames, warp_backend)
    cap = _capture_arg(warp_backend)
    try:
        s = g.stream(frames * 3, depth=4, capture=cap)
        np.testing.assert_array_equal(next(s)["out"], _blur_reference(frames[0]))
        next(s)
        s.close()
        assert g.plan.executor().in_flight == 0
        for f in frames:
            np.testing.assert_array_equal(g.process(f, capture=cap)["out"], _blur_reference(f))
        assert g.plan.executor().captures == 1
    finally:
        g.close()


ERROR_SNIPPET = """
import numpy as np, warpvx
from tests.images import bgr
from warpvx.errors import NodeExecutionError
frame = np.ascontiguousarray(bgr("astronaut")[:96, :128])
calls, armed = [], []
def check(b):
    calls.append(1)
    if armed and len(calls) == 4:
        raise ValueError("boom in a CPU node")
    return float(b.mean())
g = warpvx.Graph("err")
f = g.input("frame", shape=frame.shape, dtype=np.uint8)
gray = g.color_convert(f, code="BGR2GRAY", name="gray", target="gpu")
blur = g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="blur", target="gpu")
g.output("m", g.user(check, [blur], "m", name="check"))
g.verify({"frame": frame})
g.schedule("baseline", n_cpus=1, gpu=GPU)
calls.clear()
armed.append(True)
try:
    for _ in g.stream([frame] * 8, depth=3, capture=CAPTURE):
        pass
except NodeExecutionError as e:
    assert isinstance(e.__cause__, ValueError), e
    print("raised", g.plan.executor().captures)
out = g.process(frame, capture=CAPTURE)["m"]
print("after", out == float(warpvx.gaussian_blur(warpvx.color_convert(frame, code="BGR2GRAY"),
                                                 ksize=(5, 5), sigma=1.2).mean()))
g.close()
"""


def test_error_in_cpu_node_reaches_caller_without_hang(warp_backend):
    code = ERROR_SNIPPET.replace("GPU", repr(warp_backend)).replace(
        "CAPTURE", repr(_capture_arg(warp_backend)))
    res = run_python(code, timeout=240)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.split("\n")
    assert "raised 1" in lines, res.stdout  # the gray+blur segment was captured, then the error
    assert "after True" in lines, res.stdout


@pytest.mark.parametrize("native", [True, False])
def test_copy_device_copies_the_bytes(warp_backend, native):
    """The copy a captured segment uses in and out of its fixed buffers: native entry point
    and Warp's public fallback give the source's bytes."""
    from warpvx.backend import resolve_backend
    from warpvx.runtime.native_copy import copy_device

    wp = warpvx.backend.init_warp()
    device = resolve_backend(warp_backend).device
    host = np.random.default_rng(5).random((7, 9)).astype(np.float32)
    src = wp.array(host, device=device)
    dst = wp.zeros_like(src)
    copy_device(dst, src, native=native)
    np.testing.assert_array_equal(dst.numpy(), host)
