"""warpvx.fast_corners and warpvx.cv.FastFeatureDetector against cv2's FAST-9/16."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import cv as wcv
from warpvx.backend import init_warp
from warpvx.errors import (DTypeError, ShapeError, UnsupportedError, WarpvxTypeError,
                           WarpvxValueError)
from tests.images import bgr, gray
from tests.parity import on_device as _on_device
from tests.cv.fallback import runs_on_cv2

IMAGES = ["camera", "brick", "text", "coffee", "chelsea"]
BORDER = 3


def _cv_fast(img, threshold, nonmax):
    kps = cv2.FastFeatureDetector_create(threshold, nonmax).detect(img)
    return {(int(k.pt[0]), int(k.pt[1])): k.response for k in kps}


def _ours(kps):
    h = kps.numpy()
    return {(int(x), int(y)): r for x, y, r in zip(h.x, h.y, h.response)}


def _inner(points, shape):
    h, w = shape
    return {p: v for p, v in points.items()
            if BORDER <= p[0] < w - BORDER and BORDER <= p[1] < h - BORDER}




# --- smoke and shapes ------------------------------------------------------------------------

def test_smoke(backend):
    kps = warpvx.fast_corners(gray("camera"), 20, backend=backend)
    assert isinstance(kps, warpvx.Keypoints)
    assert kps.is_host and len(kps) > 100
    assert np.all(kps.size == 7) and np.all(kps.angle == -1) and np.all(kps.octave == 0)
    assert kps.x.dtype == np.float32 and kps.octave.dtype == np.int32
    assert np.all(kps.response >= 20)


@pytest.mark.parametrize("shape", [(7, 7), (31, 17), (64, 101), (120, 77)])
def test_shapes(backend, shape):
    img = np.ascontiguousarray(cv2.resize(gray("brick"), (shape[1], shape[0])))
    kps = warpvx.fast_corners(img, 10, backend=backend)
    ref = _cv_fast(img, 10, True)
    assert _ours(kps) == ref
    h, w = shape
    assert np.all((kps.x >= 3) & (kps.x < w - 3) & (kps.y >= 3) & (kps.y < h - 3))


@pytest.mark.parametrize("shape", [(6, 40), (40, 6), (1, 1), (5, 5)])
def test_smaller_than_7x7_gives_no_keypoints(backend, shape):
    img = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    kps = warpvx.fast_corners(img, 0, backend=backend)
    assert len(kps) == 0 and kps.is_host
    assert len(cv2.FastFeatureDetector_create(0).detect(img)) == 0


def test_hxwx1_accepted(backend):
    img = gray("text")
    a = warpvx.fast_corners(img[..., None].copy(), 20, backend=backend)
    assert _ours(a) == _cv_fast(img, 20, True)


# --- bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize("threshold", [-1, 256, 1000])
def test_threshold_out_of_range(backend, threshold):
    with pytest.raises(WarpvxValueError, match="threshold"):
        warpvx.fast_corners(gray("camera"), threshold, backend=backend)


def test_threshold_not_int(backend):
    with pytest.raises(WarpvxTypeError, match="threshold"):
        warpvx.fast_corners(gray("camera"), 2.5, backend=backend)


def test_nonmax_not_bool(backend):
    with pytest.raises(WarpvxTypeError, match="nonmax"):
        warpvx.fast_corners(gray("camera"), 10, "yes", backend=backend)


def test_wrong_dtype(backend):
    with pytest.raises(DTypeError, match="src"):
        warpvx.fast_corners(gray("camera").astype(np.float32), 10, backend=backend)


def test_colour_image_rejected(backend):
    with pytest.raises(ShapeError, match="src"):
        warpvx.fast_corners(bgr("coffee"), 10, backend=backend)


def test_empty_image(backend):
    with pytest.raises(ShapeError, match="src"):
        warpvx.fast_corners(np.zeros((0, 10), np.uint8), 10, backend=backend)


def test_not_an_array(backend):
    with pytest.raises(WarpvxTypeError, match="src"):
        warpvx.fast_corners([[1, 2], [3, 4]], 10, backend=backend)


# --- OpenCV parity on real images ------------------------------------------------------------

@pytest.mark.parametrize("name", IMAGES)
@pytest.mark.parametrize("threshold", [7, 20])
def test_parity_nonmax(backend, name, threshold):
    img = gray(name)
    ref = _inner(_cv_fast(img, threshold, True), img.shape)
    got = _inner(_ours(warpvx.fast_corners(img, threshold, True, backend=backend)), img.shape)
    missing, extra = set(ref) - set(got), set(got) - set(ref)
    assert len(missing) <= 0.02 * len(ref), f"missing {len(missing)} of {len(ref)}"
    assert len(extra) <= 0.02 * len(ref), f"extra {len(extra)} of {len(ref)}"
    assert all(got[p] == ref[p] for p in set(ref) & set(got)), "scores differ"


@pytest.mark.parametrize("name", ["camera", "coffee"])
def test_parity_without_nonmax(backend, name):
    img = gray(name)
    ref = _inner(_cv_fast(img, 12, False), img.shape)
    got = _inner(_ours(warpvx.fast_corners(img, 12, False, backend=backend)), img.shape)
    missing, extra = set(ref) - set(got), set(got) - set(ref)
    assert len(missing) <= 0.02 * len(ref) and len(extra) <= 0.02 * len(ref)
    # cv2 reports no score without NMS; the survivors of its NMS carry it.
    scored = _cv_fast(img, 12, True)
    common = set(scored) & set(got)
    assert len(common) > 0.9 * len(scored)
    assert all(got[p] == scored[p] for p in common)


def test_threshold_zero_parity(backend):
    img = gray("text")
    assert _ours(warpvx.fast_corners(img, 0, True, backend=backend)) == _cv_fast(img, 0, True)


def test_sorted_by_score_then_y_then_x(backend):
    kps = warpvx.fast_corners(gray("camera"), 15, backend=backend)
    order = np.lexsort((kps.x, kps.y, -kps.response))
    assert np.array_equal(order, np.arange(len(kps)))


def test_kernels_refuse_out(backend):
    """The keypoint count depends on the data: an out= other than a Counted reaching the
    implementation through the registry's dispatch is refused rather than ignored."""
    from warpvx.backend import resolve_backend
    from warpvx.registry import dispatch

    src = _on_device(gray("brick"), backend)
    out = _on_device(np.zeros(16, np.float32), backend)
    with pytest.raises(UnsupportedError, match="out"):
        dispatch("fast_corners", resolve_backend(backend), src, 20, True, out=out)


