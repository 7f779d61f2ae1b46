"""Brute-force Hamming matching: smoke, shapes, bad input, parity with cv2.BFMatcher."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from warpvx import DTypeError, ShapeError, UnsupportedError, WarpvxTypeError, WarpvxValueError
from warpvx.matching import knn_match_hamming
from tests.images import gray
from tests.parity import on_device
from warpvx.arrays import to_numpy as _np
from tests.cv.fallback import runs_on_cv2


@pytest.fixture(scope="module")
def real_descriptors():
    """OpenCV ORB descriptors of a photo and of a rotated, scaled view of it."""
    img = gray("astronaut")
    h, w = img.shape
    view = cv2.warpAffine(img, cv2.getRotationMatrix2D((w / 2, h / 2), 20, 0.8), (w, h))
    orb = cv2.ORB_create(1500)
    _, d1 = orb.detectAndCompute(img, None)
    _, d2 = orb.detectAndCompute(view, None)
    return d1, d2




def _cv_match(d1, d2, cross_check):
    ms = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=cross_check).match(d1, d2)
    pairs = np.array([(m.queryIdx, m.trainIdx) for m in ms], np.int32).reshape(-1, 2)
    return pairs, np.array([m.distance for m in ms], np.int32)


def _cv_ratio(d1, d2, ratio):
    keep = [(r[0].queryIdx, r[0].trainIdx, r[0].distance)
            for r in cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d1, d2, k=2)
            if len(r) == 2 and r[0].distance < ratio * r[1].distance]
    a = np.array(keep, np.float64).reshape(-1, 3)
    return a[:, :2].astype(np.int32), a[:, 2].astype(np.int32)


def test_match_hamming_smoke(backend, real_descriptors):
    d1, d2 = real_descriptors
    pairs, dist = warpvx.match_hamming(d1, d2, backend=backend)
    assert isinstance(pairs, np.ndarray) and pairs.dtype == np.int32 and dist.dtype == np.int32
    assert pairs.shape == (len(d1), 2) and dist.shape == (len(d1),)
    np.testing.assert_array_equal(pairs[:, 0], np.arange(len(d1)))
    assert dist.min() >= 0 and dist.max() <= 256


@pytest.mark.parametrize("n1, n2, width", [(1, 1, 32), (7, 1, 32), (1, 9, 32), (33, 17, 32),
                                           (20, 31, 17), (5, 40, 64), (0, 5, 32), (5, 0, 32)])
def test_match_hamming_shapes(backend, n1, n2, width):
    rng = np.random.default_rng(n1 * 100 + n2)
    d1 = rng.integers(0, 256, (n1, width), dtype=np.uint8)
    d2 = rng.integers(0, 256, (n2, width), dtype=np.uint8)
    for cross_check in (False, True):
        pairs, dist = warpvx.match_hamming(d1, d2, cross_check, backend=backend)
        want_pairs, want_dist = _cv_match(d1, d2, cross_check) if n1 and n2 else (
            np.zeros((0, 2), np.int32), np.zeros(0, np.int32))
        np.testing.assert_array_equal(pairs, want_pairs)
        np.testing.assert_array_equal(dist, want_dist)
    pairs, _ = warpvx.match_hamming(d1, d2, ratio=0.9, backend=backend)
    if n2 == 1:  # no second neighbour: the ratio test cannot reject
        assert len(pairs) == n1


def test_match_hamming_ties_go_to_lowest_index(backend):
    rng = np.random.default_rng(5)
    base = rng.integers(0, 256, (6, 32), dtype=np.uint8)
    train = np.concatenate([base, base, base[::-1]])  # every query has 3 equal best rows
    for cross_check in (False, True):
        pairs, dist = warpvx.match_hamming(base, train, cross_check, backend=backend)
        want_pairs, want_dist = _cv_match(base, train, cross_check)
        np.testing.assert_array_equal(pairs, want_pairs)
        np.testing.assert_array_equal(dist, want_dist)
    np.testing.assert_array_equal(warpvx.match_hamming(base, train, backend=backend)[0][:, 1],
                                  np.arange(6))


@pytest.mark.parametrize("args, kwargs, err, name", [
    ((np.zeros((4, 32), np.float32), np.zeros((4, 32), np.uint8)), {}, DTypeError, "desc1"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 32), np.int8)), {}, DTypeError, "desc2"),
    ((np.zeros(32, np.uint8), np.zeros((4, 32), np.uint8)), {}, ShapeError, "desc1"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 16), np.uint8)), {}, ShapeError, "desc2"),
    ((np.zeros((4, 0), np.uint8), np.zeros((4, 0), np.uint8)), {}, ShapeError, "desc1"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 32), np.uint8)), {"cross_check": 1},
     WarpvxTypeError, "cross_check"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 32), np.uint8)), {"ratio": 0.0},
     WarpvxValueError, "ratio"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 32), np.uint8)), {"ratio": 1.5},
     WarpvxValueError, "ratio"),
    ((np.zeros((4, 32), np.uint8), np.zeros((4, 32), np.uint8)), {"ratio": "0.8"},
     WarpvxTypeError, "ratio"),
    ((np.zeros((4, 32), np.uint8), [[1, 2]]), {}, WarpvxTypeError, "desc2"),
])
def test_match_hamming_bad_input(args, kwargs, err, name):
    with pytest.raises(err, match=name):
        warpvx.match_hamming(*args, backend="cpu", **kwargs)


def test_knn_bad_k():
    d = np.zeros((3, 32), np.uint8)
    with pytest.raises(UnsupportedError, match="k"):
        knn_match_hamming(d, d, 3, backend="cpu")
    with pytest.raises(WarpvxValueError, match="k"):
        knn_match_hamming(d, d, 0, backend="cpu")


@pytest.mark.parametrize("cross_check", [False, True])
def test_match_equals_bfmatcher(backend, real_descriptors, cross_check):
    d1, d2 = real_descriptors
    pairs, dist = warpvx.match_hamming(d1, d2, cross_check, backend=backend)
    want_pairs, want_dist = _cv_match(d1, d2, cross_check)
    np.testing.assert_array_equal(pairs, want_pairs)
    np.testing.assert_array_equal(dist, want_dist)


@pytest.mark.parametrize("ratio", [0.7, 0.8])
def test_ratio_equals_knn_match(backend, real_descriptors, ratio):
    d1, d2 = real_descriptors
    pairs, dist = warpvx.match_hamming(d1, d2, ratio=ratio, backend=backend)
    want_pairs, want_dist = _cv_ratio(d1, d2, ratio)
    assert len(want_pairs) > 200
    np.testing.assert_array_equal(pairs, want_pairs)
    np.testing.assert_array_equal(dist, want_dist)
    # Both filters: the mutual ones among the ratio survivors.
    both, _ = warpvx.match_hamming(d1, d2, True, ratio, backend=backend)
    mutual = {tuple(p) for p in _cv_match(d1, d2, True)[0]}
    assert {tuple(p) for p in both} == {tuple(p) for p in want_pairs} & mutual


def test_knn_equals_knn_match(backend, real_descriptors):
    d1, d2 = real_descriptors
    idx, dist = knn_match_hamming(d1, d2, 2, backend=backend)
    ref = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d1, d2, k=2)
    np.testing.assert_array_equal(idx, [[m.trainIdx for m in r] for r in ref])
    np.testing.assert_array_equal(dist, [[m.distance for m in r] for r in ref])


def test_rules_switch_between_calls_of_one_size(backend, real_descriptors):
    """Calls of one size share recorded launches: each must apply its own cross check and
    ratio (the sequence goes back and forth between them)."""
    d1, d2 = real_descriptors
    q, t = on_device(d1, backend), on_device(d2, backend)
    for cross_check, ratio in [(False, None), (True, None), (False, 0.7), (True, 0.8),
                               (True, 0.8), (False, None), (True, 0.7)]:
        pairs, dist = warpvx.match_hamming(q, t, cross_check, ratio, backend=backend)
        want_pairs, want_dist = warpvx.match_hamming(d1, d2, cross_check, ratio, backend="cpu")
        np.testing.assert_array_equal(_np(pairs), want_pairs)
        np.testing.assert_array_equal(_np(dist), want_dist)


def _sentinel_out(shape, backend):
    """An (indices, distances) pair on the backend, filled with a value no result holds."""
    return tuple(on_device(np.full(shape, -7, np.int32), backend) for _ in range(2))


@pytest.mark.parametrize("k", [1, 2])
def test_knn_out_receives_the_result(backend, real_descriptors, k):
    d1, d2 = real_descriptors
    want_idx, want_dist = knn_match_hamming(d1, d2, k, backend=backend)
    q, t = on_device(d1, backend), on_device(d2, backend)
    out = _sentinel_out((len(d1), k), backend)
    idx, dist = knn_match_hamming(q, t, k, out=out, backend=backend)
    assert idx is out[0] and dist is out[1]
    np.testing.assert_array_equal(_np(out[0]), want_idx)
    np.testing.assert_array_equal(_np(out[1]), want_dist)


def test_knn_out_reused_across_calls(backend, real_descriptors):
    """The same buffers, another query set: the second result replaces the first."""
    d1, d2 = real_descriptors
    out = _sentinel_out((200, 2), backend)
    t = on_device(d2, backend)
    for rows in (slice(0, 200), slice(200, 400)):
        knn_match_hamming(on_device(np.ascontiguousarray(d1[rows]), backend), t, out=out,
                          backend=backend)
        want_idx, want_dist = knn_match_hamming(d1[rows], d2, backend=backend)
        np.testing.assert_array_equal(_np(out[0]), want_idx)
        np.testing.assert_array_equal(_np(out[1]), want_dist)


def test_knn_host_out_on_warp_backend(warp_backend, real_descriptors):
    """NumPy buffers for a Warp backend: the result is copied into them."""
    d1, d2 = real_descriptors
    out = _sentinel_out((len(d1), 2), "cpu")
    idx, dist = knn_match_hamming(d1, d2, out=out, backend=warp_backend)
    assert idx is out[0] and dist is out[1]
    want_idx, want_dist = knn_match_hamming(d1, d2, backend="cpu")
    np.testing.assert_array_equal(out[0], want_idx)
    np.testing.assert_array_equal(out[1], want_dist)


def test_knn_out_capped_k_and_empty_query(backend):
    rng = np.random.default_rng(3)
    d1 = rng.integers(0, 256, (5, 32), dtype=np.uint8)
    d2 = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    out = _sentinel_out((5, 1), backend)  # k = 2 capped at N2 = 1
    knn_match_hamming(on_device(d1, backend), on_device(d2, backend), 2, out=out,
                      backend=backend)
    want = knn_match_hamming(d1, d2, 2, backend="cpu")
    np.testing.assert_array_equal(_np(out[0]), want[0])
    np.testing.assert_array_equal(_np(out[1]), want[1])
    empty = _sentinel_out((0, 2), backend)
    idx, dist = knn_match_hamming(on_device(d1[:0], backend), on_device(d1, backend), out=empty,
                                  backend=backend)
    assert idx is empty[0] and dist is empty[1]


def _read_only(shape):
    a = np.zeros(shape, np.int32)
    a.flags.writeable = False
    return a


@pytest.mark.parametrize("out, err, name", [
    (np.zeros((4, 2), np.int32), WarpvxTypeError, "out"),
    ((np.zeros((4, 2), np.int32),), WarpvxTypeError, "out"),
    ((np.zeros((4, 2), np.int32), [[0, 0]] * 4), WarpvxTypeError, "out\\[1\\]"),
    ((np.zeros((4, 1), np.int32), np.zeros((4, 2), np.int32)), ShapeError, "out\\[0\\]"),
    ((np.zeros((4, 2), np.int32), np.zeros((3, 2), np.int32)), ShapeError, "out\\[1\\]"),
    ((np.zeros((4, 2), np.int64), np.zeros((4, 2), np.int32)), DTypeError, "out\\[0\\]"),
    ((np.zeros((4, 2), np.int32), _read_only((4, 2))), WarpvxValueError, "out\\[1\\]"),
    ((np.zeros((2, 4), np.int32).T, np.zeros((4, 2), np.int32)), WarpvxValueError, "out\\[0\\]"),
])
def test_knn_bad_out(backend, out, err, name):
    d = np.zeros((4, 32), np.uint8)
    with pytest.raises(err, match=name):
        knn_match_hamming(d, d, 2, out=out, backend=backend)


def test_match_hamming_kernels_refuse_out(backend):
    """M depends on the data: the implementations refuse out= rather than ignore it."""
    from warpvx.registry import get_primitive

    d = on_device(np.zeros((4, 32), np.uint8), backend)
    impl = get_primitive("match_hamming").implementation("cpu" if backend == "cpu" else "warp")
    out = (on_device(np.zeros((4, 2), np.int32), backend), on_device(np.zeros(4, np.int32), backend))
    with pytest.raises(UnsupportedError, match="out"):
        impl(d, d, False, None, out=out)


def test_device_in_device_out(warp_backend, real_descriptors):
    wp = pytest.importorskip("warp")
    d1, d2 = real_descriptors
    dev = "cpu" if warp_backend == "warp-cpu" else warp_backend
    a, b = wp.array(d1, dtype=wp.uint8, device=dev), wp.array(d2, dtype=wp.uint8, device=dev)
    pairs, dist = warpvx.match_hamming(a, b, True)
    assert str(pairs.device) == str(a.device) and str(dist.device) == str(a.device)
    want_pairs, want_dist = _cv_match(d1, d2, True)
    np.testing.assert_array_equal(_np(pairs), want_pairs)
    np.testing.assert_array_equal(_np(dist), want_dist)


def test_cv_bfmatcher_drop_in(real_descriptors):
    from warpvx import cv as wcv

    d1, d2 = real_descriptors
    for cross_check in (False, True):
        ours = wcv.BFMatcher(wcv.NORM_HAMMING, cross_check).match(d1, d2)
        ref = cv2.BFMatcher(cv2.NORM_HAMMING, cross_check).match(d1, d2)
        assert [(m.queryIdx, m.trainIdx, m.distance) for m in ours] == \
            [(m.queryIdx, m.trainIdx, m.distance) for m in ref]
    ours = wcv.BFMatcher_create(wcv.NORM_HAMMING).knnMatch(d1, d2, k=2)
    ref = cv2.BFMatcher(cv2.NORM_HAMMING).knnMatch(d1, d2, k=2)
    assert [[(m.trainIdx, m.distance) for m in r] for r in ours] == \
        [[(m.trainIdx, m.distance) for m in r] for r in ref]
    with runs_on_cv2("normType"):
        wcv.BFMatcher(cv2.NORM_L2).match(d1, d2)
