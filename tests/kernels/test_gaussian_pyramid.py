"""warpvx.gaussian_pyramid against repeated cv2.pyrDown (SPEC §4 bar: each pixel within 1;
achieved: bit-exact, pyrDown being integer arithmetic), and the pyrDown / buildPyramid
drop-ins."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.parity import assert_images_match as assert_parity, crop, on_device
from warpvx import cv as wcv
from warpvx.errors import BackendError, DTypeError, ShapeError, UnsupportedError, WarpvxTypeError, WarpvxValueError
from tests.cv.fallback import runs_on_cv2






def cv_pyramid(src, levels):
    out = [src]
    for _ in range(1, levels):
        out.append(cv2.pyrDown(out[-1]))
    return out


# --- smoke ----------------------------------------------------------------------------------


def test_smoke(backend):
    src = crop(gray("camera"), 64, 80)
    pyr = warpvx.gaussian_pyramid(src, 3, backend=backend)
    assert isinstance(pyr, list) and len(pyr) == 3
    assert [p.shape for p in pyr] == [(64, 80), (32, 40), (16, 20)]
    assert pyr[0] is src
    assert all(isinstance(p, np.ndarray) and p.dtype == np.uint8 for p in pyr)


# --- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("shape,levels", [((1, 1), 1), ((1, 2), 2), ((3, 1), 3), ((5, 7), 4), ((2, 3), 3),
                                          ((33, 17), 6), ((31, 30, 3), 5), ((15, 16, 4), 4), ((9, 8, 1), 3)])
def test_shapes(backend, shape, levels):
    rng = np.random.default_rng(sum(shape))
    src = rng.integers(0, 256, shape, dtype=np.uint8)
    pyr = warpvx.gaussian_pyramid(src, levels, backend=backend)
    plain = src[..., 0] if len(shape) == 3 and shape[2] == 1 else src
    ref = cv_pyramid(plain, levels)
    assert len(pyr) == levels
    for lvl in range(1, levels):
        assert_parity(pyr[lvl], ref[lvl])


def test_one_level_is_the_input(backend):
    src = crop(gray("camera"), 10, 10)
    pyr = warpvx.gaussian_pyramid(src, 1, backend=backend)
    assert len(pyr) == 1 and pyr[0] is src


# --- bad input ------------------------------------------------------------------------------


def _img():
    return crop(gray("camera"), 20, 30)


@pytest.mark.parametrize("src,levels,kwargs,exc,name", [
    (np.zeros((8, 8), np.float32), 2, {}, DTypeError, "src"),
    (np.zeros((8, 8, 2), np.uint8), 2, {}, ShapeError, "src"),
    (np.zeros((8, 0), np.uint8), 2, {}, ShapeError, "src"),
    (np.zeros((8, 16), np.uint8)[:, ::2], 2, {}, WarpvxValueError, "src"),
    ([[1]], 2, {}, WarpvxTypeError, "src"),
    (None, 0, {}, WarpvxValueError, "levels"),
    (None, 2.0, {}, WarpvxTypeError, "levels"),
    (None, True, {}, WarpvxTypeError, "levels"),
    (None, 7, {}, WarpvxValueError, "levels"),  # 30x20 -> 15x10 -> 8x5 -> 4x3 -> 2x2 -> 1x1
    (None, 3, {"out": None}, None, None),
    (None, 3, {"out": "x"}, WarpvxTypeError, "out"),
    (None, 3, {"out": [None, np.zeros((10, 15), np.uint8)]}, ShapeError, "out"),
    (None, 2, {"out": [np.zeros((20, 30), np.uint8), np.zeros((10, 15), np.uint8)]}, WarpvxValueError, r"out\[0\]"),
    (None, 2, {"out": ["src", np.zeros((10, 13), np.uint8)]}, ShapeError, r"out\[1\]"),
    (None, 2, {"out": ["src", np.zeros((10, 15), np.int16)]}, DTypeError, r"out\[1\]"),
    (None, 2, {"out": ["src", np.zeros((10, 15, 3), np.uint8)]}, ShapeError, r"out\[1\]"),
    (None, 2, {"backend": "gpu"}, BackendError, "backend"),
])
def test_bad_input(src, levels, kwargs, exc, name):
    src = _img() if src is None else src
    if "out" in kwargs and isinstance(kwargs["out"], list):
        kwargs = {"out": [src if isinstance(o, str) and o == "src" else o for o in kwargs["out"]]}
    if exc is None:
        assert len(warpvx.gaussian_pyramid(src, levels, **kwargs)) == levels
        return
    with pytest.raises(exc, match=name):
        warpvx.gaussian_pyramid(src, levels, **kwargs)


def test_most_levels_allowed():
    src = _img()
    assert warpvx.gaussian_pyramid(src, 6)[-1].shape == (1, 1)


# --- OpenCV parity on real photos -----------------------------------------------------------


@pytest.mark.parametrize("name,h,w,colour", [("camera", 301, 457, False), ("chelsea", 300, 451, True),
                                             ("rocket", 427, 640, False)])
def test_opencv_parity(backend, name, h, w, colour):
    src = crop(bgr(name) if colour else gray(name), h, w)
    pyr = warpvx.gaussian_pyramid(src, 5, backend=backend)
    for out, ref in zip(pyr[1:], cv_pyramid(src, 5)[1:]):
        assert_parity(out, ref)


def test_out_is_written(backend):
    src = crop(bgr("coffee"), 101, 149)
    out = [src] + [np.zeros((h, w, 3), np.uint8) for w, h in [(75, 51), (38, 26), (19, 13)]]
    pyr = warpvx.gaussian_pyramid(src, 4, out=out, backend=backend)
    for got, buf, ref in zip(pyr[1:], out[1:], cv_pyramid(src, 4)[1:]):
        assert got is buf
        assert np.array_equal(buf, ref)


def test_out_level0_none_is_the_input(backend):
    """A graph's pooled buffers leave level 0 None (it is the input): same levels as OpenCV."""
    src = crop(gray("camera"), 101, 149)
    out = [None] + [np.zeros((h, w), np.uint8) for w, h in [(75, 51), (38, 26)]]
    pyr = warpvx.gaussian_pyramid(src, 3, out=out, backend=backend)
    assert pyr[0] is src or np.array_equal(pyr[0], src)
    for got, buf, ref in zip(pyr[1:], out[1:], cv_pyramid(src, 3)[1:]):
        assert got is buf and np.array_equal(buf, ref)


