"""The stabilizer's device engine (warpvx.apps.stabilize_device) against the graph engine and
the host functions it moves to the device.

Equality: on warp-cpu the device engine gives the graph engine's frames bit for bit on the
bundled real clip (measured: every byte of all 46 frames, centred and causal). Both run the same
Warp kernels on the same points in the same order (RANSAC draws the same samples: the same
seed, the generator limited to the same point count). What may differ, and why the matrices are
compared to 1e-9 and not exactly: the device inverts 3x3 matrices by cofactors, NumPy by LU
(last float64 bits); a difference there could flip the float32 rounding of a sampling matrix
and move some pixels by 1 on some frame. On cuda the same is allowed: 99.9% of the bytes equal
and none off by more than 1 unless a whole re-detection differs (not seen).
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.images import CLIP, bgr, clip_frames, gray
from warpvx import cli
from warpvx.apps import stabilize as st
from warpvx.apps import stabilize_device as sd
from warpvx.errors import WarpvxError


def _device(backend):
    return "cpu" if backend == "warp-cpu" else backend


def _assert_same_frames(graph, device, backend):
    assert [o.index for o in device] == [o.index for o in graph]
    for a, b in zip(graph, device):
        np.testing.assert_allclose(b.trajectory, a.trajectory, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(b.warp, a.warp, rtol=1e-9, atol=1e-9)
        if backend == "warp-cpu":
            np.testing.assert_array_equal(b.image, a.image, err_msg=f"frame {a.index}")
        else:
            diff = np.abs(a.image.astype(int) - b.image)
            assert (diff == 0).mean() >= 0.999 and diff.max() <= 1, f"frame {a.index}"


@pytest.mark.parametrize("mode, window, n", [("centered", 15, None), ("causal", 7, 16)])
def test_device_engine_gives_the_graph_frames(warp_backend, mode, window, n):
    frames = list(st.VideoSource(st.demo_clip())) if n is None else clip_frames(n)
    cfg = st.StabilizerConfig(window=window, mode=mode)
    graph = list(st.stabilize(frames, cfg, backend=warp_backend, engine="graph"))
    device = list(st.stabilize(frames, cfg, backend=warp_backend, engine="device"))
    _assert_same_frames(graph, device, warp_backend)


@pytest.mark.parametrize("mode, window", [("centered", 15), ("causal", 7)])
def test_device_engine_gives_the_graph_frames_across_a_scene_cut(warp_backend, mode, window):
    """Street frames then a shaken real photo: both engines restart the path at the cut."""
    from warpvx.apps import stabilize_metrics as sm

    photo, _, _ = sm.shaky_clip(bgr("astronaut"), 12, (320, 136), seed=1)
    frames = clip_frames(12) + photo
    cfg = st.StabilizerConfig(window=window, mode=mode)
    graph = list(st.stabilize(frames, cfg, backend=warp_backend, engine="graph"))
    device = list(st.stabilize(frames, cfg, backend=warp_backend, engine="device"))
    assert [o.segment for o in device] == [o.segment for o in graph] == [0] * 12 + [1] * 12
    _assert_same_frames(graph, device, warp_backend)


def test_device_engine_undistorts_as_the_graph(warp_backend, bikes):
    K = np.array([[300.0, 0, 160], [0, 300, 68], [0, 0, 1]])
    cfg = st.StabilizerConfig(window=5, camera_matrix=K, dist_coeffs=np.array([-0.2, 0.05, 0, 0]))
    graph = list(st.stabilize(bikes[:8], cfg, backend=warp_backend, engine="graph"))
    device = list(st.stabilize(bikes[:8], cfg, backend=warp_backend, engine="device"))
    _assert_same_frames(graph, device, warp_backend)
    plain = list(st.stabilize(bikes[:8], st.StabilizerConfig(window=5), backend=warp_backend))
    assert np.abs(plain[-1].image.astype(int) - device[-1].image).mean() > 1  # it did undistort


def test_captured_program_replays_the_eager_one(warp_backend):
    """Each ring slot's program captured once and replayed (a CPU capture on warp-cpu, a CUDA
    graph with a conditional node on cuda) gives the eager launches' frames."""
    frames = clip_frames(16)
    cfg = st.StabilizerConfig(window=5)
    plans = []

    def run(use_graph):
        def go(feed, size):
            plans.append(sd.DevicePlan(size, cfg, _device(warp_backend), depth=2, use_graph=use_graph))
            yield from plans[-1].run(feed)
        return [o.image for o in st._drive(frames, cfg, go)]

    eager, captured = run(False), run(True)
    assert all(g is not None for g in plans[1].graphs)  # every slot captured
    for a, b in zip(eager, captured):
        np.testing.assert_array_equal(a, b)


