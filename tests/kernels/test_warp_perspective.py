"""warpvx.warp_perspective against cv2.warpPerspective (SPEC §4: as remap; achieved:
bit-exact for ordinary homographies, rare 1-level differences at rounding ties)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.parity import assert_bench_cases_match_opencv
from warpvx.bench.inputs import mild_homography

PHOTOS = ["chelsea", "rocket", "motorcycle"]
INTERPOLATIONS = {"linear": cv2.INTER_LINEAR, "nearest": cv2.INTER_NEAREST}
BORDERS = {"constant": cv2.BORDER_CONSTANT, "replicate": cv2.BORDER_REPLICATE,
           "reflect101": cv2.BORDER_REFLECT_101}


def homographies(w: int, h: int) -> dict:
    """src->dst homographies of increasing strength, all keeping the horizon out of view."""
    c, s = np.cos(np.deg2rad(12)), np.sin(np.deg2rad(12))
    return {
        "mild": mild_homography(w, h),
        "half_pixel_shift": np.array([[1, 0, 0.5], [0, 1, -0.5], [0, 0, 1.0]]),
        "zoom_rotate": np.array([[1.3 * c, -1.3 * s, -40], [1.3 * s, 1.3 * c, -90], [0, 0, 1.0]]),
        "keystone": np.array([[0.9, 0.05, 15], [0.02, 0.85, 10], [4e-4, 2e-4, 1.0]]),
    }


# Backends whose worst linear pixel was measured (1 level off OpenCV's for ordinary
# homographies); CUDA's float arithmetic may round a sub-pixel weight differently: not measured.
MEASURED = ("cpu", "warp-cpu")


def assert_parity(out, ref, interpolation, *, within1=0.999, equal=0.999, max_diff=1, backend=None):
    """SPEC's bar, tightened to what ordinary homographies reach; on a ``MEASURED`` backend also
    no linear pixel off by more than ``max_diff`` (None where float32 rounding near the horizon
    is amplified)."""
    assert out.shape == ref.shape and out.dtype == ref.dtype
    diff = np.abs(out.astype(np.int16) - ref.astype(np.int16))
    if interpolation == "linear":
        assert (diff <= 1).mean() >= within1, f"within 1: {(diff <= 1).mean():.5f}"
        assert max_diff is None or backend not in MEASURED or diff.max() <= max_diff, f"max diff {diff.max()}"
    else:
        assert (diff == 0).mean() >= equal, f"equal: {(diff == 0).mean():.5f}"


# --- smoke ----------------------------------------------------------------------------------


def test_smoke(backend):
    src = bgr("chelsea")
    out = warpvx.warp_perspective(src, np.eye(3), (451, 300), backend=backend)
    np.testing.assert_array_equal(out, src)  # identity is exact


# --- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("src_hw", [(1, 1), (1, 7), (9, 1), (17, 33)])
@pytest.mark.parametrize("dsize", [(1, 1), (5, 3), (40, 21)])
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_shapes(backend, src_hw, dsize, channels):
    rng = np.random.default_rng(sum(src_hw) + channels)
    shape = src_hw if channels == 1 else (*src_hw, channels)
    src = rng.integers(0, 256, shape, dtype=np.uint8)
    m = np.array([[0.8, 0.1, 1.5], [-0.05, 0.9, 0.5], [1e-3, 2e-3, 1.0]])
    for border, bcode in BORDERS.items():
        out = warpvx.warp_perspective(src, m, dsize, "linear", False, border, 33, backend=backend)
        ref = cv2.warpPerspective(src, m, dsize, flags=cv2.INTER_LINEAR, borderMode=bcode,
                                  borderValue=(33, 33, 33, 33))
        expected_shape = (dsize[1], dsize[0]) if channels == 1 else (dsize[1], dsize[0], channels)
        assert out.shape == expected_shape
        assert_parity(out, ref, "linear", within1=1.0, backend=backend)


# --- bad input ------------------------------------------------------------------------------


def test_bad_src(backend):
    with pytest.raises(warpvx.DTypeError, match="src"):
        warpvx.warp_perspective(np.zeros((8, 8), np.int16), np.eye(3), (8, 8), backend=backend)
    with pytest.raises(warpvx.ShapeError, match="src"):
        warpvx.warp_perspective(np.zeros((8, 8, 2), np.uint8), np.eye(3), (8, 8), backend=backend)
    with pytest.raises(warpvx.ShapeError, match="src"):
        warpvx.warp_perspective(np.zeros((8, 0, 3), np.uint8), np.eye(3), (8, 8), backend=backend)
    with pytest.raises(warpvx.WarpvxValueError, match="src"):
        warpvx.warp_perspective(bgr("chelsea")[:, 1:], np.eye(3), (8, 8), backend=backend)


@pytest.mark.parametrize("m,err", [
    (np.zeros((3, 3)), warpvx.WarpvxValueError),  # singular
    (np.array([[1, 2, 3], [2, 4, 6], [0, 0, 1.0]]), warpvx.WarpvxValueError),  # rank 2
    (np.array([[1, 0, np.nan], [0, 1, 0], [0, 0, 1.0]]), warpvx.WarpvxValueError),
    (np.array([[1, 0, np.inf], [0, 1, 0], [0, 0, 1.0]]), warpvx.WarpvxValueError),
    (np.eye(2), warpvx.ShapeError),
    (np.eye(3)[:2], warpvx.ShapeError),
    (np.array([["a"] * 3] * 3), warpvx.DTypeError),
])
@pytest.mark.parametrize("inverse_map", [False, True])
def test_bad_matrix(backend, m, err, inverse_map):
    with pytest.raises(err, match="M"):
        warpvx.warp_perspective(gray("camera"), m, (64, 64), inverse_map=inverse_map, backend=backend)


@pytest.mark.parametrize("dsize,err", [((0, 10), warpvx.WarpvxValueError), ((10, 0), warpvx.WarpvxValueError),
                                       ((0, 0), warpvx.WarpvxValueError), ((-5, 5), warpvx.WarpvxValueError),
                                       ((10.5, 5), warpvx.WarpvxTypeError), (10, warpvx.WarpvxTypeError),
                                       ((1, 2, 3), warpvx.WarpvxTypeError)])
def test_bad_dsize(backend, dsize, err):
    with pytest.raises(err, match="dsize"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), dsize, backend=backend)


def test_bad_modes(backend):
    with pytest.raises(warpvx.UnsupportedError, match="interpolation"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 8), "cubic", backend=backend)
    with pytest.raises(warpvx.UnsupportedError, match="border"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 8), border="wrap", backend=backend)
    with pytest.raises(warpvx.WarpvxTypeError, match="inverse_map"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 8), inverse_map="yes", backend=backend)
    with pytest.raises(warpvx.WarpvxTypeError, match="border_value"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 8), border_value=[1] * 5, backend=backend)


def test_bad_out(backend):
    with pytest.raises(warpvx.ShapeError, match="out"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 6), out=np.empty((8, 6), np.uint8),
                                backend=backend)


def test_unknown_backend():
    with pytest.raises(warpvx.BackendError, match="backend"):
        warpvx.warp_perspective(gray("camera"), np.eye(3), (8, 8), backend="vulkan")


def test_w_zero_takes_border_value(backend):
    """A row of output pixels maps to W == 0 (the line at infinity): border value, no crash."""
    src = bgr("chelsea")
    # dst->src with W = y - 10: output row 10 has W == 0.
    m_inv = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 1.0, -10.0]])
    out = warpvx.warp_perspective(src, m_inv, (64, 32), "linear", True, "constant", (1, 2, 3),
                                  backend=backend)
    np.testing.assert_array_equal(out[10], np.tile([1, 2, 3], (64, 1)))
    ref = cv2.warpPerspective(src, m_inv, (64, 32), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                              borderValue=(1, 2, 3))
    assert_parity(out, ref, "linear", within1=0.99, backend=backend)


# --- OpenCV parity on real photos -----------------------------------------------------------


@pytest.mark.parametrize("name", PHOTOS)
@pytest.mark.parametrize("border", list(BORDERS))
@pytest.mark.parametrize("interpolation", list(INTERPOLATIONS))
def test_parity(backend, name, interpolation, border):
    src = bgr(name)
    h, w = src.shape[:2]
    dsize = (w - 31, h + 12)
    for label, m in homographies(w, h).items():
        for inverse in (False, True):
            flags = INTERPOLATIONS[interpolation] | (cv2.WARP_INVERSE_MAP if inverse else 0)
            out = warpvx.warp_perspective(src, m, dsize, interpolation, inverse, border, (9, 99, 199),
                                          backend=backend)
            ref = cv2.warpPerspective(src, m, dsize, flags=flags, borderMode=BORDERS[border],
                                      borderValue=(9, 99, 199))
            assert_parity(out, ref, interpolation, backend=backend)


def test_parity_gray(backend):
    src = gray("motorcycle")
    h, w = src.shape
    m = homographies(w, h)["keystone"]
    for interp, code in INTERPOLATIONS.items():
        out = warpvx.warp_perspective(src, m, (w, h), interp, backend=backend)
        assert_parity(out, cv2.warpPerspective(src, m, (w, h), flags=code), interp, backend=backend)


def test_parity_strong_perspective_spec_bar(backend):
    """Horizon inside the output: float32 rounding near W == 0 is amplified, so only the SPEC
    bar (linear within 1 on 90%+ of pixels) is asserted."""
    src = bgr("rocket")
    h, w = src.shape[:2]
    m = np.array([[0.7, -0.2, 100], [0.1, 0.9, -20], [1e-3, 5e-4, 1.0]])
    for border, bcode in BORDERS.items():
        out = warpvx.warp_perspective(src, m, (w + 13, h - 20), "linear", False, border, backend=backend)
        ref = cv2.warpPerspective(src, m, (w + 13, h - 20), flags=cv2.INTER_LINEAR, borderMode=bcode)
        assert_parity(out, ref, "linear", within1=0.99, max_diff=None)


@pytest.mark.parametrize("name", ["chelsea", "motorcycle"])
@pytest.mark.parametrize("border", list(BORDERS))
def test_parity_mostly_border(backend, name, border):
    """The photo shrunk to a third, rotated, in a larger output: most pixels come from the
    border rule, each checked against OpenCV's."""
    src = bgr(name)
    h, w = src.shape[:2]
    c, s = np.cos(0.3), np.sin(0.3)
    m = np.array([[0.3 * c, -0.3 * s, w * 0.6], [0.3 * s, 0.3 * c, h * 0.5], [2e-4, -1e-4, 1.0]])
    for interp, code in INTERPOLATIONS.items():
        out = warpvx.warp_perspective(src, m, (w + 40, h + 30), interp, False, border, (3, 30, 240),
                                      backend=backend)
        ref = cv2.warpPerspective(src, m, (w + 40, h + 30), flags=code, borderMode=BORDERS[border],
                                  borderValue=(3, 30, 240))
        assert_parity(out, ref, interp, backend=backend)


