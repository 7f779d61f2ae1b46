"""warpvx.cv as a drop-in for real scripts: names it does not accelerate are cv2's own, arrays
are taken as cv2 takes them (strided views, strided dst, fixed-point remap maps), and ORB
returns what cv2.ORB returns (cv2's count; empty compute)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.kernels.test_cv_imgproc import assert_close
from warpvx import cv as wcv
from warpvx.bench.inputs import mild_homography, undistort_maps

_MODULES = (wcv.imgproc, wcv.pyramids, wcv.features2d, wcv.orb, wcv.video)


# --- names: warpvx's where accelerated, cv2's otherwise -------------------------------------


@pytest.mark.parametrize("name", ["imread", "imwrite", "initUndistortRectifyMap",
                                  "convertMaps", "KeyPoint", "DMatch", "error", "COLOR_BGR2HSV",
                                  "CV_16SC2", "RANSAC", "data", "__version__"])
def test_unaccelerated_names_fall_through_to_cv2(name):
    assert getattr(wcv, name) is getattr(cv2, name)
    assert name in dir(wcv)


def test_accelerated_names_stay_warpvx():
    for name in ("cvtColor", "remap", "warpPerspective", "resize", "ORB_create", "BFMatcher"):
        assert getattr(wcv, name) is not getattr(cv2, name) and name in dir(wcv)
    assert wcv.remap.__module__ == "warpvx.cv.imgproc"


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_function"):
        wcv.no_such_function  # noqa: B018
    assert not hasattr(wcv, "no_such_function")


def test_every_constant_matches_cv2():
    for module in _MODULES:
        for name in module.__all__:
            value = getattr(wcv, name)
            if not callable(value) and hasattr(cv2, name):  # ORB_kHarrisScore left cv2 5
                assert value == getattr(cv2, name), (module.__name__, name)


def test_script_with_drop_in_recovers_a_homography(tmp_path, backend):
    """An unchanged OpenCV script with ``from warpvx import cv as cv2``: imread and
    findHomography (cv2's) around warpPerspective, cvtColor, ORB and BFMatcher (warpvx's)."""
    path = str(tmp_path / "rocket.png")
    cv2.imwrite(path, bgr("rocket"))
    img = wcv.imread(path, wcv.IMREAD_COLOR)
    h_true = mild_homography(640, 427)
    warped = wcv.warpPerspective(img, h_true, (640, 427), backend=backend)
    g0 = wcv.cvtColor(img, wcv.COLOR_BGR2GRAY, backend=backend)
    g1 = wcv.cvtColor(warped, wcv.COLOR_BGR2GRAY, backend=backend)
    orb = wcv.ORB_create(1000, backend=backend)
    k0, d0 = orb.detectAndCompute(g0, None)
    k1, d1 = orb.detectAndCompute(g1, None)
    matches = wcv.BFMatcher(wcv.NORM_HAMMING, crossCheck=True, backend=backend).match(d0, d1)
    src = np.float32([k0[m.queryIdx].pt for m in matches])
    dst = np.float32([k1[m.trainIdx].pt for m in matches])
    h, inliers = wcv.findHomography(src, dst, wcv.RANSAC, 3.0)
    assert inliers.mean() > 0.5
    corners = np.float32([[0, 0], [639, 0], [639, 426], [0, 426]])[:, None]
    got = wcv.perspectiveTransform(corners, h)
    want = cv2.perspectiveTransform(corners, h_true)
    # cv2's own ORB features, listed in 20 other orders, put the corners 0.25-2.5 px off
    # here: RANSAC's samples depend on the order (warpvx.cv.ORB lists cv2's set in its own).
    assert np.abs(got - want).max() < 3.0


# --- strided views in, strided dst out -------------------------------------------------------


def _views():
    """Strided views cv2 takes as they are: an ROI and a channel flip (BGR as RGB)."""
    big = bgr("motorcycle")
    return {"roi": big[37:337, 51:502], "flip": bgr("chelsea")[:, :, ::-1]}


@pytest.mark.parametrize("view", ["roi", "flip"])
@pytest.mark.parametrize("call", [
    lambda cv, s, **kw: cv.cvtColor(s, cv.COLOR_BGR2GRAY, **kw),
    lambda cv, s, **kw: cv.warpPerspective(s, mild_homography(451, 300), (451, 300), **kw),
    lambda cv, s, **kw: cv.pyrDown(s, **kw),
    lambda cv, s, **kw: cv.resize(s, (300, 200), **kw),
    lambda cv, s, **kw: cv.GaussianBlur(s, (7, 7), 1.5, **kw),
    lambda cv, s, **kw: cv.remap(s, *undistort_maps(451, 300), cv.INTER_LINEAR, **kw),
], ids=["cvtColor", "warpPerspective", "pyrDown", "resize", "GaussianBlur", "remap"])
def test_strided_views_like_cv2(backend, view, call):
    src = _views()[view]
    assert not src.flags.c_contiguous
    assert_close(call(wcv, src, backend=backend), call(cv2, src))


def test_strided_view_build_pyramid(backend):
    src = _views()["roi"]
    levels = wcv.buildPyramid(src, 2, backend=backend)
    assert_close(levels[2], cv2.pyrDown(cv2.pyrDown(src)))


@pytest.mark.parametrize("view", ["roi", "flip"])
def test_strided_views_features_like_contiguous(backend, view):
    """Feature functions give on a view exactly what they give on its contiguous copy (their
    parity with cv2 on contiguous images is tested per operation)."""
    src = _views()[view]
    copy = np.ascontiguousarray(src)
    g, g_copy = src[:, :, 1], copy[:, :, 1].copy()
    np.testing.assert_array_equal(wcv.cornerHarris(g, 3, 3, 0.04, backend=backend),
                                  wcv.cornerHarris(g_copy, 3, 3, 0.04, backend=backend))
    np.testing.assert_array_equal(wcv.goodFeaturesToTrack(g, 50, 0.01, 5, backend=backend),
                                  wcv.goodFeaturesToTrack(g_copy, 50, 0.01, 5, backend=backend))
    fast = wcv.FastFeatureDetector_create(20, backend=backend)
    assert [k.pt for k in fast.detect(src)] == [k.pt for k in fast.detect(copy)]
    orb = wcv.ORB_create(300, backend=backend)
    (k, d), (k_copy, d_copy) = orb.detectAndCompute(src, None), orb.detectAndCompute(copy, None)
    assert [p.pt for p in k] == [p.pt for p in k_copy]
    np.testing.assert_array_equal(d, d_copy)
    # every other descriptor row: a strided view of descriptors, matched as cv2 matches them
    ref = cv2.BFMatcher(cv2.NORM_HAMMING).match(d[::2], d_copy)
    got = wcv.BFMatcher(wcv.NORM_HAMMING, backend=backend).match(d[::2], d_copy)
    assert [(m.queryIdx, m.distance) for m in got] == [(m.queryIdx, m.distance) for m in ref]


def test_strided_points_and_images_for_lk(backend):
    """Strided images as cv2 takes them; strided points too (cv2 refuses those)."""
    prev = bgr("coffee")[:, :, 1]  # a channel view
    nxt = cv2.warpAffine(bgr("coffee"), np.float32([[1, 0, 1.5], [0, 1, -0.75]]), (600, 400))[:, :, 1]
    pts = cv2.goodFeaturesToTrack(np.ascontiguousarray(prev), 40, 0.01, 8)
    strided = np.repeat(pts, 2, axis=0)[::2]  # same points, a strided [N, 1, 2] view
    assert not strided.flags.c_contiguous and not prev.flags.c_contiguous
    got, st, _ = wcv.calcOpticalFlowPyrLK(prev, nxt, strided, None, backend=backend)
    ref, ref_st, _ = cv2.calcOpticalFlowPyrLK(prev, nxt, pts, None)
    assert (st == ref_st).all()
    assert np.abs(got - ref)[st[:, 0] == 1].max() < 0.05
    _, levels = wcv.buildOpticalFlowPyramid(prev, (21, 21), 2, backend=backend)
    assert len(levels) == 3 and levels[1].shape == (200, 300)


@pytest.mark.parametrize("call", [
    lambda cv, s, d, **kw: cv.cvtColor(s, cv.COLOR_BGR2RGB, d, **kw),
    lambda cv, s, d, **kw: cv.GaussianBlur(s, (5, 5), 1.0, d, **kw),
    lambda cv, s, d, **kw: cv.remap(s, *undistort_maps(451, 300), cv.INTER_LINEAR, d, **kw),
    lambda cv, s, d, **kw: cv.warpPerspective(s, mild_homography(451, 300), (451, 300), d, **kw),
    lambda cv, s, d, **kw: cv.resize(s, (451, 300), d, **kw),
], ids=["cvtColor", "GaussianBlur", "remap", "warpPerspective", "resize"])
def test_strided_dst_is_written_through_like_cv2(backend, call):
    src = bgr("chelsea")
    ref_big = np.zeros((320, 480, 3), np.uint8)
    ref_view = ref_big[10:310, 20:471]
    got_big = ref_big.copy()
    got_view = got_big[10:310, 20:471]
    assert call(cv2, src, ref_view) is not None
    res = call(wcv, src, got_view, backend=backend)
    assert np.shares_memory(res, got_big)
    assert_close(got_big, ref_big)
    assert not got_big[:10].any() and not got_big[:, :20].any()  # outside the ROI untouched


# --- remap: cv2's fixed-point maps (CV_16SC2) and interleaved float maps --------------------


def _fixed_maps(nninterpolation=False):
    """CV_16SC2 maps for a 451x300 image: a lens undistortion from
    cv2.initUndistortRectifyMap, or (``nninterpolation``) whole-pixel maps from convertMaps."""
    if nninterpolation:
        return cv2.convertMaps(*undistort_maps(451, 300), cv2.CV_16SC2, nninterpolation=True)
    k = np.array([[420.0, 0, 225.5], [0, 420.0, 150.0], [0, 0, 1]])
    return cv2.initUndistortRectifyMap(k, np.array([-0.28, 0.09, 0.001, -0.002]), None, k,
                                       (451, 300), cv2.CV_16SC2)


@pytest.mark.parametrize("border", ["BORDER_CONSTANT", "BORDER_REPLICATE", "BORDER_REFLECT_101"])
def test_remap_fixed_point_maps_like_cv2(backend, border):
    src = bgr("chelsea")
    m1, m2 = _fixed_maps()
    assert m1.dtype == np.int16 and m1.shape == (300, 451, 2) and m2.dtype == np.uint16
    b = getattr(cv2, border)
    # INTER_NEAREST: exactly cv2's reading (its NNDeltaTab included)
    np.testing.assert_array_equal(wcv.remap(src, m1, m2, wcv.INTER_NEAREST, borderMode=b, backend=backend),
                                  cv2.remap(src, m1, m2, cv2.INTER_NEAREST, borderMode=b))
    # INTER_LINEAR: at x + fx/32, y + fy/32, i.e. cv2 on the float maps it converts them to;
    # cv2's own fixed-point path rounds its 15-bit weights differently on < 1% of pixels, by 1.
    out = wcv.remap(src, m1, m2, wcv.INTER_LINEAR, borderMode=b, backend=backend)
    fx, fy = cv2.convertMaps(m1, m2, cv2.CV_32FC1)
    assert_close(out, cv2.remap(src, fx, fy, cv2.INTER_LINEAR, borderMode=b))
    diff = np.abs(out.astype(np.int16) - cv2.remap(src, m1, m2, cv2.INTER_LINEAR, borderMode=b))
    assert diff.max() <= 1 and (diff == 0).mean() >= 0.99


def test_remap_fixed_point_map_without_table(backend):
    """convertMaps(nninterpolation=True): whole-pixel map1, map2 None."""
    src = gray("camera")[:300, :451].copy()
    m1, m2 = _fixed_maps(nninterpolation=True)
    assert m2 is None
    ref = cv2.remap(src, m1, None, cv2.INTER_NEAREST)
    np.testing.assert_array_equal(wcv.remap(src, m1, None, wcv.INTER_NEAREST, backend=backend), ref)
    # whole pixels sample the same under INTER_LINEAR (cv2 5.0 gives the border value instead)
    np.testing.assert_array_equal(wcv.remap(src, m1, None, wcv.INTER_LINEAR, backend=backend), ref)


def test_remap_fixed_point_bad_input(backend):
    src = gray("camera")
    m1, m2 = _fixed_maps()
    with pytest.raises(warpvx.DTypeError, match="map2"):
        wcv.remap(src, m1, m2.astype(np.float32), wcv.INTER_LINEAR, backend=backend)
    with pytest.raises(warpvx.ShapeError, match="map2"):
        wcv.remap(src, m1, m2[:10], wcv.INTER_LINEAR, backend=backend)
    with pytest.raises(warpvx.ShapeError, match="map1"):
        wcv.remap(src, m1[..., 0], m2, wcv.INTER_LINEAR, backend=backend)


def test_remap_on_warp_arrays_interleaved_and_fixed(warp_backend):
    import warp as wp

    from warpvx.backend import resolve_backend

    dev = resolve_backend(warp_backend).device
    src_host = bgr("chelsea")
    mx, my = undistort_maps(451, 300)
    xy = cv2.convertMaps(mx, my, cv2.CV_32FC2)[0]
    src = wp.array(src_host, dtype=wp.uint8, device=dev)
    out = wcv.remap(src, wp.array(xy, dtype=wp.float32, device=dev), None, wcv.INTER_LINEAR)
    assert isinstance(out, wp.array)
    assert_close(out.numpy(), cv2.remap(src_host, xy, None, cv2.INTER_LINEAR))
    m1, m2 = _fixed_maps()
    with pytest.raises(warpvx.UnsupportedError, match="map1"):
        wcv.remap(src, wp.array(m1, dtype=wp.int16, device=dev), None, wcv.INTER_LINEAR)


# --- ORB: cv2's count; compute with no keypoints -------------------------------------------


@pytest.mark.parametrize("name,n", [("camera", 500), ("astronaut", 2000), ("coffee", 100),
                                    ("chelsea", 500)])
def test_orb_returns_cv2s_count(backend, name, n):
    """As many keypoints as cv2 (nfeatures where the photo has that many corners), with a
    descriptor row each; detect gives detectAndCompute's keypoints (their positions against
    cv2's: tests/cv/test_orb_opencv.py)."""
    img = gray(name)
    ref = cv2.ORB_create(n).detect(img)
    orb = wcv.ORB_create(n, backend=backend)
    kps, desc = orb.detectAndCompute(img, None)
    assert abs(len(kps) - len(ref)) <= max(1, 0.01 * len(ref)) and len(kps) <= n
    assert desc.shape == (len(kps), 32) and desc.dtype == np.uint8
    assert [k.pt for k in orb.detect(img)] == [k.pt for k in kps]


@pytest.mark.parametrize("keypoints", [None, [], ()], ids=["None", "list", "tuple"])
def test_orb_compute_without_keypoints_like_cv2(backend, keypoints):
    img = gray("camera")
    ref = cv2.ORB_create().compute(img, keypoints)
    got = wcv.ORB_create(backend=backend).compute(img, keypoints)
    assert got == ref == ((), None)
    assert type(got[0]) is type(ref[0])
