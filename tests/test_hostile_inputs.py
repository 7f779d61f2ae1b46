"""Hostile inputs to public functions (issue 10, items 6, 9, 12, 13, 15): each must end in a
warpvx error naming the argument, or a defined result, on every backend."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.isolated import run_isolated
from tests.parity import on_device
from warpvx.backend import init_warp


# --- item 6: output-size guard on resize --------------------------------------------------------


@pytest.mark.parametrize("kwargs, name", [
    ({"fx": 1e5, "fy": 1e5}, "fx, fy"),
    ({"fx": 1e300, "fy": 1.0}, "fx"),
    ({"dsize": (2**31, 1)}, r"dsize\[0\]"),
    ({"dsize": (30000, 30000)}, "dsize"),
])
def test_resize_output_size_guard_regression(backend, kwargs, name):
    """Refused before anything is allocated (it used to raise cv2.error / Warp errors, or
    allocate gigabytes)."""
    run_isolated(f"""
        import numpy as np, re, warpvx
        try:
            warpvx.resize(np.zeros((8, 8), np.uint8), backend="{backend}", **{kwargs!r})
        except warpvx.WarpvxValueError as e:
            assert re.match({name!r}, str(e)), e
        else:
            raise SystemExit("not refused")
    """, timeout=60)


def test_output_size_limit_still_allows_large_outputs(backend):
    out = warpvx.resize(gray("camera"), (4096, 16), backend=backend)
    np.testing.assert_array_equal(np.asarray(out), cv2.resize(gray("camera"), (4096, 16)))


# --- item 9: out overlapping an input ----------------------------------------------------------


def test_gaussian_blur_out_overlapping_src_refused_regression(backend):
    big = gray("camera")[:64].copy()
    before = big.copy()
    with pytest.raises(warpvx.WarpvxValueError, match="out: .*overlaps src"):
        warpvx.gaussian_blur(big[:-1], 3, 1.0, out=big[1:], backend=backend)
    np.testing.assert_array_equal(big, before)  # refused before anything was written


def test_gaussian_blur_in_place_still_allowed(backend):
    img = on_device(gray("camera"), backend)
    ref = cv2.GaussianBlur(gray("camera"), (5, 5), 1.2)
    out = warpvx.gaussian_blur(img, 5, 1.2, out=img, backend=backend)
    np.testing.assert_array_equal(np.asarray(out if isinstance(out, np.ndarray) else out.numpy()), ref)


def test_out_overlapping_device_view_refused(warp_backend):
    wp = init_warp()
    big = wp.array(gray("camera")[:64], device=warp_backend.replace("warp-", ""))
    with pytest.raises(warpvx.WarpvxValueError, match="out: .*overlaps src"):
        warpvx.gaussian_blur(big[:-1], 3, 1.0, out=big[1:], backend=warp_backend)


def test_remap_out_aliasing_an_input_refused(backend):
    src = gray("camera")[:32, :32].copy()
    mx, my = np.meshgrid(np.arange(32, dtype=np.float32), np.arange(32, dtype=np.float32))
    with pytest.raises(warpvx.WarpvxValueError, match="out: .*is src"):
        warpvx.remap(src, mx, my, out=src, backend=backend)
    with pytest.raises(warpvx.WarpvxValueError, match="out: .*map_x"):
        warpvx.remap(src, mx, my, out=mx.view(np.uint8).ravel()[:32 * 32].reshape(32, 32),
                     backend=backend)


def test_warp_perspective_out_overlapping_src_refused(backend):
    buf = gray("camera")[:65].copy()
    with pytest.raises(warpvx.WarpvxValueError, match="out: .*overlaps src"):
        warpvx.warp_perspective(buf[:64], np.eye(3), (512, 64), out=buf[1:], backend=backend)


# --- item 12: a read-only out= --------------------------------------------------------------------


def _read_only(shape):
    a = np.zeros(shape, np.uint8)
    a.flags.writeable = False
    return a


@pytest.mark.parametrize("call", [
    lambda src, out, be: warpvx.gaussian_blur(src, 3, 1.0, out=out, backend=be),
    lambda src, out, be: warpvx.warp_perspective(src, np.eye(3), (451, 300), out=out, backend=be),
    lambda src, out, be: warpvx.resize(src, (451, 300), out=out, backend=be),
], ids=["gaussian_blur", "warp_perspective", "resize"])
def test_read_only_out_refused_regression(backend, call):
    src = gray("chelsea")
    with pytest.raises(warpvx.WarpvxValueError, match="out: expected a writable array"):
        call(src, _read_only(src.shape), backend)


def test_read_only_out_refused_by_dispatch(backend):
    """Primitives validated elsewhere are refused up front by the dispatcher."""
    src = bgr("chelsea")
    with pytest.raises(warpvx.WarpvxValueError, match="out: expected a writable array"):
        warpvx.color_convert(src, "bgr2gray", out=_read_only(src.shape[:2]), backend=backend)


# --- item 13: a tiny sigma --------------------------------------------------------------------------


@pytest.mark.parametrize("sigma", [1e-300, 1e-160, (1e-300, 1.5), 1e-3])
@pytest.mark.parametrize("ksize", [3, 7, 31])
def test_gaussian_blur_tiny_sigma_regression(backend, sigma, ksize):
    """OpenCV's kernel is the identity for a tiny sigma (warp-cpu raised ZeroDivisionError)."""
    src = gray("camera")
    sx, sy = sigma if isinstance(sigma, tuple) else (sigma, 0)
    ref = cv2.GaussianBlur(src, (ksize, ksize), sx, sigmaY=sy)
    out = warpvx.gaussian_blur(on_device(src, backend), ksize, sigma, backend=backend)
    np.testing.assert_array_equal(out if isinstance(out, np.ndarray) else out.numpy(), ref)


# --- item 15: exotic array inputs ---------------------------------------------------------------------


class _ArrayRaises:
    def __array__(self, *args, **kwargs):
        raise RuntimeError("no array for you")


class _DLPackRaises:
    def __dlpack__(self, *args, **kwargs):
        raise BufferError("no dlpack for you")

    def __dlpack_device__(self):
        return (1, 0)


@pytest.mark.parametrize("make, err", [
    (lambda: np.matrix(gray("camera")), warpvx.WarpvxTypeError),
    (_ArrayRaises, warpvx.WarpvxTypeError),
    (_DLPackRaises, warpvx.WarpvxTypeError),
    (lambda: init_warp().zeros((8, 8), dtype=init_warp().vec3, device="cpu"), warpvx.DTypeError),
    (lambda: init_warp().zeros((8, 8), dtype=init_warp().mat22, device="cpu"), warpvx.DTypeError),
], ids=["np.matrix", "__array__raises", "__dlpack__raises", "wp.vec3", "wp.mat22"])
def test_exotic_arrays_refused_by_name_regression(backend, make, err):
    x = make()
    with pytest.raises(err, match="^src: "):
        warpvx.gaussian_blur(x, 3, 1.0, backend=backend)
    with pytest.raises(err, match="^map_x: "):
        warpvx.remap(gray("camera"), x, np.zeros((8, 8), np.float32), backend=backend)