def test_two_plans_at_once_keep_their_own_state(warp_backend, bikes):
    """Two videos of one size stabilized interleaved, frame by frame: each as when alone
    (no scratch shared between plans: the point sets, detections, RANSAC buffers)."""
    cfg = st.StabilizerConfig(window=5)
    a, b = bikes[:8], bikes[8:16][::-1]
    alone = [[o.image for o in st.stabilize(v, cfg, backend=warp_backend)] for v in (a, b)]
    gens = [st.stabilize(v, cfg, backend=warp_backend) for v in (a, b)]
    together = [[], []]
    for outs in zip(*gens):
        for k, o in enumerate(outs):
            together[k].append(o.image)
    for want, got in zip(alone, together):
        for x, y in zip(want, got):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("image, max_corners, quality, min_distance", [
    ("astronaut", 400, 0.001, 8.0), ("coffee", 400, 0.001, 8.0), ("astronaut", 50, 0.01, 25.0),
    ("coffee", 300, 0.01, 0.5),  # below 1 px: no distance suppression
])
def test_device_corners_equal_harris_corners(warp_backend, image, max_corners, quality, min_distance):
    import warp as wp

    from warpvx import harris_corners
    from warpvx.kernels_warp.stabilize_points import DeviceCorners

    src = wp.array(gray(image), dtype=wp.uint8, device=_device(warp_backend))
    want = harris_corners(src, max_corners, quality, min_distance).numpy()
    det = DeviceCorners(src.shape, src.device, max_corners, quality, min_distance)
    for _ in range(2):  # the workspace is reused: a second call starts from a clean rank map
        det.launch(src)
        n = int(det.result.numpy()[0])
        np.testing.assert_array_equal(det.points.numpy()[:n], want)


def test_device_corners_with_few_round_counters(warp_backend, monkeypatch):
    """Batches of 1 round and 3 round counters: on cuda the rounds run out of counters and
    start them again on the device (``capture_while``); on warp-cpu one round decides every
    candidate (its threads run in rank order), so there it checks the one-round batches.
    Either way: harris_corners' points."""
    import warp as wp

    from warpvx import harris_corners
    from warpvx.kernels_warp import harris_corners as hc
    from warpvx.kernels_warp import harris_counted as hcd
    from warpvx.kernels_warp import stabilize_points as kp

    src = wp.array(gray("rocket"), dtype=wp.uint8, device=_device(warp_backend))
    want = harris_corners(src, 400, 0.001, 8.0).numpy()
    monkeypatch.setattr(hc, "MAX_ROUNDS", 3)
    monkeypatch.setattr(hcd, "ROUND_BATCH", 1)
    det = kp.DeviceCorners(src.shape, src.device, 400, 0.001, 8.0)
    det.launch(src)
    n = int(det.result.numpy()[0])
    np.testing.assert_array_equal(det.points.numpy()[:n], want)


def _refresh_on_device(device, next_pts, status, detections, min_tracked, max_corners, min_distance):
    """keep_tracked, merge_fresh (when flagged), pad_points on a P-row buffer; returns the
    first ``count`` rows and the rows after them."""
    import warp as wp

    from warpvx.kernels_warp import stabilize_points as kp

    P = max(max_corners, 4)
    nxt = np.full((P, 2), np.nan, np.float32)
    nxt[:len(next_pts)] = next_pts
    stat = np.zeros(P, np.uint8)
    stat[:len(status)] = status
    fresh = np.zeros((max_corners, 2), np.float32)
    fresh[:len(detections)] = detections
    arr = {k: wp.array(v, device=device) for k, v in
           {"nxt": nxt, "stat": stat, "fresh": fresh,
            "selected": np.int32([len(detections), 0, 0])}.items()}
    points = wp.array(np.full((P, 2), 7.0, np.float32), device=device)
    tracked, count, detect = (wp.zeros(1, dtype=wp.int32, device=device) for _ in range(3))
    wp.launch_tiled(kp.keep_tracked, dim=[1], inputs=[arr["nxt"], arr["stat"], min_tracked,
                                                      max_corners, points, tracked, count, detect],
                    block_dim=kp.BLOCK, device=device)
    if detect.numpy()[0]:
        wp.launch_tiled(kp.merge_fresh, dim=[1], inputs=[arr["fresh"], arr["selected"], tracked,
                                               float(min_distance) ** 2, max_corners, points, count],
                        block_dim=kp.BLOCK, device=device)
    wp.launch(kp.pad_points, P, [count, points], device=device)
    n = int(count.numpy()[0])
    return points.numpy()[:n], points.numpy()[n:]


