"""warpvx.cv.ORB_create against cv2.ORB_create on real photos: OpenCV's algorithm (FAST per
level, edge border, best by FAST then Harris score, intensity-centroid angle, BRIEF).

Bars, and why: the pyramid (INTER_LINEAR_EXACT), FAST, the border, the Harris score, the
rankings, the angle, the blur and the BRIEF tests are OpenCV's arithmetic, so the keypoints must
be cv2's: the same count (within 1) and 99.5%+ of cv2's keypoints with one of ours at exactly
its position, level, angle, size and response (measured 100%; the margin is for a FAST corner a
backend might score differently). Their descriptors: 99.99%+ of the bits equal on ``cpu``
(cv2's own separable float blur; measured on 7 photos x 2 sizes: one bit of one descriptor of
12,000 differed, a float cos/sin rounding a pattern point the other way), 99.9%+ on Warp, whose
float32 blur may also round a pixel the other way (2 pixels of 420000 on one photo).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.images import gray
from warpvx import ShapeError
from warpvx import cv as wcv
from warpvx.arrays import to_numpy, to_warp
from warpvx.backend import resolve_backend
from warpvx.cv import _orb_detect
from warpvx.cv._orb_levels import resize_exact

DATA = Path(__file__).resolve().parent.parent / "data"


def _photo(name: str) -> np.ndarray:
    return cv2.imread(str(DATA / name), cv2.IMREAD_GRAYSCALE) if "." in name else gray(name)


def _pairs(ours, ref):
    """(i_ref, i_ours): cv2's keypoints paired with ours at exactly their position, level and
    angle."""
    index = {(k.pt, k.octave, k.angle): i for i, k in enumerate(ours)}
    return [(i, index[key]) for i, key in enumerate((k.pt, k.octave, k.angle) for k in ref)
            if key in index]


def _bits_equal(d_ours, d_ref, pairs) -> float:
    i, j = np.array(pairs).T
    return 1.0 - np.unpackbits(d_ref[i] ^ d_ours[j]).mean()


def _assert_like_cv2(ours, d_ours, ref, d_ref, backend):
    assert abs(len(ours) - len(ref)) <= 1, (len(ours), len(ref))
    pairs = _pairs(ours, ref)
    assert len(pairs) >= 0.995 * len(ref), f"{len(pairs)} of {len(ref)} as cv2's"
    resp = np.float32([[ref[i].response, ours[j].response] for i, j in pairs])
    np.testing.assert_array_equal(resp[:, 1], resp[:, 0])
    assert {k.octave: k.size for k in ours} == {k.octave: k.size for k in ref}
    assert _bits_equal(d_ours, d_ref, pairs) >= (0.9999 if backend == "cpu" else 0.999)


# --- OpenCV parity ---------------------------------------------------------------------------


@pytest.mark.parametrize("name,n", [("box.png", 500), ("box_in_scene.png", 1000),
                                    ("basketball1.png", 1000), ("leuvenA.jpg", 500),
                                    ("camera", 500)])
def test_orb_keypoints_and_descriptors_like_cv2(backend, name, n):
    img = _photo(name)
    ours, d_ours = wcv.ORB_create(n, backend=backend).detectAndCompute(img, None)
    ref, d_ref = cv2.ORB_create(n).detectAndCompute(img, None)
    _assert_like_cv2(ours, d_ours, ref, d_ref, backend)


@pytest.mark.parametrize("setting", [
    dict(nfeatures=300, scaleFactor=1.5, nlevels=4),
    dict(edgeThreshold=15, fastThreshold=10),
    dict(scoreType=cv2.ORB_FAST_SCORE, fastThreshold=30),
    dict(nfeatures=2000, nlevels=3),
    dict(edgeThreshold=3),
], ids=["scale1.5", "edge15-fast10", "fast-score", "2000x3", "edge3-reflected-border"])
def test_orb_parameters_like_cv2(backend, setting):
    img = _photo("box_in_scene.png")
    ours, d_ours = wcv.ORB_create(**setting, backend=backend).detectAndCompute(img, None)
    ref, d_ref = cv2.ORB_create(**setting).detectAndCompute(img, None)
    _assert_like_cv2(ours, d_ours, ref, d_ref, backend)


def test_orb_setters_change_detection_like_cv2(backend):
    img = _photo("leuvenA.jpg")
    ours, ref = wcv.ORB_create(backend=backend), cv2.ORB_create()
    for o in (ours, ref):
        o.setMaxFeatures(700)
        o.setScaleFactor(1.3)
        o.setNLevels(6)
        o.setEdgeThreshold(20)
        o.setFastThreshold(15)
        o.setScoreType(cv2.ORB_HARRIS_SCORE)
    k, d = ours.detectAndCompute(img, None)
    k_ref, d_ref = ref.detectAndCompute(img, None)
    _assert_like_cv2(k, d, k_ref, d_ref, backend)
    assert max(k.octave for k in k) == 5
    assert min(min(p.pt) for p in k if p.octave == 0) >= 20


def _blobs(shape):
    """A mask of discs of values 1-255 (cv2 takes any nonzero value as inside)."""
    rng = np.random.default_rng(1)
    mask = np.zeros(shape, np.uint8)
    for _ in range(30):
        centre = (int(rng.integers(0, shape[1])), int(rng.integers(0, shape[0])))
        cv2.circle(mask, centre, int(rng.integers(10, 60)), int(rng.integers(1, 256)), -1)
    return mask


def test_orb_mask_like_cv2(backend):
    """As cv2, each level is masked before the best are kept: a masked image gets its own
    nfeatures, not a subset of the unmasked ones."""
    img = _photo("basketball1.png")
    mask = _blobs(img.shape)
    orb = wcv.ORB_create(500, backend=backend)
    ours, d_ours = orb.detectAndCompute(img, mask)
    ref, d_ref = cv2.ORB_create(500).detectAndCompute(img, mask)
    _assert_like_cv2(ours, d_ours, ref, d_ref, backend)
    assert all(mask[int(k.pt[1] + 0.5), int(k.pt[0] + 0.5)] for k in ours)
    assert [k.pt for k in orb.detect(img, mask)] == [k.pt for k in ours]


@pytest.mark.parametrize("edge", [31, 5])
def test_orb_compute_like_cv2(backend, edge):
    """compute(): the keypoints cv2 keeps (edgeThreshold border) and their descriptors, on
    cv2's ORB keypoints and on FAST corners near the border (octave 0, reflected reads)."""
    img = _photo("basketball1.png")
    fast = cv2.FastFeatureDetector_create(30).detect(img)
    for kps in (cv2.ORB_create(800).detect(img), fast):
        ours, d_ours = wcv.ORB_create(edgeThreshold=edge, backend=backend).compute(img, kps)
        ref, d_ref = cv2.ORB_create(edgeThreshold=edge).compute(img, kps)
        assert [k.pt for k in ours] == [k.pt for k in ref]
        pairs = list(zip(range(len(ref)), range(len(ref))))
        assert _bits_equal(d_ours, d_ref, pairs) >= (0.9999 if backend == "cpu" else 0.999)


