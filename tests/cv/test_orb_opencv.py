"""warpvx.cv.ORB_create against cv2.ORB_create on real photos: OpenCV's algorithm (FAST per
level, edge border, best by FAST then Harris score, intensity-centroid angle, BRIEF).

Bars, and why: the level-0 image is the input on both sides, so level-0 keypoints must be
cv2's (the same set, positions and angles exact: 99%+, float Harris sums may swap a tie at the
cut-off). Levels >= 1 are resized INTER_LINEAR here and INTER_LINEAR_EXACT in cv2 (pixels
differ by at most 1), which moves a few FAST corners: 90%+ of cv2's keypoints must have one of
ours on the same level within 1 px (measured 95-98%), the counts within 1%. Descriptors of
those pairs: 97%+ of the bits equal (measured 98.6-99.5%; OpenCV 5.0's ORB blurs in floating
point, ours in bit-exact fixed point, and a pixel that differs by 1 can flip a comparison).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.images import gray
from warpvx import ShapeError
from warpvx import cv as wcv
from warpvx._pyramid_sizes import scale_pyramid_sizes
from warpvx.cv import _orb_detect

DATA = Path(__file__).resolve().parent.parent / "data"


def _photo(name: str) -> np.ndarray:
    return cv2.imread(str(DATA / name), cv2.IMREAD_GRAYSCALE) if "." in name else gray(name)


def _pairs(ours, ref, tol: float = 1.0):
    """(i_ref, i_ours): each of cv2's keypoints paired with our nearest on its level, when
    within ``tol`` px."""
    pairs = []
    for level in {k.octave for k in ref}:
        a = [i for i, k in enumerate(ref) if k.octave == level]
        b = [i for i, k in enumerate(ours) if k.octave == level]
        if not b:
            continue
        pa = np.float32([ref[i].pt for i in a])
        pb = np.float32([ours[i].pt for i in b])
        d = np.linalg.norm(pa[:, None] - pb[None], axis=2)
        near = d.argmin(1)
        pairs += [(a[i], b[j]) for i, j in enumerate(near) if d[i, j] <= tol]
    return pairs


def _bits_equal(d_ours, d_ref, pairs) -> float:
    i, j = np.array(pairs).T
    return 1.0 - np.unpackbits(d_ref[i] ^ d_ours[j]).mean()


def _assert_like_cv2(ours, d_ours, ref, d_ref, *, count_tol=0.01, matched=0.90, bits=0.97):
    assert abs(len(ours) - len(ref)) <= max(1, count_tol * len(ref)), (len(ours), len(ref))
    pairs = _pairs(ours, ref)
    assert len(pairs) >= matched * len(ref), f"{len(pairs)} of {len(ref)} at cv2's positions"
    assert _bits_equal(d_ours, d_ref, pairs) >= bits
    level0 = {(k.pt, k.angle) for k in ref if k.octave == 0}
    ours0 = {(k.pt, k.angle) for k in ours if k.octave == 0}
    assert len(level0 & ours0) >= 0.99 * len(level0), (len(level0 & ours0), len(level0))


# --- OpenCV parity ---------------------------------------------------------------------------


@pytest.mark.parametrize("name,n", [("box.png", 500), ("box_in_scene.png", 1000),
                                    ("basketball1.png", 1000), ("leuvenA.jpg", 500),
                                    ("camera", 500)])
def test_orb_keypoints_and_descriptors_like_cv2(backend, name, n):
    img = _photo(name)
    ours, d_ours = wcv.ORB_create(n, backend=backend).detectAndCompute(img, None)
    ref, d_ref = cv2.ORB_create(n).detectAndCompute(img, None)
    _assert_like_cv2(ours, d_ours, ref, d_ref)
    assert {k.octave: k.size for k in ours} == {k.octave: k.size for k in ref}


@pytest.mark.parametrize("setting", [
    dict(nfeatures=300, scaleFactor=1.5, nlevels=4),
    dict(edgeThreshold=15, fastThreshold=10),
    dict(scoreType=cv2.ORB_FAST_SCORE, fastThreshold=30),
    dict(nfeatures=2000, nlevels=3),
], ids=["scale1.5", "edge15-fast10", "fast-score", "2000x3"])
def test_orb_parameters_like_cv2(backend, setting):
    img = _photo("box_in_scene.png")
    ours, d_ours = wcv.ORB_create(**setting, backend=backend).detectAndCompute(img, None)
    ref, d_ref = cv2.ORB_create(**setting).detectAndCompute(img, None)
    _assert_like_cv2(ours, d_ours, ref, d_ref)


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
    _assert_like_cv2(k, d, k_ref, d_ref)
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
    _assert_like_cv2(ours, d_ours, ref, d_ref)
    assert all(mask[int(k.pt[1] + 0.5), int(k.pt[0] + 0.5)] for k in ours)
    assert [k.pt for k in orb.detect(img, mask)] == [k.pt for k in ours]


def test_orb_exact_with_opencvs_pyramid(monkeypatch):
    """Given cv2's own pyramid (INTER_LINEAR_EXACT), detection is cv2's exactly: the same
    keypoints, responses and angles on every level (only the order within a level differs)."""

    def exact_pyramid(src, levels, scale_factor, backend=None):
        out = [src]
        for w, h in scale_pyramid_sizes(src.shape[1], src.shape[0], levels, scale_factor)[1:]:
            out.append(cv2.resize(out[-1], (w, h), interpolation=cv2.INTER_LINEAR_EXACT))
        return out

    monkeypatch.setattr(_orb_detect.pyramid, "scale_pyramid", exact_pyramid)
    for name, masked in (("box_in_scene.png", False), ("leuvenA.jpg", False),
                         ("basketball1.png", True)):
        img = _photo(name)
        mask = _blobs(img.shape) if masked else None
        ours = wcv.ORB_create(1000, backend="cpu").detect(img, mask)
        ref = cv2.ORB_create(1000).detect(img, mask)

        def key(k):
            return k.octave, k.pt, k.angle

        assert sorted(map(key, ours)) == sorted(map(key, ref))
        resp = {key(k): k.response for k in ref}
        assert all(k.response == pytest.approx(resp[key(k)], rel=1e-4) for k in ours)


# --- pieces ----------------------------------------------------------------------------------


def test_retain_best_keeps_ties_at_the_cut_like_opencv():
    score = np.float32([5, 9, 7, 7, 7, 1, 9])
    # the 3rd best is 7: every 7 stays (KeyPointsFilter::retainBest's partition)
    assert retain(score, 3) == [1, 2, 3, 4, 6]
    assert retain(score, 2) == [1, 6]
    assert retain(score, 7) == retain(score, 10) == list(range(7))
    assert retain(score, 0) == []


def retain(score, n):
    return np.flatnonzero(_orb_detect.retain_best(score, n)).tolist()


def test_orb_backends_agree(backend):
    img = _photo("box.png")
    k_cpu, d_cpu = wcv.ORB_create(500, backend="cpu").detectAndCompute(img, None)
    k, d = wcv.ORB_create(500, backend=backend).detectAndCompute(img, None)
    same = {(p.pt, p.octave) for p in k} & {(p.pt, p.octave) for p in k_cpu}
    assert len(same) >= 0.99 * len(k_cpu) and abs(len(k) - len(k_cpu)) <= 2
    pairs = _pairs(k, k_cpu, tol=0.0)
    assert _bits_equal(d, d_cpu, pairs) >= 0.999


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
