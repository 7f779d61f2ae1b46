"""warpvx.scale_pyramid (ORB-SLAM2's) and warpvx.pyramid.resize against cv2.resize INTER_LINEAR
(SPEC §4 bar: each pixel within 1; achieved: bit-exact, OpenCV's 11-bit fixed point
reproduced), and the resize drop-in."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.parity import assert_images_match as assert_parity, crop, on_device
from warpvx import cv as wcv
from warpvx.errors import DTypeError, ShapeError, UnsupportedError, WarpvxTypeError, WarpvxValueError
from warpvx.pyramid import resize, scale_pyramid_sizes
from tests.cv.fallback import runs_on_cv2

# ORB-SLAM2 on KITTI (1241x376, scale 1.2, 8 levels): cvRound(w / 1.2^l), computed by hand.
KITTI_SIZES = [(1241, 376), (1034, 313), (862, 261), (718, 218), (598, 181), (499, 151), (416, 126),
               (346, 105)]






def cv_scale_pyramid(src, sizes):
    out = [src]
    for size in sizes[1:]:
        out.append(cv2.resize(out[-1], size, interpolation=cv2.INTER_LINEAR))
    return out


# --- smoke ----------------------------------------------------------------------------------


def test_smoke(backend):
    src = crop(gray("camera"), 120, 160)
    pyr = warpvx.scale_pyramid(src, 3, backend=backend)
    assert [p.shape for p in pyr] == [(120, 160), (100, 133), (83, 111)]
    assert pyr[0] is src and all(p.dtype == np.uint8 for p in pyr)


def test_kitti_level_sizes():
    assert scale_pyramid_sizes(1241, 376, 8, 1.2) == KITTI_SIZES
    src = np.zeros((376, 1241), np.uint8)
    pyr = warpvx.scale_pyramid(src, 8, 1.2, backend="cpu")
    assert [(p.shape[1], p.shape[0]) for p in pyr] == KITTI_SIZES


# --- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("shape,levels,factor", [((1, 1), 1, 1.2), ((7, 9), 3, 1.2), ((31, 17, 3), 4, 1.5),
                                                 ((16, 15, 4), 3, 2.0), ((33, 40, 1), 5, 1.2),
                                                 ((2, 50), 3, 1.1)])
def test_shapes(backend, shape, levels, factor):
    rng = np.random.default_rng(sum(shape))
    src = rng.integers(0, 256, shape, dtype=np.uint8)
    plain = src[..., 0] if len(shape) == 3 and shape[2] == 1 else src
    pyr = warpvx.scale_pyramid(src, levels, factor, backend=backend)
    sizes = scale_pyramid_sizes(shape[1], shape[0], levels, factor)
    ref = cv_scale_pyramid(plain, sizes)
    assert len(pyr) == levels
    for got, want in zip(pyr[1:], ref[1:]):
        assert_parity(got, want)


# --- bad input ------------------------------------------------------------------------------


def _img():
    return crop(gray("camera"), 20, 30)


@pytest.mark.parametrize("src,levels,factor,kwargs,exc,name", [
    (np.zeros((8, 8), np.int8), 2, 1.2, {}, DTypeError, "src"),
    (np.zeros((8, 8, 5), np.uint8), 2, 1.2, {}, ShapeError, "src"),
    (np.zeros((0, 8), np.uint8), 2, 1.2, {}, ShapeError, "src"),
    (None, 0, 1.2, {}, WarpvxValueError, "levels"),
    (None, "8", 1.2, {}, WarpvxTypeError, "levels"),
    (None, 40, 1.2, {}, WarpvxValueError, "levels"),  # a 30x20 image has no 40 levels at 1.2
    (None, 3, 1.0, {}, WarpvxValueError, "scale_factor"),
    (None, 3, 0.8, {}, WarpvxValueError, "scale_factor"),
    (None, 3, float("inf"), {}, WarpvxValueError, "scale_factor"),
    (None, 3, "1.2", {}, WarpvxTypeError, "scale_factor"),
    (None, 2, 1.2, {"out": [None]}, ShapeError, "out"),
    (None, 2, 1.2, {"out": ["src", np.zeros((16, 25), np.uint8)]}, ShapeError, r"out\[1\]"),
    (None, 2, 1.2, {"out": ["src", np.zeros((17, 25), np.float32)]}, DTypeError, r"out\[1\]"),
    (None, 2, 1.2, {"out": [np.zeros((20, 30), np.uint8), np.zeros((17, 25), np.uint8)]}, WarpvxValueError,
     r"out\[0\]"),
])
def test_bad_input(src, levels, factor, kwargs, exc, name):
    src = _img() if src is None else src
    if "out" in kwargs:
        kwargs = {"out": [src if isinstance(o, str) else o for o in kwargs["out"]]}
    with pytest.raises(exc, match=name):
        warpvx.scale_pyramid(src, levels, factor, **kwargs)


@pytest.mark.parametrize("args,kwargs,exc,name", [
    (((0, 5),), {}, WarpvxValueError, r"dsize\[0\]"),
    (((10, -1),), {}, WarpvxValueError, r"dsize\[1\]"),
    (((10.0, 5),), {}, WarpvxTypeError, r"dsize\[0\]"),
    (("10x5",), {}, WarpvxTypeError, "dsize"),
    ((None,), {}, WarpvxValueError, "fx"),
    ((None, 0.5, -1.0), {}, WarpvxValueError, "fy"),
    ((None, 0.01, 0.5), {}, WarpvxValueError, "fx"),  # rounds to an empty image
    (((10, 5),), {"out": np.zeros((10, 5), np.uint8)}, ShapeError, "out"),
])
def test_resize_bad_input(args, kwargs, exc, name):
    with pytest.raises(exc, match=name):
        resize(_img(), *args, **kwargs)


# --- OpenCV parity on real photos -----------------------------------------------------------


@pytest.mark.parametrize("name,h,w,colour", [("camera", 301, 457, False), ("chelsea", 300, 451, True),
                                             ("motorcycle", 376, 621, False)])
def test_opencv_parity(backend, name, h, w, colour):
    src = crop(bgr(name) if colour else gray(name), h, w)
    pyr = warpvx.scale_pyramid(src, 8, 1.2, backend=backend)
    sizes = scale_pyramid_sizes(w, h, 8, 1.2)
    assert [(p.shape[1], p.shape[0]) for p in pyr] == sizes
    for got, want in zip(pyr[1:], cv_scale_pyramid(src, sizes)[1:]):
        assert_parity(got, want)


@pytest.mark.parametrize("dsize,fx,fy", [
    ((100, 70), 0, 0), ((640, 427), 0, 0), ((1000, 20), 0, 0), ((3, 500), 0, 0),
    (None, 0.37, 1.7), (None, 0.5, 0.5), (None, 2.0, 3.0), (None, 1 / 3, 1 / 3), ((451, 300), 0, 0),
])
@pytest.mark.parametrize("colour", [False, True])
def test_resize_opencv_parity(backend, dsize, fx, fy, colour):
    """Down and up, odd sizes; fx = fy = 0.5 on an odd image takes OpenCV's INTER_AREA edge."""
    src = crop(bgr("chelsea") if colour else gray("chelsea"), 299, 451)
    out = resize(src, dsize, fx, fy, backend=backend)
    assert_parity(out, cv2.resize(src, dsize, fx=fx, fy=fy, interpolation=cv2.INTER_LINEAR))


