"""warpvx.cv drop-ins (cvtColor, remap, warpPerspective): same results, shapes, dtypes and
constants as cv2 for the supported subset; UnsupportedError outside it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

import warpvx
from tests.images import bgr, gray
from warpvx import cv as wcv
from warpvx.bench.inputs import mild_homography, undistort_maps
from tests.cv.fallback import runs_on_cv2


def assert_close(out, ref):
    """Values at the SPEC bar and then some: within 1 everywhere, equal on 99.9%+ (OpenCV's
    own SIMD tail columns round a few coordinates differently)."""
    diff = np.abs(out.astype(np.int16) - ref.astype(np.int16))
    assert diff.max() <= 1 and (diff == 0).mean() >= 0.999, (diff.max(), (diff == 0).mean())


def test_constants_match_cv2():
    for name in wcv.imgproc.__all__:
        value = getattr(wcv, name)
        if callable(value):
            assert hasattr(cv2, name), name
            continue
        assert value == getattr(cv2, name), name


def test_all_lists_the_subset():
    for name in ("cvtColor", "remap", "warpPerspective", "COLOR_BGR2GRAY", "COLOR_YUV2BGR_NV12",
                 "INTER_LINEAR", "INTER_NEAREST", "WARP_INVERSE_MAP", "BORDER_CONSTANT",
                 "BORDER_REPLICATE", "BORDER_REFLECT_101", "BORDER_DEFAULT"):
        assert name in wcv.imgproc.__all__
        assert hasattr(wcv, name)


# --- cvtColor -------------------------------------------------------------------------------


@pytest.mark.parametrize("code", ["COLOR_BGR2GRAY", "COLOR_RGB2GRAY", "COLOR_BGR2RGB", "COLOR_BGR2BGRA",
                                  "COLOR_GRAY2BGR", "COLOR_YUV2BGR_NV12", "COLOR_YUV2RGB_NV12"])
def test_cvtcolor_like_cv2(backend, code):
    from warpvx.bench.inputs import bgr_to_nv12

    src = {"COLOR_GRAY2BGR": gray("chelsea")}.get(code, bgr("chelsea"))
    if "NV12" in code:
        src = bgr_to_nv12(bgr("chelsea"))
    ref = cv2.cvtColor(src, getattr(cv2, code))
    out = wcv.cvtColor(src, getattr(wcv, code), backend=backend)
    assert type(out) is type(ref) and out.shape == ref.shape and out.dtype == ref.dtype
    assert_close(out, ref)


def test_cvtcolor_dst(backend):
    src = bgr("rocket")
    dst = np.zeros((427, 640), np.uint8)
    res = wcv.cvtColor(src, wcv.COLOR_BGR2GRAY, dst, backend=backend)
    assert res is dst
    assert_close(dst, cv2.cvtColor(src, cv2.COLOR_BGR2GRAY))
    # a dst that does not fit is replaced, as cv2 does
    res = wcv.cvtColor(src, wcv.COLOR_BGR2GRAY, np.zeros((3, 3), np.uint8), backend=backend)
    assert res.shape == (427, 640)


def test_cvtcolor_unsupported(backend):
    with runs_on_cv2("code"):
        wcv.cvtColor(bgr("chelsea"), cv2.COLOR_BGR2HSV, backend=backend)
    with runs_on_cv2("dstCn"):
        wcv.cvtColor(bgr("chelsea"), wcv.COLOR_BGR2GRAY, None, 3, backend=backend)


# --- remap ----------------------------------------------------------------------------------


@pytest.mark.parametrize("interpolation", ["INTER_LINEAR", "INTER_NEAREST"])
@pytest.mark.parametrize("border", ["BORDER_CONSTANT", "BORDER_REPLICATE", "BORDER_REFLECT_101"])
def test_remap_like_cv2(backend, interpolation, border):
    src = bgr("motorcycle")
    mx, my = undistort_maps(741, 500)
    args = (getattr(cv2, interpolation),)
    kw = {"borderMode": getattr(cv2, border), "borderValue": (3, 4, 5)}
    ref = cv2.remap(src, mx, my, *args, **kw)
    out = wcv.remap(src, mx, my, *args, **kw, backend=backend)
    assert type(out) is type(ref) and out.shape == ref.shape and out.dtype == ref.dtype
    assert_close(out, ref)


def test_remap_scalar_border_value_is_cv2_scalar(backend):
    """cv2 turns borderValue=v into Scalar(v, 0, 0, 0): only channel 0 gets v."""
    src = bgr("chelsea")
    m1 = np.full((4, 6), -100, np.float32)
    m2 = np.full((4, 6), -100, np.float32)
    ref = cv2.remap(src, m1, m2, cv2.INTER_LINEAR, borderValue=77)
    out = wcv.remap(src, m1, m2, wcv.INTER_LINEAR, borderValue=77, backend=backend)
    assert out[0, 0].tolist() == ref[0, 0].tolist() == [77, 0, 0]


def test_remap_gray_hxwx1_returns_hxw(backend):
    g = gray("camera")[..., None].copy()
    mx, my = undistort_maps(512, 512)
    ref = cv2.remap(g, mx, my, cv2.INTER_LINEAR)
    out = wcv.remap(g, mx, my, wcv.INTER_LINEAR, backend=backend)
    assert out.shape == ref.shape == (512, 512)
    assert_close(out, ref)


def test_remap_interleaved_map(backend):
    src = bgr("chelsea")
    mx, my = undistort_maps(451, 300)
    xy = np.ascontiguousarray(np.dstack([mx, my]))
    ref = cv2.remap(src, xy, None, cv2.INTER_LINEAR)
    assert_close(wcv.remap(src, xy, None, wcv.INTER_LINEAR, backend=backend), ref)


def test_remap_dst(backend):
    src = bgr("chelsea")
    mx, my = undistort_maps(451, 300)
    dst = np.zeros_like(src)
    res = wcv.remap(src, mx, my, wcv.INTER_LINEAR, dst, backend=backend)
    assert res is dst
    assert_close(dst, cv2.remap(src, mx, my, cv2.INTER_LINEAR))


def test_remap_unsupported(backend):
    src = gray("camera")
    mx, my = undistort_maps(512, 512)
    with runs_on_cv2("interpolation"):
        wcv.remap(src, mx, my, cv2.INTER_CUBIC, backend=backend)
    with runs_on_cv2("borderMode"):
        wcv.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP, backend=backend)
    with runs_on_cv2("map2"):
        wcv.remap(src, mx, None, cv2.INTER_LINEAR, backend=backend)
    with pytest.raises(warpvx.ShapeError, match="map2"):
        wcv.remap(src, mx, my[:10], cv2.INTER_LINEAR, backend=backend)


# --- warpPerspective ------------------------------------------------------------------------


@pytest.mark.parametrize("flags", ["INTER_LINEAR", "INTER_NEAREST"])
@pytest.mark.parametrize("inverse", [False, True])
def test_warp_perspective_like_cv2(backend, flags, inverse):
    src = bgr("rocket")
    m = mild_homography(640, 427)
    f = getattr(cv2, flags) | (cv2.WARP_INVERSE_MAP if inverse else 0)
    ref = cv2.warpPerspective(src, m, (600, 400), flags=f, borderMode=cv2.BORDER_REPLICATE)
    out = wcv.warpPerspective(src, m, (600, 400), flags=f, borderMode=wcv.BORDER_REPLICATE, backend=backend)
    assert type(out) is type(ref) and out.shape == ref.shape and out.dtype == ref.dtype
    assert_close(out, ref)


def test_warp_perspective_defaults_and_zero_dsize(backend):
    src = gray("camera")
    m = mild_homography(512, 512)
    ref = cv2.warpPerspective(src, m, (0, 0))
    out = wcv.warpPerspective(src, m, (0, 0), backend=backend)
    assert out.shape == ref.shape == (512, 512)
    assert_close(out, ref)


def test_warp_perspective_dst(backend):
    src = bgr("chelsea")
    dst = np.zeros((200, 300, 3), np.uint8)
    res = wcv.warpPerspective(src, np.eye(3), (300, 200), dst, backend=backend)
    assert res is dst
    np.testing.assert_array_equal(dst, src[:200, :300])


def test_warp_perspective_unsupported(backend):
    src = gray("camera")
    with runs_on_cv2("flags"):
        wcv.warpPerspective(src, np.eye(3), (10, 10), flags=cv2.INTER_CUBIC, backend=backend)
    with runs_on_cv2("flags"):
        wcv.warpPerspective(src, np.eye(3), (10, 10), flags=cv2.INTER_LINEAR | cv2.WARP_RELATIVE_MAP,
                            backend=backend)
    with runs_on_cv2("borderMode"):
        wcv.warpPerspective(src, np.eye(3), (10, 10), borderMode=cv2.BORDER_REFLECT, backend=backend)
    with pytest.raises(warpvx.WarpvxValueError, match="M"):
        wcv.warpPerspective(src, np.zeros((3, 3)), (10, 10), backend=backend)


def test_drop_in_on_warp_arrays(warp_backend):
    import warp as wp

    from warpvx.backend import resolve_backend

    dev = resolve_backend(warp_backend).device
    src_host = bgr("chelsea")
    src = wp.array(src_host, dtype=wp.uint8, device=dev)
    gray_out = wcv.cvtColor(src, wcv.COLOR_BGR2GRAY)
    assert isinstance(gray_out, wp.array) and gray_out.shape == (300, 451)
    assert_close(gray_out.numpy(), cv2.cvtColor(src_host, cv2.COLOR_BGR2GRAY))