def test_inverse_map_equivalence(backend):
    src = bgr("chelsea")
    m = homographies(451, 300)["keystone"]
    a = warpvx.warp_perspective(src, m, (451, 300), backend=backend)
    b = warpvx.warp_perspective(src, np.linalg.inv(m), (451, 300), inverse_map=True, backend=backend)
    diff = np.abs(a.astype(int) - b.astype(int))
    assert (diff <= 1).mean() > 0.999


def test_matrix_inputs(backend):
    """M as a list and as float32 (a wp.array M: test_warp_in_warp_out)."""
    src = gray("camera")
    m = mild_homography(512, 512)
    ref = warpvx.warp_perspective(src, m, (512, 512), backend=backend)
    np.testing.assert_array_equal(warpvx.warp_perspective(src, m.tolist(), (512, 512), backend=backend), ref)
    m32 = m.astype(np.float32)
    assert_parity(warpvx.warp_perspective(src, m32, (512, 512), backend=backend),
                  cv2.warpPerspective(src, m32, (512, 512)), "linear", backend=backend)


# --- kinds in and out -----------------------------------------------------------------------


def test_numpy_in_numpy_out(backend):
    assert type(warpvx.warp_perspective(gray("camera"), np.eye(3), (10, 10), backend=backend)) is np.ndarray