def test_out_is_written(backend):
    src = crop(gray("coffee"), 200, 300)
    sizes = scale_pyramid_sizes(300, 200, 4, 1.2)
    out = [src] + [np.zeros((h, w), np.uint8) for w, h in sizes[1:]]
    pyr = warpvx.scale_pyramid(src, 4, 1.2, out=out, backend=backend)
    for got, buf, want in zip(pyr[1:], out[1:], cv_scale_pyramid(src, sizes)[1:]):
        assert got is buf
        assert np.array_equal(buf, want)


def test_warp_array_in_warp_array_out(warp_backend):
    import warp as wp

    src = crop(bgr("coffee"), 81, 121)
    a = on_device(src, warp_backend)
    pyr = warpvx.scale_pyramid(a, 3, 1.2)
    assert pyr[0] is a
    ref = cv_scale_pyramid(src, scale_pyramid_sizes(121, 81, 3, 1.2))
    for got, want in zip(pyr[1:], ref[1:]):
        assert isinstance(got, wp.array) and str(got.device) == str(a.device)
        assert np.array_equal(got.numpy(), want)
    r = resize(a, (50, 40))
    assert isinstance(r, wp.array) and np.array_equal(r.numpy(), cv2.resize(src, (50, 40)))


def test_warp_kernel_module_direct(warp_backend):
    """The signature the ORB extractor calls: kernels_warp.scale_pyramid(src, levels, factor)."""
    import warp as wp

    from warpvx.kernels_warp.scale_pyramid import scale_pyramid

    src = crop(gray("rocket"), 188, 621)
    dev = warpvx.backend.resolve_backend(warp_backend).device
    with wp.ScopedDevice(dev):
        pyr = scale_pyramid(wp.array(src, dtype=wp.uint8, device=dev), 4, 1.2)
    ref = cv_scale_pyramid(src, scale_pyramid_sizes(621, 188, 4, 1.2))
    for got, want in zip(pyr[1:], ref[1:]):
        assert np.array_equal(got.numpy(), want)


# --- the cv2 drop-in ------------------------------------------------------------------------


def test_cv_resize(backend):
    src = crop(bgr("rocket"), 427, 639)
    assert np.array_equal(wcv.resize(src, (320, 213), backend=backend), cv2.resize(src, (320, 213)))
    assert np.array_equal(wcv.resize(src, None, fx=0.75, fy=0.6, backend=backend),
                          cv2.resize(src, None, fx=0.75, fy=0.6))
    assert np.array_equal(wcv.resize(src, (0, 0), fx=0.5, fy=0.5, backend=backend),
                          cv2.resize(src, (0, 0), fx=0.5, fy=0.5))
    dst = np.empty((100, 200, 3), np.uint8)
    assert wcv.resize(src, (200, 100), dst, backend=backend) is dst
    assert np.array_equal(dst, cv2.resize(src, (200, 100)))


def test_cv_resize_bad_input():
    with runs_on_cv2("interpolation"):
        wcv.resize(_img(), (10, 10), interpolation=wcv.INTER_AREA)
    with runs_on_cv2("interpolation"):
        wcv.resize(_img(), (10, 10), interpolation=wcv.INTER_NEAREST)


def test_reused_levels_follow_new_frames(warp_backend):
    """Regression: caller-owned levels replay recorded launches; each new frame in the same
    buffer must give that frame's pyramid."""
    import warp as wp

    dev = warpvx.backend.resolve_backend(warp_backend).device
    sizes = scale_pyramid_sizes(97, 66, 4, 1.2)
    src = wp.empty((66, 97), dtype=wp.uint8, device=dev)
    out = [src] + [wp.empty((h, w), dtype=wp.uint8, device=dev) for w, h in sizes[1:]]
    for name in ("camera", "coffee", "camera"):
        frame = crop(gray(name), 66, 97)
        src.assign(frame)
        warpvx.scale_pyramid(src, 4, 1.2, out=out)
        for got, want in zip(out[1:], cv_scale_pyramid(frame, sizes)[1:]):
            assert np.array_equal(got.numpy(), want), name
