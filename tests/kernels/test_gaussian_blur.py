"""warpvx.gaussian_blur against cv2.GaussianBlur (SPEC §4 bar: each pixel within 1; achieved:
bit-exact, OpenCV's 8-bit path being integer fixed point)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from tests.parity import assert_images_match as assert_parity, crop, on_device
from warpvx import cv as wcv
from warpvx.errors import (
    BackendError,
    DTypeError,
    ShapeError,
    UnsupportedError,
    WarpvxTypeError,
    WarpvxValueError,
)
from tests.cv.fallback import runs_on_cv2

CV_BORDERS = {"reflect101": cv2.BORDER_REFLECT_101, "reflect": cv2.BORDER_REFLECT,
              "replicate": cv2.BORDER_REPLICATE, "constant": cv2.BORDER_CONSTANT}






# --- smoke ----------------------------------------------------------------------------------


def test_smoke(backend):
    src = crop(gray("camera"), 48, 64)
    out = warpvx.gaussian_blur(src, 5, 1.0, backend=backend)
    assert isinstance(out, np.ndarray)
    assert out.shape == (48, 64) and out.dtype == np.uint8


# --- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("shape", [(1, 1), (1, 9), (7, 1), (5, 7), (31, 17), (17, 31, 3), (16, 15, 4),
                                   (9, 8, 1)])
def test_shapes(backend, shape):
    rng = np.random.default_rng(sum(shape))
    src = rng.integers(0, 256, shape, dtype=np.uint8)
    out = warpvx.gaussian_blur(src, 7, 1.5, backend=backend)
    plain = src[..., 0] if shape[-1] == 1 and len(shape) == 3 else src
    assert out.shape == plain.shape
    # kernels larger than the image reflect more than once
    assert_parity(out, cv2.GaussianBlur(plain, (7, 7), 1.5, borderType=cv2.BORDER_REFLECT_101))


# --- bad input ------------------------------------------------------------------------------


def _img():
    return crop(gray("camera"), 20, 30)


@pytest.mark.parametrize("args,kwargs,exc,name", [
    ((np.zeros((8, 8), np.float32), 3, 1.0), {}, DTypeError, "src"),
    ((np.zeros((8, 8, 2), np.uint8), 3, 1.0), {}, ShapeError, "src"),
    ((np.zeros((2, 8, 8, 3), np.uint8), 3, 1.0), {}, ShapeError, "src"),
    ((np.zeros((0, 8), np.uint8), 3, 1.0), {}, ShapeError, "src"),
    ((np.zeros((8, 16), np.uint8)[:, ::2], 3, 1.0), {}, WarpvxValueError, "src"),
    (([[1, 2], [3, 4]], 3, 1.0), {}, WarpvxTypeError, "src"),
    (("image", 3, 1.0), {}, WarpvxTypeError, "src"),
    ((None, 4, 1.0), {}, UnsupportedError, "ksize"),
    ((None, 0, 1.0), {}, WarpvxValueError, "ksize"),
    ((None, 33, 1.0), {}, WarpvxValueError, "ksize"),
    ((None, 3.0, 1.0), {}, WarpvxTypeError, "ksize"),
    ((None, (3, 4), 1.0), {}, UnsupportedError, r"ksize\[1\]"),
    ((None, (3, 3, 3), 1.0), {}, WarpvxTypeError, "ksize"),
    ((None, 3, -1.0), {}, WarpvxValueError, "sigma"),
    ((None, 3, float("nan")), {}, WarpvxValueError, "sigma"),
    ((None, 3, "1"), {}, WarpvxTypeError, "sigma"),
    ((None, 3, (1.0, -2.0)), {}, WarpvxValueError, r"sigma\[1\]"),
    ((None, 3, 1.0), {"border": "wrap"}, UnsupportedError, "border"),
    ((None, 3, 1.0), {"border": 3}, UnsupportedError, "border"),
    ((None, 3, 1.0), {"border": None}, UnsupportedError, "border"),
    ((None, 3, 1.0), {"out": np.zeros((20, 31), np.uint8)}, ShapeError, "out"),
    ((None, 3, 1.0), {"out": np.zeros((20, 30), np.int16)}, DTypeError, "out"),
    ((None, 3, 1.0), {"backend": "tpu"}, BackendError, "backend"),
])
def test_bad_input(args, kwargs, exc, name):
    args = (_img(),) + args[1:] if args[0] is None else args
    with pytest.raises(exc, match=name):
        warpvx.gaussian_blur(*args, **kwargs)


def test_bad_input_is_a_value_or_type_error():
    with pytest.raises(ValueError):
        warpvx.gaussian_blur(_img(), 4, 1.0)
    with pytest.raises(TypeError):
        warpvx.gaussian_blur(np.zeros((4, 4), np.float64), 3, 1.0)


# --- OpenCV parity on real photos -----------------------------------------------------------


@pytest.mark.parametrize("name,h,w", [("camera", 301, 457), ("chelsea", 300, 451)])
@pytest.mark.parametrize("ksize,sigma", [(3, 0.0), (5, 1.0), (7, 2.0), (9, 0.0), (11, 1.7), (15, 3.3)])
def test_opencv_parity(backend, name, h, w, ksize, sigma):
    src = crop(gray(name) if name == "camera" else bgr(name), h, w)
    out = warpvx.gaussian_blur(src, ksize, sigma, backend=backend)
    assert_parity(out, cv2.GaussianBlur(src, (ksize, ksize), sigma, borderType=cv2.BORDER_REFLECT_101))


@pytest.mark.parametrize("border", list(CV_BORDERS))
@pytest.mark.parametrize("ksize,sigma", [(17, 0.0), (31, 6.0)])
def test_large_kernels_take_the_two_pass_path(backend, border, ksize, sigma):
    """Radii over the fused kernel's limit (7) run as a row pass plus a column pass."""
    src = crop(bgr("rocket"), 120, 163)
    out = warpvx.gaussian_blur(src, ksize, sigma, border, backend=backend)
    assert_parity(out, cv2.GaussianBlur(src, (ksize, ksize), sigma, borderType=CV_BORDERS[border]))