@pytest.mark.parametrize("sizes", [[(229, 151)], [(227, 149), (114, 75)], [(229, 149), (114, 74)]])
def test_out_sizes_follow_pyrdown_dstsize(backend, sizes):
    """Any size cv2.pyrDown's dstsize allows, including OpenCV's w/2 + 1 edge stepping."""
    src = crop(gray("camera"), 300, 456)
    out = [src] + [np.zeros((h, w), np.uint8) for w, h in sizes]
    pyr = warpvx.gaussian_pyramid(src, len(out), out=out, backend=backend)
    prev = src
    for lvl, (w, h) in enumerate(sizes, start=1):
        ref = cv2.pyrDown(prev, dstsize=(w, h))
        assert np.array_equal(pyr[lvl], ref), lvl
        prev = ref


def test_warp_array_in_warp_array_out(warp_backend):
    import warp as wp

    src = crop(gray("camera"), 65, 97)
    a = on_device(src, warp_backend)
    pyr = warpvx.gaussian_pyramid(a, 3)
    assert pyr[0] is a
    for got, ref in zip(pyr[1:], cv_pyramid(src, 3)[1:]):
        assert isinstance(got, wp.array) and str(got.device) == str(a.device)
        assert np.array_equal(got.numpy(), ref)


def test_warp_kernel_module_direct(warp_backend):
    """The signature the LK extractor calls: kernels_warp.gaussian_pyramid(src, levels)."""
    import warp as wp

    from warpvx.kernels_warp.gaussian_pyramid import gaussian_pyramid

    src = crop(gray("brick"), 77, 93)
    dev = warpvx.backend.resolve_backend(warp_backend).device
    with wp.ScopedDevice(dev):
        a = wp.array(src, dtype=wp.uint8, device=dev)
        pyr = gaussian_pyramid(a, 4)
    assert pyr[0] is a
    for got, ref in zip(pyr[1:], cv_pyramid(src, 4)[1:]):
        assert np.array_equal(got.numpy(), ref)


# --- the cv2 drop-ins -----------------------------------------------------------------------


def test_cv_pyrdown(backend):
    src = crop(bgr("chelsea"), 300, 451)
    assert np.array_equal(wcv.pyrDown(src, backend=backend), cv2.pyrDown(src))
    assert np.array_equal(wcv.pyrDown(src, dstsize=(226, 151), backend=backend),
                          cv2.pyrDown(src, dstsize=(226, 151)))
    dst = np.empty((150, 226, 3), np.uint8)
    assert wcv.pyrDown(src, dst, backend=backend) is dst
    assert np.array_equal(dst, cv2.pyrDown(src))
    one = np.full((1, 1), 7, np.uint8)
    assert np.array_equal(wcv.pyrDown(one, backend=backend), cv2.pyrDown(one))


def test_cv_build_pyramid(backend):
    src = crop(gray("camera"), 5, 9)
    pyr = wcv.buildPyramid(src, 5, backend=backend)
    assert len(pyr) == 6
    ref = cv_pyramid(src, 6)
    for got, want in zip(pyr, ref):
        assert np.array_equal(got, want)


def test_cv_pyrdown_bad_input():
    src = _img()
    with runs_on_cv2("borderType"):
        wcv.pyrDown(src, borderType=wcv.BORDER_REPLICATE)
    with pytest.raises(WarpvxValueError, match="dstsize"):
        wcv.pyrDown(src, dstsize=(18, 10))
    with pytest.raises(WarpvxValueError, match="maxlevel"):
        wcv.buildPyramid(src, -1)


def test_reused_levels_follow_new_frames(warp_backend):
    """Regression: caller-owned levels replay recorded launches; each new frame in the same
    buffer must give that frame's pyramid."""
    import warp as wp

    dev = warpvx.backend.resolve_backend(warp_backend).device
    src = wp.empty((66, 97, 3), dtype=wp.uint8, device=dev)
    out = [src] + [wp.empty((h, w, 3), dtype=wp.uint8, device=dev) for w, h in [(49, 33), (25, 17)]]
    for name in ("chelsea", "coffee", "chelsea"):
        frame = crop(bgr(name), 66, 97)
        src.assign(frame)
        warpvx.gaussian_pyramid(src, 3, out=out)
        for got, want in zip(out[1:], cv_pyramid(frame, 3)[1:]):
            assert np.array_equal(got.numpy(), want), name
