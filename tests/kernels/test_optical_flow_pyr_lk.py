"""Pyramidal Lucas-Kanade: warpvx.optical_flow_pyr_lk, build_optical_flow_pyramid, warpvx.cv.

Parity bar (SPEC §4): against cv2.calcOpticalFlowPyrLK on real frames, points lost that
OpenCV tracks at most 5% of those it tracks; points more than 2 px from OpenCV's at most 10%.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import cv as wcv
from tests.images import gray
from warpvx.arrays import to_numpy as _np
from tests.cv.fallback import runs_on_cv2

DATA = Path(__file__).resolve().parent.parent / "data"
CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)


@functools.lru_cache(maxsize=None)
def _basketball():
    """Two consecutive real video frames (OpenCV samples), gray 640x480."""
    a = cv2.imread(str(DATA / "basketball1.png"), cv2.IMREAD_GRAYSCALE)
    b = cv2.imread(str(DATA / "basketball2.png"), cv2.IMREAD_GRAYSCALE)
    return a, b


@functools.lru_cache(maxsize=None)
def _camera_shifted(dx=3.4, dy=-2.7):
    """The camera photo and a copy translated by a known subpixel shift (bilinear)."""
    cam = gray("camera")
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    moved = cv2.warpAffine(cam, m, (cam.shape[1], cam.shape[0]), flags=cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_REFLECT_101)
    return cam, moved, np.float32([dx, dy])


def _corners(img, n=400, min_distance=7):
    return cv2.goodFeaturesToTrack(img, n, 0.01, min_distance).reshape(-1, 2).astype(np.float32)


def _opencv(prev, nxt, pts, guess=None, win=(21, 21), max_level=3, criteria=CRITERIA, min_eig=1e-4):
    flags = 0 if guess is None else cv2.OPTFLOW_USE_INITIAL_FLOW
    g = None if guess is None else guess.reshape(-1, 1, 2).copy()
    p, s, e = cv2.calcOpticalFlowPyrLK(prev, nxt, pts.reshape(-1, 1, 2), g, winSize=win, maxLevel=max_level,
                                       criteria=criteria, flags=flags, minEigThreshold=min_eig)
    return p.reshape(-1, 2), s.ravel(), e.ravel()


def _assert_parity(ours, ref, *, max_lost=0.05, max_far=0.10):
    """SPEC §4's bar; returns (lost share, far share, median distance) for the record."""
    p, s, _ = ours
    rp, rs, _ = ref
    tracked = rs == 1
    assert tracked.sum() > 0
    lost = np.mean(s[tracked] == 0)
    both = tracked & (s == 1)
    dist = np.linalg.norm(p[both] - rp[both], axis=1)
    far = np.mean(dist > 2.0)
    assert lost <= max_lost, f"lost {lost:.1%} of the points OpenCV tracks"
    assert far <= max_far, f"{far:.1%} of points more than 2 px from OpenCV's"
    return lost, far, float(np.median(dist))




# --------------------------------------------------------------------------------------------
# smoke


def test_smoke(backend):
    a, b = _basketball()
    pts = _corners(a, 50)
    p, s, e = warpvx.optical_flow_pyr_lk(a, b, pts, backend=backend)
    assert isinstance(p, np.ndarray) and p.dtype == np.float32 and p.shape == (len(pts), 2)
    assert s.dtype == np.uint8 and s.shape == (len(pts),)
    assert e.dtype == np.float32 and e.shape == (len(pts),)
    assert s.sum() > 0.9 * len(pts)
    assert np.all(np.isfinite(p[s == 1])) and np.all(e[s == 1] >= 0)


def test_warp_in_warp_out(warp_backend):
    import warp as wp

    a, b = _basketball()
    pts = _corners(a, 40)
    be = warpvx.backend.resolve_backend(warp_backend)
    wa, wb = wp.array(a, dtype=wp.uint8, device=be.device), wp.array(b, dtype=wp.uint8, device=be.device)
    wpts = wp.array(pts, dtype=wp.float32, device=be.device)
    p, s, e = warpvx.optical_flow_pyr_lk(wa, wb, wpts)
    for arr in (p, s, e):
        assert warpvx.arrays.is_warp_array(arr) and str(arr.device) == str(wpts.device)
    _assert_parity((p.numpy(), s.numpy(), e.numpy()), _opencv(a, b, pts))


# --------------------------------------------------------------------------------------------
# shapes