def test_orb_descriptor_blur_regression(backend):
    """ORB-SLAM2 blurs each level 7x7, sigma 2, REFLECT_101 before its descriptors."""
    src = crop(gray("rocket"), 427, 639)
    out = warpvx.gaussian_blur(src, 7, 2.0, "reflect101", backend=backend)
    ref = cv2.GaussianBlur(src, (7, 7), 2, borderType=cv2.BORDER_REFLECT_101)
    assert np.array_equal(out, ref)


@pytest.mark.parametrize("border", list(CV_BORDERS))
def test_borders(backend, border):
    src = crop(bgr("coffee"), 61, 83)
    out = warpvx.gaussian_blur(src, 9, 2.5, border, backend=backend)
    assert_parity(out, cv2.GaussianBlur(src, (9, 9), 2.5, borderType=CV_BORDERS[border]))
    # cv2's integer codes are accepted too
    out2 = warpvx.gaussian_blur(src, 9, 2.5, CV_BORDERS[border], backend=backend)
    assert np.array_equal(out, out2)


def test_separate_x_and_y(backend):
    src = crop(gray("brick"), 97, 131)
    out = warpvx.gaussian_blur(src, (7, 3), (1.2, 2.5), backend=backend)
    ref = cv2.GaussianBlur(src, (7, 3), 1.2, sigmaY=2.5, borderType=cv2.BORDER_REFLECT_101)
    assert_parity(out, ref)


def test_four_channels(backend):
    img = crop(bgr("astronaut"), 77, 91)
    src = np.ascontiguousarray(np.concatenate([img, crop(gray("astronaut"), 77, 91)[..., None]], 2))
    out = warpvx.gaussian_blur(src, 5, 1.3, backend=backend)
    assert_parity(out, cv2.GaussianBlur(src, (5, 5), 1.3))


