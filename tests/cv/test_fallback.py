"""warpvx.cv as OpenCV's own tests and samples call it: calls outside the accelerated subset run
on cv2 (one CvFallbackWarning naming the argument), detection masks, LK flags, detector and
matcher getters/setters; every result against cv2 on real images."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.cv.fallback import runs_on_cv2
from tests.images import bgr, gray
from warpvx import WarpvxError
from warpvx import cv as wcv
from warpvx.cv import CvFallbackWarning


def _mask(img):
    """255 except a disc and a left band, as OpenCV's lk_track sample masks tracked points."""
    m = np.full(img.shape[:2], 255, np.uint8)
    cv2.circle(m, (img.shape[1] // 2, img.shape[0] // 2), img.shape[0] // 4, 0, -1)
    m[:, : img.shape[1] // 5] = 0
    return m


def test_unsupported_code_runs_on_cv2_and_warns_once():
    img = bgr("chelsea")
    with runs_on_cv2("code"):
        out = wcv.cvtColor(img, cv2.COLOR_BGR2HSV)
    assert np.array_equal(out, cv2.cvtColor(img, cv2.COLOR_BGR2HSV))
    with warnings.catch_warnings():
        warnings.simplefilter("error", CvFallbackWarning)  # once per function and argument
        wcv.cvtColor(img, cv2.COLOR_BGR2HSV)


def test_other_dtype_runs_on_cv2():
    img = bgr("chelsea").astype(np.float32) / 255
    with runs_on_cv2("src"):
        out = wcv.GaussianBlur(img, (5, 5), 1.2)
    assert np.array_equal(out, cv2.GaussianBlur(img, (5, 5), 1.2))


def test_input_cv2_rejects_raises_warpvx_error():
    with pytest.raises(WarpvxError, match="code"):
        wcv.cvtColor(np.zeros((4, 4, 2), np.uint8), cv2.COLOR_BGR2HSV)


def test_warp_arrays_are_not_handed_over(warp_backend):
    import warp as wp

    src = wp.array(bgr("chelsea"), dtype=wp.uint8, device="cpu")
    with pytest.raises(WarpvxError, match="code"):
        wcv.cvtColor(src, cv2.COLOR_BGR2HSV)


def test_umat_runs_on_cv2():
    img = gray("camera")
    with runs_on_cv2("UMat"):
        out = wcv.goodFeaturesToTrack(cv2.UMat(img), 50, 0.05, 5)
    assert isinstance(out, cv2.UMat)
    assert np.array_equal(out.get(), cv2.goodFeaturesToTrack(img, 50, 0.05, 5))


@pytest.mark.parametrize("name", ["camera", "brick", "coffee"])
@pytest.mark.parametrize("params", [
    dict(maxCorners=500, qualityLevel=0.3, minDistance=7, blockSize=7),
    dict(maxCorners=0, qualityLevel=0.01, minDistance=8, blockSize=19),
    dict(maxCorners=100, qualityLevel=0.02, minDistance=0.5, useHarrisDetector=True),
])
def test_good_features_mask_like_cv2(backend, name, params):
    img = gray(name)
    mask = _mask(img)
    ref = cv2.goodFeaturesToTrack(img, mask=mask, **params)
    got = wcv.goodFeaturesToTrack(img, mask=mask, backend=backend, **params)
    assert got.shape == ref.shape and got.dtype == ref.dtype
    if backend == "cpu":
        assert np.array_equal(got, ref)
    else:  # Warp's response may differ in the last float bits: same corners, nearly all in order
        assert (got == ref).all(axis=2).mean() >= 0.98
    assert all(mask[int(y), int(x)] for x, y in got.reshape(-1, 2))


def test_good_features_mask_errors():
    img = gray("camera")
    with pytest.raises(WarpvxError, match="mask"):
        wcv.goodFeaturesToTrack(img, 10, 0.01, 3, mask=np.ones((5, 5), np.uint8))
    assert wcv.goodFeaturesToTrack(img, 10, 0.01, 3, mask=np.zeros_like(img)) is None


def test_fast_mask_like_cv2(backend):
    img = gray("brick")
    mask = _mask(img)
    det = wcv.FastFeatureDetector_create(20, backend=backend)
    got = det.detect(img, mask)
    ref = cv2.FastFeatureDetector_create(20).detect(img, mask)
    assert [k.pt for k in got] == [k.pt for k in ref]


def test_orb_setters_getters_and_write_read():
    orb = wcv.ORB_create()
    orb.setMaxFeatures(200)
    orb.setScaleFactor(1.3)
    orb.setNLevels(5)
    orb.setEdgeThreshold(28)
    orb.setFastThreshold(12)
    assert (orb.getMaxFeatures(), orb.getNLevels(), orb.getEdgeThreshold(), orb.getFastThreshold()) \
        == (200, 5, 28, 12)
    with tempfile.TemporaryDirectory() as d:
        path = str(Path(d) / "orb.yml")
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_WRITE)
        orb.write(fs, "ORB")
        fs.release()
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
        ref, back = cv2.ORB_create(), wcv.ORB_create()
        ref.read(fs.getNode("ORB"))
        back.read(fs.getNode("ORB"))
        fs.release()
    assert (ref.getMaxFeatures(), ref.getNLevels(), ref.getEdgeThreshold()) == (200, 5, 28)
    assert (back.getMaxFeatures(), back.getNLevels(), back.getEdgeThreshold()) == (200, 5, 28)
    assert back.getScaleFactor() == pytest.approx(1.3)


def test_orb_unaccelerated_parameters_run_on_cv2():
    img = gray("brick")
    orb = wcv.ORB_create(500)
    orb.setWTA_K(3)
    assert orb.getWTA_K() == 3
    with runs_on_cv2("WTA_K"):
        kps, desc = orb.detectAndCompute(img, None)
    ref_kps, ref_desc = cv2.ORB_create(500, WTA_K=3).detectAndCompute(img, None)
    assert [k.pt for k in kps] == [k.pt for k in ref_kps] and np.array_equal(desc, ref_desc)


def test_fast_getters_setters_and_other_types():
    img = gray("brick")
    det = wcv.FastFeatureDetector_create()
    det.setType(wcv.FAST_FEATURE_DETECTOR_TYPE_7_12)
    assert det.getType() == cv2.FAST_FEATURE_DETECTOR_TYPE_7_12
    with runs_on_cv2("type"):
        got = det.detect(img)
    ref = cv2.FastFeatureDetector_create(10, True, cv2.FAST_FEATURE_DETECTOR_TYPE_7_12).detect(img)
    assert [k.pt for k in got] == [k.pt for k in ref]


def test_bfmatcher_train_collection_like_cv2(backend):
    orb = cv2.ORB_create(300)
    descs = [orb.detectAndCompute(gray(n), None)[1] for n in ("camera", "brick", "coffee")]
    ours = wcv.BFMatcher(wcv.NORM_HAMMING, backend=backend)
    ref = cv2.BFMatcher(cv2.NORM_HAMMING)
    for m in (ours, ref):
        m.add(descs[1:])
    assert len(ours.getTrainDescriptors()) == 2 and not ours.empty()

    def key(ms):
        return [[(m.queryIdx, m.trainIdx, m.imgIdx, m.distance) for m in r] for r in ms]

    assert key(ours.knnMatch(descs[0], k=2)) == key(ref.knnMatch(descs[0], k=2))
    assert key([ours.match(descs[0])]) == key([ref.match(descs[0])])
    ours.clear()
    assert ours.empty()


def test_bfmatcher_mask_and_norm_run_on_cv2():
    orb = cv2.ORB_create(200)
    d1 = orb.detectAndCompute(gray("camera"), None)[1]
    d2 = orb.detectAndCompute(gray("brick"), None)[1]
    mask = np.zeros((len(d1), len(d2)), np.uint8)
    mask[:, ::2] = 1
    with runs_on_cv2("mask"):
        got = wcv.BFMatcher(wcv.NORM_HAMMING).match(d1, d2, mask)
    ref = cv2.BFMatcher(cv2.NORM_HAMMING).match(d1, d2, mask)
    assert [(m.queryIdx, m.trainIdx) for m in got] == [(m.queryIdx, m.trainIdx) for m in ref]


def test_lk_min_eigenvals_runs_on_cv2():
    a, b = gray("camera"), np.roll(gray("camera"), (2, 3), (0, 1))
    pts = cv2.goodFeaturesToTrack(a, 100, 0.01, 7)
    with runs_on_cv2("flags"):
        got = wcv.calcOpticalFlowPyrLK(a, b, pts, None, flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)
    ref = cv2.calcOpticalFlowPyrLK(a, b, pts, None, flags=cv2.OPTFLOW_LK_GET_MIN_EIGENVALS)
    for g, r in zip(got, ref):
        assert np.array_equal(g, r)


def test_lk_track_pattern(backend):
    """OpenCV's lk_track loop in brief: mask out tracked points, detect, track forward and back."""
    a = gray("coffee")
    b = np.ascontiguousarray(np.roll(a, (1, 2), (0, 1)))
    params = dict(winSize=(15, 15), maxLevel=2,
                  criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 10, 0.03))
    mask = _mask(a)
    p0 = wcv.goodFeaturesToTrack(a, 200, 0.3, 7, mask=mask, blockSize=7, backend=backend)
    p1, st, _ = wcv.calcOpticalFlowPyrLK(a, b, p0, None, backend=backend, **params)
    p0r, _, _ = wcv.calcOpticalFlowPyrLK(b, a, p1, None, backend=backend, **params)
    good = np.abs(p0 - p0r).reshape(-1, 2).max(-1) < 1
    assert good.mean() > 0.9
    assert np.allclose((p1 - p0).reshape(-1, 2)[good], (2, 1), atol=0.1)