def test_warp_in_warp_out(warp_backend):
    import warp as wp

    from warpvx.backend import resolve_backend

    dev = resolve_backend(warp_backend).device
    src_host = bgr("rocket")
    m = mild_homography(640, 427)
    src = wp.array(src_host, dtype=wp.uint8, device=dev)
    m_wp = wp.array(m, dtype=wp.float64, device=dev)
    out = wp.zeros((427, 640, 3), dtype=wp.uint8, device=dev)
    res = warpvx.warp_perspective(src, m_wp, (640, 427), out=out)
    assert res is out and str(res.device) == str(src.device)
    assert_parity(out.numpy(), cv2.warpPerspective(src_host, m, (640, 427)), "linear", backend=warp_backend)


def test_out_argument(backend):
    src = bgr("chelsea")
    out = np.zeros((100, 120, 3), np.uint8)
    res = warpvx.warp_perspective(src, np.eye(3), (120, 100), out=out, backend=backend)
    assert res is out
    np.testing.assert_array_equal(out, src[:100, :120])


# --- benchmark cases ------------------------------------------------------------------------


def test_bench_cases(backend):
    from warpvx.bench.cases.warp_perspective import cases

    assert_bench_cases_match_opencv(cases(bgr("chelsea")), backend, n_cases=1)