# --- pieces ----------------------------------------------------------------------------------


def test_retain_best_keeps_ties_at_the_cut_like_opencv():
    score = np.float32([5, 9, 7, 7, 7, 1, 9])
    # the 3rd best is 7: every 7 stays (KeyPointsFilter::retainBest's partition)
    assert retain(score, 3) == [1, 2, 3, 4, 6]
    assert retain(score, 2) == [1, 6]
    assert retain(score, 7) == retain(score, 10) == list(range(7))
    assert retain(score, 0) == []


@pytest.mark.parametrize("size", [(427, 320), (256, 192), (1024, 391), (100, 37)])
def test_resize_exact_is_cv2s_inter_linear_exact(backend, size):
    img = _photo("box_in_scene.png")
    src = img if backend == "cpu" else to_warp(img, resolve_backend(backend).device)
    np.testing.assert_array_equal(
        to_numpy(resize_exact(src, size)),
        cv2.resize(img, size, interpolation=cv2.INTER_LINEAR_EXACT))


def test_harris_at_is_corner_harris_at_the_points():
    """OpenCV ORB's per-point Harris (integer sums) against cv2.cornerHarris (block 7, Sobel
    3, k 0.04: the same formula and scaling, float sums) where the window and its Sobel stay
    inside (nearer the edge ORB reflects the image, cornerHarris the gradients)."""
    img = _photo("leuvenA.jpg")
    ref = cv2.cornerHarris(img, 7, 3, 0.04)
    ys, xs = np.mgrid[4:img.shape[0] - 4:37, 4:img.shape[1] - 4:29]
    x, y = xs.ravel().astype(np.int32), ys.ravel().astype(np.int32)
    got = _orb_detect.harris_at(img, x, y)
    np.testing.assert_allclose(got, ref[y, x], rtol=1e-4, atol=1e-4 * np.abs(ref).max())


def retain(score, n):
    return np.flatnonzero(_orb_detect.retain_best(score, n)).tolist()


def test_orb_backends_agree(backend):
    img = _photo("box.png")
    k_cpu, d_cpu = wcv.ORB_create(500, backend="cpu").detectAndCompute(img, None)
    k, d = wcv.ORB_create(500, backend=backend).detectAndCompute(img, None)
    same = {(p.pt, p.octave) for p in k} & {(p.pt, p.octave) for p in k_cpu}
    assert len(same) >= 0.99 * len(k_cpu) and abs(len(k) - len(k_cpu)) <= 2
    assert _bits_equal(d, d_cpu, _pairs(k, k_cpu)) >= 0.999


def test_orb_small_images_need_no_fallback(backend, recwarn):
    """Levels too small for the border are skipped, as cv2 finds nothing there."""
    for h, w in ((8, 13), (40, 45), (64, 69), (100, 90)):
        img = np.ascontiguousarray(gray("camera")[:h, :w])
        got = wcv.ORB_create(backend=backend).detectAndCompute(img, None)
        ref = cv2.ORB_create().detectAndCompute(img, None)
        assert [k.pt for k in got[0]] == [k.pt for k in ref[0]]
        assert (got[1] is None) == (ref[1] is None)
    assert not [w for w in recwarn if issubclass(w.category, wcv.CvFallbackWarning)]


# --- bad input -------------------------------------------------------------------------------


def test_orb_bad_mask_names_the_argument(backend):
    img = _photo("box.png")
    with pytest.raises(ShapeError, match="mask"):
        wcv.ORB_create(backend=backend).detectAndCompute(img, np.zeros((10, 10), np.uint8))


def test_orb_compute_octave_without_a_level_names_keypoints(backend):
    img = _photo("box.png")
    kp = cv2.KeyPoint(100.0, 100.0, 31.0, 0.0, 0.0, 31)  # level 31 at scale 2: empty
    with pytest.raises(cv2.error):
        cv2.ORB_create(scaleFactor=2).compute(img, [kp])
    with pytest.raises(ShapeError, match="keypoints"):
        wcv.ORB_create(scaleFactor=2, backend=backend).compute(img, [kp])