@pytest.mark.parametrize(
    "size, win, max_level",
    [((640, 480), (21, 21), 3), ((321, 239), (15, 9), 2), ((257, 131), (7, 7), 4), ((200, 151), (31, 31), 0),
     ((640, 480), (7, 7), 6),
     ((97, 75), (3, 3), 9)],  # many levels on a small image: OpenCV's limit stops at 4x3
)
def test_shapes(backend, size, win, max_level):
    a, b = _basketball()
    w, h = size
    a, b = np.ascontiguousarray(a[:h, :w]), np.ascontiguousarray(b[:h, :w])
    pts = _corners(a, 120, 5)
    ours = warpvx.optical_flow_pyr_lk(a, b, pts, win_size=win, max_level=max_level, backend=backend)
    _assert_parity(ours, _opencv(a, b, pts, win=win, max_level=max_level))


def test_more_levels_than_one_launch_takes(backend):
    """9 levels (the photo at 2x, 3x3 window): the Warp kernel walks 8 levels per launch, the
    next launch starting from the coarser one's result; parity with OpenCV."""
    from warpvx.kernels_warp.optical_flow_pyr_lk import LEVELS_PER_LAUNCH

    a, b = (cv2.resize(x, (1280, 960), interpolation=cv2.INTER_LINEAR) for x in _basketball())
    pts = _corners(a, 150, 10)
    assert warpvx.flow._level_limit((1280, 960), (3, 3), 12) + 1 > LEVELS_PER_LAUNCH
    ours = warpvx.optical_flow_pyr_lk(a, b, pts, win_size=(3, 3), max_level=12, backend=backend)
    _assert_parity(ours, _opencv(a, b, pts, win=(3, 3), max_level=12))


def test_points_n12_shape(backend):
    a, b = _basketball()
    pts = _corners(a, 30)
    p, s, e = warpvx.optical_flow_pyr_lk(a, b, pts.reshape(-1, 1, 2), backend=backend)
    assert p.shape == (len(pts), 2) and s.shape == (len(pts),) and e.shape == (len(pts),)


def test_empty_point_set(backend):
    a, b = _basketball()
    p, s, e = warpvx.optical_flow_pyr_lk(a, b, np.zeros((0, 2), np.float32), backend=backend)
    assert p.shape == (0, 2) and p.dtype == np.float32
    assert s.shape == (0,) and s.dtype == np.uint8
    assert e.shape == (0,) and e.dtype == np.float32


def test_out_arrays_are_filled(backend):
    a, b = _basketball()
    pts = _corners(a, 30)
    out = (np.full((len(pts), 2), -1, np.float32), np.full(len(pts), 7, np.uint8), np.full(len(pts), -1, np.float32))
    res = warpvx.optical_flow_pyr_lk(a, b, pts, out=out, backend=backend)
    assert all(r is o for r, o in zip(res, out))
    _assert_parity(out, _opencv(a, b, pts))
    assert set(np.unique(out[1])) <= {0, 1}


# --------------------------------------------------------------------------------------------
# bad input


@pytest.fixture
def frames():
    a, b = _basketball()
    return a, b, _corners(a, 10)