@pytest.mark.parametrize("seed, n, tracked_share, min_tracked, max_corners", [
    (0, 300, 0.9, 150, 400),  # enough tracked: kept as they are
    (1, 300, 0.3, 150, 400),  # too few: topped up with fresh corners away from them
    (2, 400, 0.2, 150, 400),  # topped up to max_corners exactly
    (3, 6, 0.3, 150, 400),  # fewer than 4 in all: padded with off-image points
    (4, 0, 0.0, 150, 400),  # nothing tracked, no detections: the 4 padding points
    (5, 4, 1.0, 2, 3),  # max_corners under the 4 padded points: tracked cut to it
])
def test_device_refresh_equals_refresh_points(warp_backend, seed, n, tracked_share, min_tracked,
                                              max_corners):
    rng = np.random.default_rng(seed)
    next_pts = rng.uniform(0, 200, (n, 2)).astype(np.float32)
    status = (rng.random(n) < tracked_share).astype(np.uint8)
    next_pts[rng.random(n) < 0.05] = np.nan  # LK's non-finite results are never kept
    detections = np.round(rng.uniform(0, 200, (min(n, max_corners), 2))).astype(np.float32)
    if n == 6:
        detections = detections[:1]
    want = st.refresh_points(next_pts, status, detections, min_tracked=min_tracked,
                             max_corners=max_corners, min_distance=8.0)
    got, rest = _refresh_on_device(_device(warp_backend), next_pts, status, detections,
                                   min_tracked, max_corners, 8.0)
    np.testing.assert_array_equal(got, want)
    assert np.isnan(rest).all()  # rows past the count: NaN, never duplicates of a point


def _random_walk(rng, n):
    """``n`` inter-frame homographies near the identity, with a no-model (zeros), a singular
    and a non-finite one in between."""
    hs = []
    for _ in range(n):
        h = np.eye(3) + rng.normal(0, [[2e-3, 2e-3, 3.0], [2e-3, 2e-3, 3.0], [1e-6, 1e-6, 0]])
        hs.append(h * rng.uniform(0.5, 2.0))
    hs[3], hs[5], hs[7] = np.zeros((3, 3)), np.ones((3, 3)), np.full((3, 3), np.nan)
    return hs


@pytest.mark.parametrize("mode, window, crop", [("centered", 9, 0.1), ("causal", 5, 0.05),
                                                ("centered", 1, 0.0), ("centered", 15, 0.02)])
def test_follow_motion_kernel_equals_the_host_chain(warp_backend, mode, window, crop):
    import warp as wp

    from warpvx.kernels_warp import stabilize_motion as km

    device = _device(warp_backend)
    size = (320, 240)
    cfg = st.StabilizerConfig(window=window, mode=mode, crop=crop)
    slots = max(1, len(cfg.weights()) - 1)
    chain = sd.make_chain(cfg, size, device)
    history = wp.array(np.full((slots, 3, 3), np.nan), dtype=wp.mat33d, device=device)
    segments = wp.zeros(slots, dtype=wp.int32, device=device)
    record = wp.empty(sd.RECORDS, dtype=wp.mat33d, device=device)
    sampling = wp.empty(1, dtype=wp.mat33, device=device)
    host, host_segments = [np.full((3, 3), np.nan)] * slots, [np.zeros(1, np.int64)] * slots
    rng = np.random.default_rng(window)
    walk = _random_walk(rng, 20)
    walk[4] = np.array([[0.6, 0, 150.0], [0, 0.6, 20.0], [0, 0, 1]])  # a scene cut: a jump
    walk[9] = np.array([[1, 0, 0], [0, 1, 0], [-0.01, 0, 1]])  # a cut: corners past infinity
    segment = 0
    for k, h in enumerate(walk):
        live = k < 20 - cfg.lag  # the centred window's flush at the end
        wp.launch(km.follow_motion, 1, [wp.array(h, dtype=wp.float64, device=device),
                                        wp.array([int(live)], dtype=wp.int32, device=device), chain,
                                        history, segments, record, sampling], device=device)
        motion, T, seg, transform, warp = st.follow_motion(
            h, np.uint8([live]), *host, *host_segments, motion_fn=st.as_motion, n_motion=1,
            config=cfg, size=size)
        segment += k in (4, 9)  # the two cuts, and no other frame
        assert seg[0] == segment
        got = record.numpy().reshape(sd.RECORDS, 3, 3)
        for g, w in zip(got, (motion, T, transform, warp)):
            np.testing.assert_allclose(g, w, rtol=1e-10, atol=1e-10, equal_nan=True)
        assert got[4, 0, 0] == segment
        np.testing.assert_allclose(sampling.numpy().reshape(3, 3),
                                   np.linalg.inv(warp).astype(np.float32), rtol=1e-6, atol=1e-6)
        host, host_segments = host[1:] + [T], host_segments[1:] + [seg]