# --- Counted out= (a graph's fixed buffers, no host sync) -------------------------------------

def _counted_keypoints(capacity, device):
    from warpvx._counted import Counted

    wp = init_warp()
    fields = {f: wp.zeros(capacity, dtype=wp.int32 if f == "octave" else wp.float32,
                          device=device) for f in warpvx.keypoints.FIELDS}
    return Counted(warpvx.Keypoints(**fields), wp.zeros(1, dtype=wp.int32, device=device))


@pytest.mark.parametrize("name,threshold,nonmax", [("camera", 20, True), ("brick", 7, True),
                                                   ("coffee", 12, False)])
@pytest.mark.parametrize("small", [None, 64])  # 64: the count overflows the short sort
def test_counted_out_parity(warp_backend, monkeypatch, small, name, threshold, nonmax):
    """Into a Counted of the image's capacity: exactly the keypoints of the plain call (every
    field, in order), OpenCV's corners and scores, twice over the same buffers."""
    if small is not None:
        from warpvx.kernels_warp import _device_sort

        monkeypatch.setattr(_device_sort, "SMALL", small)
    from warpvx.kernels_warp.fast_corners import max_fast_corners

    img = gray(name)
    src = _on_device(img, warp_backend)
    want = warpvx.fast_corners(src, threshold, nonmax).numpy()
    out = _counted_keypoints(max_fast_corners(*img.shape, nonmax), src.device)
    for _ in range(2):
        assert warpvx.fast_corners(src, threshold, nonmax, out=out) is out
        got = out.to("host")
        for f in warpvx.keypoints.FIELDS:
            np.testing.assert_array_equal(getattr(got, f), getattr(want, f), f)
    ref = _inner(_cv_fast(img, threshold, nonmax), img.shape)
    mine = _inner(_ours(got), img.shape)
    assert len(set(ref) ^ set(mine)) <= 0.04 * len(ref)
    if nonmax:
        assert all(mine[p] == ref[p] for p in set(ref) & set(mine))


def test_counted_out_bad(warp_backend):
    src = _on_device(gray("brick"), warp_backend)
    with pytest.raises(ShapeError, match="out.rows.x"):
        warpvx.fast_corners(src, 20, out=_counted_keypoints(10, src.device))
    with pytest.raises(WarpvxTypeError, match="out: expected a Counted"):
        warpvx.fast_corners(src, 20, out=warpvx.Keypoints.empty())
    with pytest.raises(UnsupportedError, match="Warp backend"):
        warpvx.fast_corners(gray("brick"), 20, out=_counted_keypoints(10, "cpu"), backend="cpu")


# --- backends: kinds, devices, determinism ---------------------------------------------------

