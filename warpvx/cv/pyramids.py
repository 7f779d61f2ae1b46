"""warpvx.cv.pyramids: ``pyrDown``, ``buildPyramid``, ``resize``, ``GaussianBlur`` under cv2's names.

Same argument order, defaults, constants and results as ``cv2`` for the supported subset:
uint8 images (gray, 3 or 4 channels); ``pyrDown``/``buildPyramid`` with ``BORDER_DEFAULT``
(REFLECT_101); ``resize`` with ``INTER_LINEAR``; ``GaussianBlur`` with BORDER_CONSTANT,
BORDER_REPLICATE, BORDER_REFLECT or BORDER_REFLECT_101 and odd sizes up to 31. All are
bit-exact with OpenCV. Anything else runs on cv2 (one :class:`warpvx.cv.CvFallbackWarning` naming
the argument). Strided views are copied once (see :mod:`warpvx.cv`); ``dst`` is written and returned when its shape and dtype fit (cv2 reallocates
otherwise, and so do these). Each function also takes ``backend=`` (see :mod:`warpvx.backend`).
"""

from __future__ import annotations

import numbers

import numpy as np

from ..arrays import as_input, is_warp_array
from ..backend import init_warp
from ..errors import UnsupportedError, WarpvxTypeError, WarpvxValueError
from ..filters import gaussian_blur as _gaussian_blur
from ..pyramid import _max_gaussian_levels, resize_scales
from ..pyramid import gaussian_pyramid as _gaussian_pyramid
from ..pyramid import resize as _resize
from ._arrays import channels, contiguous, into_dst
from .imgproc import BORDER_CONSTANT, BORDER_DEFAULT, BORDER_REFLECT_101, BORDER_REPLICATE, INTER_LINEAR
from ._fallback import function

# cv2's values for the constants imgproc does not define.
BORDER_REFLECT = 2
BORDER_WRAP = 3
BORDER_ISOLATED = 16
INTER_CUBIC = 2
INTER_AREA = 3
INTER_LANCZOS4 = 4
INTER_LINEAR_EXACT = 5
INTER_NEAREST_EXACT = 6

_BLUR_BORDERS = (BORDER_CONSTANT, BORDER_REPLICATE, BORDER_REFLECT, BORDER_REFLECT_101)


@function
def pyrDown(src, dst=None, dstsize=None, borderType=BORDER_DEFAULT, *, backend=None):
    """``cv2.pyrDown``: blur with [1 4 6 4 1]^2 / 256 and drop every second row and column.

    ``dstsize`` (width, height) defaults to ``((w + 1) // 2, (h + 1) // 2)``; any size with
    ``|2 * dstsize - size| <= 2`` per axis is accepted, as cv2. ``borderType`` must be
    BORDER_DEFAULT / BORDER_REFLECT_101 (optionally | BORDER_ISOLATED).
    """
    _pyr_border(borderType)
    src = contiguous(src)
    arr = as_input(src, "src")
    ch = channels(arr)
    if dstsize is None or _is_zero_size(dstsize):
        h, w = arr.shape[0], arr.shape[1]
        dw, dh = (w + 1) // 2, (h + 1) // 2
    else:
        dw, dh = _int_pair(dstsize, "dstsize")
        if arr.ndim >= 2 and (abs(2 * dw - arr.shape[1]) > 2 or abs(2 * dh - arr.shape[0]) > 2
                              or dw < 1 or dh < 1):
            raise WarpvxValueError(
                f"dstsize: expected (w, h) with |2w - {arr.shape[1]}| <= 2 and |2h - {arr.shape[0]}| "
                f"<= 2, got {tuple(dstsize)}")
    expected = None if ch is None else ((dh, dw) if ch == 1 else (dh, dw, ch))
    if expected is not None and arr.shape[:2] == (1, 1) and (dh, dw) == (1, 1):
        # A 1x1 image cannot shrink: every tap mirrors onto the pixel itself.
        return into_dst(dst, expected, lambda out: _copy_into(arr, out))

    def run(out):
        if out is None and expected is not None:
            out = _empty_like(arr, expected)  # carries a dstsize other than the default
        return _gaussian_pyramid(src, 2, out=None if out is None else [src, out], backend=backend)[1]

    return into_dst(dst, expected, run)


@function
def buildPyramid(src, maxlevel, dst=None, borderType=BORDER_DEFAULT, *, backend=None):
    """``cv::buildPyramid``: ``[src, pyrDown(src), ...]``, ``maxlevel + 1`` images (a list).

    Levels past 1x1 stay 1x1, as OpenCV. ``dst`` is ignored (a list is returned).
    """
    _pyr_border(borderType)
    if isinstance(maxlevel, bool) or not isinstance(maxlevel, numbers.Integral):
        raise WarpvxTypeError(f"maxlevel: expected an integer, got {type(maxlevel).__name__} {maxlevel!r}")
    if maxlevel < 0:
        raise WarpvxValueError(f"maxlevel: expected a value >= 0, got {maxlevel}")
    src = contiguous(src)
    arr = as_input(src, "src")
    levels = int(maxlevel) + 1
    if arr.ndim >= 2 and arr.shape[0] > 0 and arr.shape[1] > 0:
        reachable = min(levels, _max_gaussian_levels(arr.shape[1], arr.shape[0]))
    else:
        reachable = levels  # let gaussian_pyramid report the bad image
    pyramid = list(_gaussian_pyramid(src, reachable, backend=backend))
    while len(pyramid) < levels:
        pyramid.append(_copy_into(pyramid[-1], None))
    return pyramid