def test_ransac_on_the_first_count_points_equals_find_homography(warp_backend):
    """The sampler limited to ``count`` points draws find_homography's samples on those points:
    the same H bit for bit, whatever fills the buffer after them (NaN rows)."""
    import warp as wp

    from warpvx import find_homography
    from warpvx.kernels_warp.stabilize_points import DeviceRansac

    device = _device(warp_backend)
    rng = np.random.default_rng(3)
    n, P = 137, 400
    src = rng.uniform(0, 640, (n, 2)).astype(np.float32)
    H = np.array([[1.01, 0.02, 5.0], [-0.015, 0.99, -3.0], [1e-5, -2e-5, 1.0]])
    dst = src @ H[:, :2].T + H[:, 2]
    dst = (dst[:, :2] / dst[:, 2:]).astype(np.float32) + rng.normal(0, 0.5, (n, 2)).astype(np.float32)
    dst[rng.random(n) < 0.3] = rng.uniform(0, 640, (1, 2))  # outliers
    want, _ = find_homography(wp.array(src, device=device), wp.array(dst, device=device),
                              ransac_reproj_threshold=3.0, max_iters=500)
    pad = np.full((P - n, 2), np.nan, np.float32)
    out = wp.empty((3, 3), dtype=wp.float64, device=device)
    ransac = DeviceRansac(wp.array(np.vstack([src, pad]), device=device),
                          wp.array(np.vstack([dst, pad]), device=device),
                          wp.array([n], dtype=wp.int32, device=device), 3.0, 500, 0, out)
    ransac.launch()
    np.testing.assert_array_equal(out.numpy(), want.numpy())


def test_device_engine_with_under_four_points_finds_no_model(bikes):
    """min_tracked 2: the kept set may fall under the 4 points a homography needs (the graph
    path refuses it in find_homography); the device engine takes no model (identity) there
    instead of drawing a sample that cannot exist."""
    import warp as wp

    from warpvx.kernels_warp.stabilize_points import DeviceRansac

    pts = wp.array(np.float32([[10, 10], [50, 12], [30, 40], [np.nan, np.nan]]), device="cpu")
    out = wp.array(np.ones((3, 3)), dtype=wp.float64, device="cpu")
    DeviceRansac(pts, pts, wp.array([3], dtype=wp.int32, device="cpu"), 3.0, 50, 0, out).launch()
    assert (out.numpy() == 0).all()
    cfg = st.StabilizerConfig(window=3, min_tracked=2, max_corners=3)
    assert len(list(st.stabilize(bikes[:4], cfg, backend="warp-cpu", engine="device"))) == 4


@pytest.mark.parametrize("kwargs, backend, match", [
    ({"engine": "fastest"}, "warp-cpu", "engine"),
    ({"engine": "device"}, "cpu", "engine"),  # the device engine needs a Warp backend
])
def test_engine_bad_input_names_the_argument(bikes, kwargs, backend, match):
    with pytest.raises(WarpvxError, match=match):
        next(iter(st.stabilize(bikes[:2], st.StabilizerConfig(window=3), backend=backend, **kwargs)))


@pytest.mark.parametrize("field, value", [("motion", "similarity"), ("detector", "fast")])
def test_unsupported_configs_take_the_graph_or_name_it(bikes, field, value):
    cfg = st.StabilizerConfig(window=3, **{field: value})
    assert value in sd.supports(cfg)
    with pytest.raises(WarpvxError, match="engine"):
        next(iter(st.stabilize(bikes[:2], cfg, backend="warp-cpu", engine="device")))
    with pytest.raises(WarpvxError, match="config"):
        sd.DevicePlan((320, 136), cfg, "cpu")
    auto = list(st.stabilize(bikes[:4], cfg, backend="warp-cpu"))  # auto: the graph runs it
    assert len(auto) == 4


def test_device_plan_bad_depth_names_it():
    with pytest.raises(WarpvxError, match="depth"):
        sd.DevicePlan((320, 136), st.StabilizerConfig(), "cpu", depth=0)