def test_nan_points_rejected(frames):
    a, b, pts = frames
    bad = pts.copy()
    bad[3, 1] = np.nan
    with pytest.raises(warpvx.WarpvxValueError, match="prev_pts"):
        warpvx.optical_flow_pyr_lk(a, b, bad, backend="cpu")
    bad[3, 1] = np.inf
    with pytest.raises(warpvx.WarpvxValueError, match="prev_pts"):
        warpvx.optical_flow_pyr_lk(a, b, bad, backend="warp-cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="next_pts"):
        warpvx.optical_flow_pyr_lk(a, b, pts, bad, backend="cpu")


def test_bad_points(frames):
    a, b, pts = frames
    with pytest.raises(warpvx.DTypeError, match="prev_pts"):
        warpvx.optical_flow_pyr_lk(a, b, pts.astype(np.float64), backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="prev_pts"):
        warpvx.optical_flow_pyr_lk(a, b, np.zeros((5, 3), np.float32), backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="next_pts"):
        warpvx.optical_flow_pyr_lk(a, b, pts, pts[:-1], backend="cpu")
    with pytest.raises(warpvx.WarpvxTypeError, match="prev_pts"):
        warpvx.optical_flow_pyr_lk(a, b, [[1.0, 2.0]], backend="cpu")


def test_bad_images(frames):
    a, b, pts = frames
    with pytest.raises(warpvx.ShapeError, match="next"):
        warpvx.optical_flow_pyr_lk(a, b[:-2], pts, backend="cpu")
    with pytest.raises(warpvx.DTypeError, match="prev"):
        warpvx.optical_flow_pyr_lk(a.astype(np.float32), b, pts, backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="next"):
        warpvx.optical_flow_pyr_lk(a, cv2.cvtColor(b, cv2.COLOR_GRAY2BGR), pts, backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="prev"):
        warpvx.optical_flow_pyr_lk(a[:0], b[:0], pts, backend="cpu")


def test_bad_window_and_params(frames):
    a, b, pts = frames
    small_a, small_b = np.ascontiguousarray(a[:15, :40]), np.ascontiguousarray(b[:15, :40])
    with pytest.raises(warpvx.ShapeError, match="win_size"):
        warpvx.optical_flow_pyr_lk(small_a, small_b, pts, win_size=(21, 21), backend="warp-cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="win_size"):
        warpvx.optical_flow_pyr_lk(a, b, pts, win_size=(2, 9), backend="cpu")
    with pytest.raises(warpvx.WarpvxTypeError, match="win_size"):
        warpvx.optical_flow_pyr_lk(a, b, pts, win_size=21, backend="cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="max_level"):
        warpvx.optical_flow_pyr_lk(a, b, pts, max_level=-1, backend="cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="max_iters"):
        warpvx.optical_flow_pyr_lk(a, b, pts, max_iters=-3, backend="cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="eps"):
        warpvx.optical_flow_pyr_lk(a, b, pts, eps=-0.1, backend="cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="min_eig_threshold"):
        warpvx.optical_flow_pyr_lk(a, b, pts, min_eig_threshold=float("nan"), backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="out"):
        warpvx.optical_flow_pyr_lk(a, b, pts, out=(np.empty((3, 2), np.float32), np.empty(3, np.uint8),
                                                   np.empty(3, np.float32)), backend="cpu")
    with pytest.raises(warpvx.DTypeError, match="img"):
        warpvx.build_optical_flow_pyramid(a.astype(np.int16), backend="cpu")
    with pytest.raises(warpvx.WarpvxValueError, match="max_level"):
        warpvx.build_optical_flow_pyramid(a, max_level=-2, backend="cpu")


def test_bad_pyramid(frames):
    a, b, pts = frames
    pa = warpvx.build_optical_flow_pyramid(a, max_level=3, backend="cpu")
    pb = warpvx.build_optical_flow_pyramid(b, max_level=3, backend="cpu")
    broken = [pa[0], pa[1], np.ascontiguousarray(pa[1][:100, :100])]
    with pytest.raises(warpvx.ShapeError, match=r"prev\[2\]"):
        warpvx.optical_flow_pyr_lk(broken, pb, pts, backend="cpu")
    with pytest.raises(warpvx.ShapeError, match="next"):
        warpvx.optical_flow_pyr_lk(pa, [], pts, backend="cpu")


def test_points_outside_image_are_lost(backend):
    """Points whose window misses the image get status 0, as OpenCV; near the border they
    are tracked as OpenCV tracks them (its windows read the reflected border)."""
    a, b = _basketball()
    h, w = a.shape
    far = np.float32([[-100, 50], [w + 60, 100], [300, -45], [200, h + 500], [1e9, 3], [-3e12, -1e12]])
    near = np.float32([[-4.5, 100.2], [w + 3.3, 240.7], [320.1, -6.0], [5.5, h + 2.2], [0, 0], [w - 1, h - 1]])
    pts = np.concatenate([far, near, _corners(a, 30)])
    p, s, e = warpvx.optical_flow_pyr_lk(a, b, pts, backend=backend)
    rp, rs, _ = _opencv(a, b, pts)
    assert np.all(rs[: len(far)] == 0)  # what OpenCV does, so what we follow
    assert np.all(s[: len(far)] == 0) and np.all(e[: len(far)] == 0)
    inner = slice(len(far), None)
    both = (s[inner] == 1) & (rs[inner] == 1)
    assert np.array_equal(s[inner], rs[inner])
    assert np.all(np.linalg.norm(p[inner][both] - rp[inner][both], axis=1) < 0.1)


# --------------------------------------------------------------------------------------------
# OpenCV parity on real frames


def test_parity_consecutive_frames(backend):
    a, b = _basketball()
    pts = _corners(a, 600, 5)
    ours = warpvx.optical_flow_pyr_lk(a, b, pts, backend=backend)
    ref = _opencv(a, b, pts)
    _assert_parity(ours, ref)
    # The Warp kernels follow OpenCV's fixed-point arithmetic: nearly every point agrees closely.
    p, s, e = ours
    both = (s == 1) & (ref[1] == 1)
    dist = np.linalg.norm(p[both] - ref[0][both], axis=1)
    assert np.mean(dist < 0.05) >= 0.98
    assert np.mean(s != ref[1]) <= 0.01
    assert np.mean(np.abs(e[both] - ref[2][both]) < 0.05) >= 0.98


def _counted_points(pts, capacity, device):
    """A Counted of ``pts`` in ``capacity`` rows (the rest far outside the image)."""
    import warp as wp

    from warpvx._counted import Counted

    rows = np.full((capacity, 2), -1e4, np.float32)
    rows[: len(pts)] = pts
    return Counted(wp.array(rows, dtype=wp.float32, device=device),
                   wp.array([len(pts)], dtype=wp.int32, device=device))


def test_counted_points_track_as_their_count(warp_backend):
    """Counted points (a graph's corners): every row is tracked, the results are Counteds
    of the points' count whose value is exactly the plain call's (OpenCV's parity), with or
    without Counted out= buffers."""
    import warp as wp

    from warpvx._counted import Counted

    a, b = _basketball()
    pts = _corners(a, 300, 5)
    device = warpvx.backend.resolve_backend(warp_backend).device
    wa, wb = (wp.array(x, dtype=wp.uint8, device=device) for x in (a, b))
    want = [r.numpy() for r in warpvx.optical_flow_pyr_lk(wa, wb, wp.array(pts, device=device))]
    counted = _counted_points(pts, 400, device)
    got = warpvx.optical_flow_pyr_lk(wa, wb, counted)
    assert all(isinstance(r, Counted) and r.count.ptr == counted.count.ptr for r in got)
    count = wp.zeros(1, dtype=wp.int32, device=device)
    out = tuple(Counted(wp.zeros((400,) + shape, dtype=dtype, device=device), count)
                for shape, dtype in (((2,), wp.float32), ((), wp.uint8), ((), wp.float32)))
    into = warpvx.optical_flow_pyr_lk(wa, wb, counted, out=out)
    assert into == out and int(count.numpy()[0]) == len(pts)
    for result in (got, into):
        for r, w in zip(result, want):
            np.testing.assert_array_equal(r.to("host"), w)
    _assert_parity(want, _opencv(a, b, pts))


def test_parity_known_subpixel_shift(backend):
    cam, moved, shift = _camera_shifted()
    pts = _corners(cam, 400)
    ours = warpvx.optical_flow_pyr_lk(cam, moved, pts, backend=backend)
    _assert_parity(ours, _opencv(cam, moved, pts))
    p, s, _ = ours
    assert np.mean(s) >= 0.98
    err = np.linalg.norm(p[s == 1] - (pts[s == 1] + shift), axis=1)
    assert np.median(err) < 0.05
    assert np.mean(err < 0.25) >= 0.95


def test_point_lost_at_a_coarse_level_continues_from_its_guess(backend):
    """Points tracked at level 3, lost at level 2 (window too flat: min eigenvalue under the
    threshold), trackable at level 0: OpenCV carries level 3's result down as the guess
    (status is only cleared at level 0) and tracks them at the finer levels; so do we. A
    14 px shift: restarting such a point from zero flow below level 2 misses it."""
    cam, moved, shift = _camera_shifted(14.2, -8.4)
    thr = 5e-3
    pts = _corners(cam, 400)
    _, pa = cv2.buildOpticalFlowPyramid(cam, (21, 21), 3, withDerivatives=False)
    _, pb = cv2.buildOpticalFlowPyramid(moved, (21, 21), 3, withDerivatives=False)
    eig = np.array([cv2.calcOpticalFlowPyrLK(pa[k], pb[k], (pts / 2**k).reshape(-1, 1, 2), None,
                                             winSize=(21, 21), maxLevel=0, minEigThreshold=0,
                                             flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)[2].ravel()
                    for k in range(4)])
    pts = pts[(eig[3] >= 1.5 * thr) & (eig[2] < thr) & (eig[0] >= 1.5 * thr)]
    assert len(pts) >= 8
    p, s, e = warpvx.optical_flow_pyr_lk(cam, moved, pts, min_eig_threshold=thr, backend=backend)
    rp, rs, re = _opencv(cam, moved, pts, min_eig=thr)
    assert np.all(rs == 1)
    np.testing.assert_array_equal(s, rs)
    assert np.abs(p - rp).max() < 0.01
    assert np.abs(e - re).max() < 0.05
    assert np.linalg.norm(p - (pts + shift), axis=1).max() < 0.1


def test_levels_per_launch_do_not_change_results(warp_backend, monkeypatch):
    """The Warp kernel walks a point through LEVELS_PER_LAUNCH levels in one launch; any split
    of the pyramid into launches (one level each, as the per-level kernel did; 3) gives the
    same bits, with and without initial flow, lost points included."""
    import warpvx.kernels_warp.optical_flow_pyr_lk as lk

    a, b = _basketball()
    h, w = a.shape
    pts = np.concatenate([_corners(a, 200, 5), np.float32([[-4.5, 100.2], [w + 3.3, 240.7], [-100, 50],
                                                           [0, 0], [w - 1, h - 1], [5.5, h + 2.2]])])
    guess = pts + np.float32([1.5, -0.5])
    cases = [dict(win_size=(7, 7), max_level=6), dict(win_size=(21, 21), max_level=3),
             dict(win_size=(15, 15), max_level=0), dict(win_size=(9, 9), max_level=2, next_pts=guess)]
    for kw in cases:
        kw = dict(kw, backend=warp_backend, min_eig_threshold=1e-3)
        want = warpvx.optical_flow_pyr_lk(a, b, pts, **kw)
        assert np.mean(want[1]) < 0.99  # some points lost
        for per_launch in (1, 3):
            monkeypatch.setattr(lk, "LEVELS_PER_LAUNCH", per_launch)
            got = warpvx.optical_flow_pyr_lk(a, b, pts, **kw)
            for x, y in zip(got, want):
                np.testing.assert_array_equal(x, y)
        monkeypatch.undo()


# --------------------------------------------------------------------------------------------
# pyramids, initial flow, iteration settings


def test_pyramid_levels_match_opencv(backend):
    a, _ = _basketball()
    for win, max_level in [((21, 21), 3), ((21, 21), 6), ((101, 31), 5)]:
        levels = warpvx.build_optical_flow_pyramid(a, win, max_level, backend=backend)
        retval, ref = cv2.buildOpticalFlowPyramid(a, win, max_level, withDerivatives=False)
        assert len(levels) == retval + 1
        for ours, theirs in zip(levels, ref):
            ours = _np(ours)
            assert ours.shape == theirs.shape and ours.dtype == np.uint8
            assert np.abs(ours.astype(int) - theirs.astype(int)).max() <= 1


def test_prebuilt_pyramids_same_result(backend):
    a, b = _basketball()
    pts = _corners(a, 200)
    pa = warpvx.build_optical_flow_pyramid(a, (21, 21), 3, backend=backend)
    pb = warpvx.build_optical_flow_pyramid(b, (21, 21), 3, backend=backend)
    from_images = warpvx.optical_flow_pyr_lk(a, b, pts, backend=backend)
    from_pyramids = warpvx.optical_flow_pyr_lk(pa, pb, pts, backend=backend)
    for x, y in zip(from_images, from_pyramids):
        np.testing.assert_array_equal(x, y)
    # Fewer levels given than asked: the pyramid's depth wins.
    short = warpvx.optical_flow_pyr_lk(pa[:2], pb[:2], pts, max_level=3, backend=backend)
    _assert_parity(short, _opencv(a, b, pts, max_level=1))


def test_initial_flow(backend):
    """A 25 px shift is out of reach without a pyramid; a close initial guess recovers it."""
    cam, moved, shift = _camera_shifted(25.3, -0.6)
    pts = _corners(cam, 200)
    rng = np.random.default_rng(0)
    guess = (pts + shift + rng.uniform(-1.5, 1.5, pts.shape)).astype(np.float32)
    p, s, e = warpvx.optical_flow_pyr_lk(cam, moved, pts, guess, max_level=0, backend=backend)
    _assert_parity((p, s, e), _opencv(cam, moved, pts, guess, max_level=0))
    good = np.linalg.norm(p - (pts + shift), axis=1) < 0.25
    assert np.mean(good & (s == 1)) >= 0.9
    p0, s0, _ = warpvx.optical_flow_pyr_lk(cam, moved, pts, max_level=0, backend=backend)
    assert np.mean((np.linalg.norm(p0 - (pts + shift), axis=1) < 0.25) & (s0 == 1)) < 0.2


def test_iteration_settings(backend):
    a, b = _basketball()
    pts = _corners(a, 150)
    for iters, eps, min_eig in [(1, 0.01, 1e-4), (5, 0.5, 1e-4), (30, 0.0, 1e-3), (0, 0.01, 1e-4)]:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, iters, eps)
        ours = warpvx.optical_flow_pyr_lk(a, b, pts, max_iters=iters, eps=eps, min_eig_threshold=min_eig,
                                          backend=backend)
        _assert_parity(ours, _opencv(a, b, pts, criteria=crit, min_eig=min_eig))


# --------------------------------------------------------------------------------------------
# warpvx.cv drop-in


def test_cv_calc_optical_flow_pyr_lk(backend):
    a, b = _basketball()
    pts = _corners(a, 100).reshape(-1, 1, 2)
    p, s, e = wcv.calcOpticalFlowPyrLK(a, b, pts, None, winSize=(15, 15), maxLevel=2, backend=backend)
    rp, rs, re = cv2.calcOpticalFlowPyrLK(a, b, pts, None, winSize=(15, 15), maxLevel=2)
    assert p.shape == rp.shape == (len(pts), 1, 2) and s.shape == rs.shape and e.shape == re.shape
    assert p.dtype == np.float32 and s.dtype == np.uint8 and e.dtype == np.float32
    _assert_parity((p.reshape(-1, 2), s.ravel(), e.ravel()), (rp.reshape(-1, 2), rs.ravel(), re.ravel()))
    # Nx2 points come back Nx2, as cv2; no points give (None, None, None), as cv2.
    p2, _, _ = wcv.calcOpticalFlowPyrLK(a, b, pts.reshape(-1, 2), None, backend=backend)
    assert p2.shape == (len(pts), 2)
    assert wcv.calcOpticalFlowPyrLK(a, b, np.zeros((0, 1, 2), np.float32), None, backend=backend) == (None,) * 3


def test_cv_initial_flow_and_criteria(backend):
    a, b = _basketball()
    pts = _corners(a, 80).reshape(-1, 1, 2)
    guess = pts + np.float32([0.5, -0.5])
    crit = (wcv.TERM_CRITERIA_COUNT, 10, 0.0)  # COUNT only: OpenCV then uses eps 0.01
    p, s, e = wcv.calcOpticalFlowPyrLK(a, b, pts, guess.copy(), criteria=crit, flags=wcv.OPTFLOW_USE_INITIAL_FLOW,
                                       backend=backend)
    rp, rs, re = cv2.calcOpticalFlowPyrLK(a, b, pts, guess.copy(), criteria=crit,
                                          flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    _assert_parity((p.reshape(-1, 2), s.ravel(), e.ravel()), (rp.reshape(-1, 2), rs.ravel(), re.ravel()))


def test_cv_build_pyramid_and_errors(backend):
    a, b = _basketball()
    retval, pyr = wcv.buildOpticalFlowPyramid(a, (21, 21), 3, backend=backend)
    ref_retval, _ = cv2.buildOpticalFlowPyramid(a, (21, 21), 3, withDerivatives=False)
    assert retval == ref_retval and len(pyr) == retval + 1
    _, pyr_b = wcv.buildOpticalFlowPyramid(b, (21, 21), 3, backend=backend)
    pts = _corners(a, 50)
    p, s, _ = wcv.calcOpticalFlowPyrLK(pyr, pyr_b, pts, None, backend=backend)
    assert p.shape == (len(pts), 2) and s.mean() > 0.9
    with runs_on_cv2("withDerivatives"):
        wcv.buildOpticalFlowPyramid(a, (21, 21), 3, withDerivatives=True, backend=backend)
    with runs_on_cv2("flags"):
        wcv.calcOpticalFlowPyrLK(a, b, pts, None, flags=wcv.OPTFLOW_LK_GET_MIN_EIGENVALS, backend=backend)
    with pytest.raises(warpvx.WarpvxValueError, match="nextPts"):
        wcv.calcOpticalFlowPyrLK(a, b, pts, None, flags=wcv.OPTFLOW_USE_INITIAL_FLOW, backend=backend)
    assert (wcv.TERM_CRITERIA_COUNT, wcv.TERM_CRITERIA_EPS, wcv.OPTFLOW_USE_INITIAL_FLOW,
            wcv.OPTFLOW_LK_GET_MIN_EIGENVALS) == (cv2.TERM_CRITERIA_COUNT, cv2.TERM_CRITERIA_EPS,
                                                  cv2.OPTFLOW_USE_INITIAL_FLOW, cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)