@function
def resize(src, dsize, dst=None, fx=0, fy=0, interpolation=INTER_LINEAR, *, backend=None):
    """``cv2.resize`` with ``interpolation=INTER_LINEAR`` (bit-exact).

    ``dsize`` (width, height), or None / (0, 0) to take the size from ``fx``, ``fy``.
    """
    if isinstance(interpolation, bool) or not isinstance(interpolation, numbers.Integral) \
            or int(interpolation) != INTER_LINEAR:
        raise UnsupportedError(f"interpolation: only INTER_LINEAR (1) is supported, got {interpolation!r}")
    if dsize is not None and _is_zero_size(dsize):
        dsize = None
    src = contiguous(src)
    arr = as_input(src, "src")
    ch = channels(arr)
    expected = None
    try:
        if ch is not None:
            (dw, dh), _ = resize_scales((arr.shape[1], arr.shape[0]),
                                        None if dsize is None else _int_pair(dsize, "dsize"), fx, fy)
            expected = (dh, dw) if ch == 1 else (dh, dw, ch)
    except (TypeError, ValueError, ZeroDivisionError, OverflowError):
        pass  # the public function reports the bad dsize / fx / fy
    return into_dst(dst, expected, lambda out: _resize(src, dsize, fx, fy, out=out, backend=backend))


@function
def GaussianBlur(src, ksize, sigmaX, dst=None, sigmaY=0, borderType=BORDER_DEFAULT, *, backend=None):
    """``cv2.GaussianBlur`` on uint8 (bit-exact).

    ``ksize`` (width, height): odd sizes up to 31, or 0 to derive one from the sigma
    (``cvRound(sigma * 6 + 1) | 1``); ``sigmaY`` 0 means ``sigmaX``; negative sigmas count as
    0, as cv2.
    """
    if isinstance(borderType, bool) or not isinstance(borderType, numbers.Integral) \
            or (int(borderType) & ~BORDER_ISOLATED) not in _BLUR_BORDERS:
        raise UnsupportedError(
            "borderType: only BORDER_CONSTANT, BORDER_REPLICATE, BORDER_REFLECT and "
            f"BORDER_REFLECT_101 are supported, got {borderType!r}")
    border = int(borderType) & ~BORDER_ISOLATED
    sx = max(_number(sigmaX, "sigmaX"), 0.0)
    sy = max(_number(sigmaY, "sigmaY"), 0.0)
    if sy == 0:
        sy = sx
    kw, kh = _int_pair(ksize, "ksize")
    if kw <= 0 and sx > 0:
        kw = int(np.rint(sx * 6 + 1)) | 1
    if kh <= 0 and sy > 0:
        kh = int(np.rint(sy * 6 + 1)) | 1
    if kw <= 0 or kh <= 0:
        raise WarpvxValueError(f"ksize: expected positive odd sizes or a sigma > 0 to derive them, got {ksize!r}")
    src = contiguous(src)
    arr = as_input(src, "src")
    ch = channels(arr)
    expected = None if ch is None else (tuple(arr.shape[:2]) if ch == 1 else tuple(arr.shape))
    return into_dst(dst, expected, lambda out: _gaussian_blur(src, (kw, kh), (sx, sy), border, out=out,
                                                              backend=backend))


# --- helpers --------------------------------------------------------------------------------


def _pyr_border(border):
    if isinstance(border, bool) or not isinstance(border, numbers.Integral) \
            or (int(border) & ~BORDER_ISOLATED) != BORDER_REFLECT_101:
        raise UnsupportedError(f"borderType: only BORDER_DEFAULT (BORDER_REFLECT_101) is supported, got {border!r}")


def _is_zero_size(size) -> bool:
    try:
        return tuple(int(v) for v in size) == (0, 0)
    except (TypeError, ValueError):
        return False


def _int_pair(v, name):
    try:
        a, b = v
    except (TypeError, ValueError):
        raise WarpvxTypeError(f"{name}: expected (width, height), got {v!r}") from None
    for x in (a, b):
        if isinstance(x, bool) or not isinstance(x, numbers.Integral):
            raise WarpvxTypeError(f"{name}: expected two integers, got {v!r}")
    return int(a), int(b)


def _number(v, name) -> float:
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise WarpvxTypeError(f"{name}: expected a number, got {type(v).__name__} {v!r}")
    return float(v)


def _empty_like(arr, shape):
    if is_warp_array(arr):
        wp = init_warp()
        return wp.empty(shape, dtype=wp.uint8, device=arr.device)
    return np.empty(shape, np.uint8)


def _copy_into(arr, dst):
    if is_warp_array(arr):
        wp = init_warp()
        if dst is None:
            return wp.clone(arr)
        wp.copy(dst, arr)
        return dst
    if dst is None:
        return np.array(arr, copy=True)
    np.copyto(dst, arr)
    return dst


__all__ = [
    "pyrDown",
    "buildPyramid",
    "resize",
    "GaussianBlur",
    "BORDER_REFLECT",
    "BORDER_WRAP",
    "BORDER_ISOLATED",
    "INTER_CUBIC",
    "INTER_AREA",
    "INTER_LANCZOS4",
    "INTER_LINEAR_EXACT",
    "INTER_NEAREST_EXACT",
]