def test_auto_engine_on_warp_is_the_device_engine(bikes, monkeypatch):
    made = []
    real = sd.DevicePlan

    def counting(*args, **kwargs):
        made.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(sd, "DevicePlan", counting)
    cfg = st.StabilizerConfig(window=5)
    assert len(list(st.stabilize(bikes[:4], cfg, backend="warp-cpu"))) == 4
    assert len(made) == 1
    list(st.stabilize(bikes[:4], cfg, backend="warp-cpu", engine="graph"))
    list(st.stabilize(bikes[:4], cfg, backend="cpu"))
    assert len(made) == 1


def test_cli_engine_option(tmp_path, capsys):
    out = tmp_path / "out.mp4"
    assert cli.main(["stabilize", CLIP, str(out), "--backend", "warp-cpu", "--engine", "device",
                     "--max-frames", "6", "--window", "3", "--quiet"]) == 0
    assert int(cv2.VideoCapture(str(out)).get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    capsys.readouterr()
    assert cli.main(["stabilize", CLIP, str(out), "--backend", "warp-cpu", "--engine", "device",
                     "--motion", "similarity", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "engine" in err and "similarity" in err


@pytest.mark.parametrize("shape, bands", [((1080, 1920, 3), 4), ((7, 5, 3), 0), ((2, 400000, 3), 2)])
def test_frame_copier_copies_in_bands(shape, bands):
    """Large frames are copied in row bands on the threads (at most one band per row), small
    ones on the calling thread; either way every byte arrives."""
    src = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    copier = sd.FrameCopier(4)
    try:
        dst = np.zeros_like(src)
        handle = copier.start(dst, src)
        assert len(handle) == bands
        copier.wait(handle)
        np.testing.assert_array_equal(dst, src)
        again = copier.copy(src)
        assert not np.shares_memory(again, src)
        np.testing.assert_array_equal(again, src)
    finally:
        copier.close()


def test_frame_copier_bad_shape_names_the_frame():
    with pytest.raises(WarpvxError, match="frame"):
        sd.FrameCopier(2).start(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8))


@pytest.mark.parametrize("src", [np.zeros((4, 4, 3), np.uint16), np.zeros((4, 4, 3)), [[0]]],
                         ids=["uint16", "float64", "list"])
def test_frame_copier_bad_frame_is_a_warpvx_error(src):
    """A frame of another dtype or not an array: refused, not cast or crashing in NumPy."""
    with pytest.raises(WarpvxError, match="frame: expected uint8"):
        sd.FrameCopier(2).start(np.zeros((4, 4, 3), np.uint8), src)


def test_live_steps_after_padding_steps_are_live_again():
    """A padding step (live=False) sets the device flag; the next live step restores it."""
    frame = clip_frames(1)[0]
    plan = sd.DevicePlan(frame.shape[1::-1], st.StabilizerConfig(window=5), "cpu", depth=2)
    plan.submit(frame, live=True)
    plan.submit(None, live=False)
    assert plan.live.numpy()[0] == 0
    plan.submit(frame, live=True)
    assert plan.live.numpy()[0] == 1


def test_staged_and_slot_frames_give_the_copied_frames(warp_backend, bikes):
    """Frames staged ahead (``run``), written straight into ``input_slot()``, or staged and
    then replaced by another frame at ``submit``: the same outputs as frames copied at
    ``submit`` on one thread."""
    cfg = st.StabilizerConfig(window=5)
    frames = bikes[:10]
    size, device = frames[0].shape[1::-1], _device(warp_backend)
    plain = sd.DevicePlan(size, cfg, device, depth=2, copy_threads=1)
    want = [plain.result(plain.submit(f, True))["stabilized"] for f in frames]
    live = np.ones(1, np.uint8)
    staged = [o["stabilized"] for o in sd.DevicePlan(size, cfg, device, depth=2).run(
        {"frame": f, "live": live} for f in frames)]
    plan = sd.DevicePlan(size, cfg, device, depth=2)
    mixed = []
    for k, f in enumerate(frames):
        if k % 2:
            slot = plan.input_slot()
            slot[...] = f
            f = slot
        else:
            plan.stage(frames[-1 - k])  # staged, then not the frame submitted
        mixed.append(plan.result(plan.submit(f, True))["stabilized"])
    for k, (a, b, c) in enumerate(zip(want, staged, mixed)):
        np.testing.assert_array_equal(b, a, err_msg=f"staged, frame {k}")
        np.testing.assert_array_equal(c, a, err_msg=f"slot/replaced, frame {k}")


def test_device_plan_bad_copy_threads_names_it():
    with pytest.raises(WarpvxError, match="copy_threads"):
        sd.DevicePlan((320, 136), st.StabilizerConfig(), "cpu", copy_threads=0)