def test_device_array_in_device_keypoints_out(warp_backend):
    wp = init_warp()
    src = _on_device(gray("brick"), warp_backend)
    kps = warpvx.fast_corners(src, 20, backend=warp_backend)
    assert not kps.is_host
    assert all(str(getattr(kps, f).device) == str(src.device) for f in warpvx.keypoints.FIELDS)
    assert isinstance(kps.x, wp.array)
    assert _ours(kps) == _cv_fast(gray("brick"), 20, True)


def test_device_array_with_default_backend_stays_on_device(warp_backend):
    src = _on_device(gray("text"), warp_backend)
    kps = warpvx.fast_corners(src, 20)
    assert not kps.is_host and str(kps.x.device) == str(src.device)


def test_deterministic_repeated_runs(warp_backend):
    img = gray("coffee")
    runs = [warpvx.fast_corners(img, 9, nm, backend=warp_backend)
            for nm in (True, True, False, False)]
    for a, b in (runs[:2], runs[2:]):
        for f in warpvx.keypoints.FIELDS:
            assert np.array_equal(getattr(a, f), getattr(b, f))


def test_cpu_and_warp_identical(warp_backend):
    img = gray("camera")
    for nm in (True, False):
        a = warpvx.fast_corners(img, 10, nm, backend="cpu")
        b = warpvx.fast_corners(img, 10, nm, backend=warp_backend)
        for f in warpvx.keypoints.FIELDS:
            assert np.array_equal(getattr(a, f), getattr(b, f)), f


def test_recorded_launches_follow_each_call(warp_backend):
    """Calls of one size replay recorded launches: each must take its own image (a new
    array, or the same array rewritten in place) and threshold, and size its own result."""
    wp = init_warp()
    a, b = gray("camera"), gray("coffee")
    h, w = min(a.shape[0], b.shape[0]), min(a.shape[1], b.shape[1])
    a, b = np.ascontiguousarray(a[:h, :w]), np.ascontiguousarray(b[:h, :w])
    buf = _on_device(a, warp_backend)
    for img, threshold, nonmax in [(a, 10, True), (a, 30, True), (b, 10, True), (b, 10, False),
                                   (a, 25, False), (a, 10, True)]:
        wp.copy(buf, _on_device(img, warp_backend))  # same array, new content
        for src in (buf, _on_device(img, warp_backend)):
            got = warpvx.fast_corners(src, threshold, nonmax, backend=warp_backend)
            want = warpvx.fast_corners(img, threshold, nonmax, backend="cpu")
            for f in warpvx.keypoints.FIELDS:
                assert np.array_equal(getattr(got, f).numpy(), getattr(want, f)), f


# --- warpvx.cv drop-in -----------------------------------------------------------------------

@pytest.mark.parametrize("nonmax", [True, False])
def test_cv_detector_matches_cv2_exactly(backend, nonmax):
    img = gray("camera")
    ref = cv2.FastFeatureDetector_create(25, nonmax).detect(img)
    got = wcv.FastFeatureDetector_create(25, nonmax, backend=backend).detect(img)
    assert isinstance(got, tuple) and all(isinstance(k, cv2.KeyPoint) for k in got)
    as_tuples = lambda ks: [(k.pt, k.size, k.angle, k.response, k.octave) for k in ks]  # noqa: E731
    assert as_tuples(got) == as_tuples(ref)


def test_cv_detector_converts_colour_like_cv2(backend):
    img = bgr("chelsea")
    ref = cv2.FastFeatureDetector_create(20).detect(img)
    got = wcv.FastFeatureDetector_create(20, backend=backend).detect(img)
    assert [k.pt for k in got] == [k.pt for k in ref]


def test_cv_detector_setters_and_errors():
    det = wcv.FastFeatureDetector_create()
    assert det.getThreshold() == 10 and det.getNonmaxSuppression() is True
    assert det.getType() == wcv.FastFeatureDetector_TYPE_9_16 == cv2.FastFeatureDetector_TYPE_9_16
    det.setThreshold(30)
    det.setNonmaxSuppression(False)
    assert det.getThreshold() == 30 and det.getNonmaxSuppression() is False
    img = gray("brick")
    assert len(det.detect(img)) == len(cv2.FastFeatureDetector_create(30, False).detect(img))
    assert len(det.detect(img, mask=np.ones_like(img))) == len(det.detect(img))  # masks: tests/cv
    with runs_on_cv2("type"):
        wcv.FastFeatureDetector_create(10, True, wcv.FAST_FEATURE_DETECTOR_TYPE_7_12).detect(img)
    det.setThreshold(300)  # cv2 clamps to 255
    assert det.detect(img) == ()