# --- out=, in place, kinds ------------------------------------------------------------------


def test_out_is_written(backend):
    src = crop(gray("camera"), 40, 57)
    out = np.zeros_like(src)
    res = warpvx.gaussian_blur(src, 5, 1.0, out=out, backend=backend)
    assert res is out
    assert np.array_equal(out, cv2.GaussianBlur(src, (5, 5), 1.0))


def test_in_place(backend):
    src = crop(gray("camera"), 40, 57)
    ref = cv2.GaussianBlur(src, (5, 5), 1.0)
    work = src.copy()
    warpvx.gaussian_blur(work, 5, 1.0, out=work, backend=backend)
    assert np.array_equal(work, ref)


def test_warp_array_in_warp_array_out(warp_backend):
    import warp as wp

    src = crop(bgr("chelsea"), 50, 63)
    a = on_device(src, warp_backend)
    out = warpvx.gaussian_blur(a, 5, 1.0)
    assert isinstance(out, wp.array) and str(out.device) == str(a.device)
    assert np.array_equal(out.numpy(), cv2.GaussianBlur(src, (5, 5), 1.0))
    # in place on the device as well
    warpvx.gaussian_blur(a, 5, 1.0, out=a)
    assert np.array_equal(a.numpy(), cv2.GaussianBlur(src, (5, 5), 1.0))


# --- the cv2 drop-in ------------------------------------------------------------------------


def test_cv_gaussian_blur(backend):
    src = crop(bgr("chelsea"), 120, 151)
    cases = [
        (((0, 0), 1.7), {}),
        (((5, 3), 1.1), {"sigmaY": 2.3, "borderType": wcv.BORDER_REFLECT}),
        (((3, 3), 0), {"borderType": wcv.BORDER_CONSTANT}),
        (((7, 7), -1.0), {"borderType": wcv.BORDER_REPLICATE | wcv.BORDER_ISOLATED}),
    ]
    for args, kwargs in cases:
        ref = cv2.GaussianBlur(src, *args, **kwargs)
        assert np.array_equal(wcv.GaussianBlur(src, *args, backend=backend, **kwargs), ref), (args, kwargs)
    dst = np.empty_like(src)
    assert wcv.GaussianBlur(src, (5, 5), 1.0, dst, backend=backend) is dst


def test_cv_gaussian_blur_bad_input():
    src = _img()
    with runs_on_cv2("borderType"):
        wcv.GaussianBlur(src, (3, 3), 1.0, borderType=wcv.BORDER_WRAP)
    with pytest.raises(WarpvxValueError, match="ksize"):
        wcv.GaussianBlur(src, (0, 0), 0)
    with pytest.raises(WarpvxTypeError, match="sigmaX"):
        wcv.GaussianBlur(src, (3, 3), "1")


def test_reused_buffers_follow_new_contents_and_arguments(warp_backend):
    """Regression: with caller-owned buffers the Warp path replays recorded launches; new
    pixels in the same buffer and new kernel arguments must still be honoured."""
    import warp as wp

    dev = warpvx.backend.resolve_backend(warp_backend).device
    frames = [crop(gray("camera"), 60, 71), crop(gray("coffee"), 60, 71)]
    src = wp.empty((60, 71), dtype=wp.uint8, device=dev)
    out = wp.empty((60, 71), dtype=wp.uint8, device=dev)
    for frame in frames:
        src.assign(frame)
        for k, s, border in ((5, 1.0, "reflect101"), (7, 2.0, "reflect101"), (5, 1.0, "constant")):
            warpvx.gaussian_blur(src, k, s, border, out=out)
            ref = cv2.GaussianBlur(frame, (k, k), s, borderType=CV_BORDERS[border])
            assert np.array_equal(out.numpy(), ref), (k, s, border)
