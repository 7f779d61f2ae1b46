"""warpvx.color_convert against cv2.cvtColor (SPEC §4: each pixel within 1; achieved: exact)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.parity import assert_images_match, assert_bench_cases_match_opencv
from warpvx.bench.inputs import bgr_to_nv12
from warpvx.color import CODES, code_spec

PHOTOS = ["chelsea", "rocket", "motorcycle"]  # 451x300, 640x427, 741x500


def assert_parity(out, ref):
    # bit-exact against OpenCV 5.0; 99% equal leaves room for other OpenCV versions
    assert_images_match(out, ref, min_equal=0.99)


def _input_for(code: int, name: str) -> list[np.ndarray]:
    """Real inputs a code accepts: BGR and BGRA photos, gray photos, NV12 planes."""
    kind = code_spec(code).kind
    if kind in ("gray", "reorder"):
        img = bgr(name)
        alpha = gray(name)[..., None]  # a real, non-constant alpha channel
        return [img, np.ascontiguousarray(np.concatenate([img, alpha], axis=2))]
    if kind == "expand":
        return [gray(name)]
    return [bgr_to_nv12(bgr(name))]


# --- smoke ----------------------------------------------------------------------------------


def test_smoke(backend):
    out = warpvx.color_convert(bgr("chelsea"), "BGR2GRAY", backend=backend)
    assert isinstance(out, np.ndarray)
    assert out.shape == (300, 451) and out.dtype == np.uint8


# --- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("h,w", [(1, 1), (2, 2), (7, 13), (31, 2), (64, 65)])
@pytest.mark.parametrize("code,cin,expect_c", [("BGR2GRAY", 3, None), ("BGRA2GRAY", 4, None),
                                               ("BGR2RGB", 3, 3), ("BGR2BGRA", 3, 4),
                                               ("BGRA2BGR", 4, 3), ("GRAY2BGR", 1, 3),
                                               ("GRAY2BGRA", 1, 4)])
def test_shapes(backend, h, w, code, cin, expect_c):
    rng = np.random.default_rng(h * 100 + w)
    shape = (h, w) if cin == 1 else (h, w, cin)
    src = rng.integers(0, 256, shape, dtype=np.uint8)
    out = warpvx.color_convert(src, code, backend=backend)
    assert out.shape == ((h, w) if expect_c is None else (h, w, expect_c))
    assert_parity(out, cv2.cvtColor(src, CODES[code]))


@pytest.mark.parametrize("h,w", [(2, 2), (4, 6), (10, 14), (426, 640)])
def test_shapes_nv12(backend, h, w):
    rng = np.random.default_rng(h + w)
    src = rng.integers(0, 256, (h * 3 // 2, w), dtype=np.uint8)
    out = warpvx.color_convert(src, "YUV2BGR_NV12", backend=backend)
    assert out.shape == (h, w, 3)
    assert_parity(out, cv2.cvtColor(src, cv2.COLOR_YUV2BGR_NV12))


def test_gray_hxwx1_input(backend):
    g = gray("chelsea")
    out = warpvx.color_convert(g[..., None].copy(), "GRAY2BGR", backend=backend)
    assert_parity(out, cv2.cvtColor(g, cv2.COLOR_GRAY2BGR))


# --- bad input ------------------------------------------------------------------------------


def test_bad_dtype(backend):
    with pytest.raises(warpvx.DTypeError, match="src"):
        warpvx.color_convert(bgr("chelsea").astype(np.float32), "BGR2GRAY", backend=backend)


@pytest.mark.parametrize("code,shape", [("BGR2GRAY", (8, 8)), ("BGR2GRAY", (8, 8, 2)),
                                        ("GRAY2BGR", (8, 8, 3)), ("BGR2RGB", (8, 8)),
                                        ("YUV2BGR_NV12", (12, 8, 3))])
def test_bad_channels(backend, code, shape):
    with pytest.raises(warpvx.ShapeError, match="src"):
        warpvx.color_convert(np.zeros(shape, np.uint8), code, backend=backend)


def test_empty(backend):
    with pytest.raises(warpvx.ShapeError, match="src"):
        warpvx.color_convert(np.zeros((0, 5, 3), np.uint8), "BGR2GRAY", backend=backend)


def test_not_contiguous(backend):
    with pytest.raises(warpvx.WarpvxValueError, match="src"):
        warpvx.color_convert(bgr("chelsea")[:, ::2], "BGR2GRAY", backend=backend)


@pytest.mark.parametrize("shape", [(13, 8), (12, 7), (1, 8)])
def test_bad_nv12_size(backend, shape):
    with pytest.raises(warpvx.ShapeError, match="src"):
        warpvx.color_convert(np.zeros(shape, np.uint8), "YUV2BGR_NV12", backend=backend)


@pytest.mark.parametrize("code", ["BGR2HSV", "COLOR_BGR2LAB", 40, 999, -1, None, 6.0, True])
def test_unknown_code(backend, code):
    with pytest.raises(warpvx.UnsupportedError, match="code"):
        warpvx.color_convert(bgr("chelsea"), code, backend=backend)


def test_unknown_backend():
    with pytest.raises(warpvx.BackendError, match="backend"):
        warpvx.color_convert(bgr("chelsea"), "BGR2GRAY", backend="tpu")


def test_bad_out(backend):
    src = bgr("chelsea")
    with pytest.raises(warpvx.ShapeError, match="out"):
        warpvx.color_convert(src, "BGR2GRAY", out=np.empty((300, 451, 1), np.uint8), backend=backend)
    with pytest.raises(warpvx.DTypeError, match="out"):
        warpvx.color_convert(src, "BGR2GRAY", out=np.empty((300, 451), np.float32), backend=backend)


# --- OpenCV parity on real photos -----------------------------------------------------------


@pytest.mark.parametrize("name", PHOTOS)
@pytest.mark.parametrize("code", sorted(set(CODES.values())))
def test_parity_opencv(backend, code, name):
    for src in _input_for(code, name):
        assert_parity(warpvx.color_convert(src, code, backend=backend), cv2.cvtColor(src, code))


@pytest.mark.parametrize("spelling", ["BGR2GRAY", "COLOR_BGR2GRAY", "bgr2gray", cv2.COLOR_BGR2GRAY])
def test_code_spellings(backend, spelling):
    src = bgr("rocket")
    assert_parity(warpvx.color_convert(src, spelling, backend=backend),
                  cv2.cvtColor(src, cv2.COLOR_BGR2GRAY))


def test_gray_all_colours_exact():
    """All 2^24 BGR colours on the Warp kernel, against OpenCV."""
    v = np.arange(1 << 24, dtype=np.uint32)
    img = np.stack([v >> 16, (v >> 8) & 255, v & 255], -1).astype(np.uint8).reshape(4096, 4096, 3)
    out = warpvx.color_convert(img, "BGR2GRAY", backend="warp-cpu")
    assert_parity(out, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))


def test_nv12_all_yuv_exact():
    """Every (U, V) pair with Y sweeping its whole range, against OpenCV."""
    u, v = np.meshgrid(np.arange(256, dtype=np.uint8), np.arange(256, dtype=np.uint8))
    uv = np.stack([u, v], -1).reshape(256, 512)
    y = (np.arange(512 * 512, dtype=np.uint32) * 7 % 256).astype(np.uint8).reshape(512, 512)
    plane = np.ascontiguousarray(np.vstack([y, uv]))
    for code in (cv2.COLOR_YUV2BGR_NV12, cv2.COLOR_YUV2RGB_NV21):
        out = warpvx.color_convert(plane, code, backend="warp-cpu")
        assert_parity(out, cv2.cvtColor(plane, code))


# --- kinds in and out -----------------------------------------------------------------------


def test_numpy_in_numpy_out(backend):
    out = warpvx.color_convert(bgr("chelsea"), "BGR2RGB", backend=backend)
    assert type(out) is np.ndarray


def test_warp_in_warp_out(warp_backend):
    import warp as wp

    src_host = bgr("chelsea")
    src = wp.array(src_host, dtype=wp.uint8, device=_device(warp_backend))
    out = warpvx.color_convert(src, "BGR2GRAY", backend=warp_backend)
    assert isinstance(out, wp.array) and str(out.device) == str(src.device)
    assert_parity(out.numpy(), cv2.cvtColor(src_host, cv2.COLOR_BGR2GRAY))
    # backend=None follows the wp.array's device
    out2 = warpvx.color_convert(src, "BGR2GRAY")
    assert isinstance(out2, wp.array) and str(out2.device) == str(src.device)


def test_out_argument(backend):
    src = bgr("rocket")
    out = np.zeros((427, 640, 3), np.uint8)
    res = warpvx.color_convert(src, "BGR2RGB", out=out, backend=backend)
    assert res is out
    np.testing.assert_array_equal(out, src[..., ::-1])


def test_out_argument_warp(warp_backend):
    import warp as wp

    src_host = bgr("rocket")
    dev = _device(warp_backend)
    src = wp.array(src_host, dtype=wp.uint8, device=dev)
    out = wp.zeros((427, 640), dtype=wp.uint8, device=dev)
    res = warpvx.color_convert(src, "BGR2GRAY", out=out, backend=warp_backend)
    assert res is out
    assert_parity(out.numpy(), cv2.cvtColor(src_host, cv2.COLOR_BGR2GRAY))


def _device(backend_name: str) -> str:
    from warpvx.backend import resolve_backend

    return resolve_backend(backend_name).device


# --- benchmark cases ------------------------------------------------------------------------


def test_bench_cases(backend):
    from warpvx.bench.cases.color_convert import cases

    assert_bench_cases_match_opencv(cases(bgr("chelsea")), backend, n_cases=3)