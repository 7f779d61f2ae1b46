"""warpvx.cv.imgproc: ``cvtColor``, ``remap``, ``warpPerspective`` under cv2's names.

Same argument order, defaults, constants and results as ``cv2`` for the supported subset:
uint8 images; float32 maps or cv2's fixed-point ones (CV_16SC2); INTER_NEAREST /
INTER_LINEAR; BORDER_CONSTANT / BORDER_REPLICATE / BORDER_REFLECT_101. Anything else runs on
cv2, with a one-time :class:`warpvx.cv.CvFallbackWarning` naming the argument. Strided views are copied once (see
:mod:`warpvx.cv`); ``dst`` is written and returned when its shape and dtype fit (cv2
reallocates otherwise, and so do these). Each function also takes ``backend=`` (see
:mod:`warpvx.backend`).
A scalar ``borderValue`` is cv2's ``Scalar(v)``, i.e. ``(v, 0, 0, 0)``.
Known difference: ``warpPerspective`` rejects a singular or non-finite ``M`` (cv2 warps
through whatever its inversion gives).
"""

from __future__ import annotations

import numbers

import numpy as np

from ..arrays import as_input, numpy_dtype
from ..check import check_array
from ..color import CODES, output_shape, resolve_code
from ..color import color_convert as _color_convert
from ..errors import UnsupportedError
from ..geometry import remap as _remap
from ..geometry import warp_perspective as _warp_perspective
from ._arrays import channels, contiguous, into_dst
from ._fallback import function

INTER_NEAREST = 0
INTER_LINEAR = 1
WARP_INVERSE_MAP = 16
BORDER_CONSTANT = 0
BORDER_REPLICATE = 1
BORDER_REFLECT_101 = 4
BORDER_REFLECT101 = 4
BORDER_DEFAULT = 4

# COLOR_<name> for every supported code, with cv2's integer values.
_COLOR_CONSTANTS = {f"COLOR_{name}": code for name, code in CODES.items()}
globals().update(_COLOR_CONSTANTS)

_INTER_MASK = 7  # cv2.INTER_MAX: the interpolation bits of warp flags
_INTER_BITS = 5  # cv2.INTER_BITS: a fixed-point map's fractions are in 1/32 pixel
_INTER_TAB_SIZE = 1 << _INTER_BITS
_BORDERS = (BORDER_CONSTANT, BORDER_REPLICATE, BORDER_REFLECT_101)


@function
def cvtColor(src, code, dst=None, dstCn=0, *, backend=None):
    """``cv2.cvtColor`` for uint8 images (codes of :data:`warpvx.color.CODES`).

    Returns HxW for gray results, HxWxC otherwise, of the input's kind.
    """
    c = resolve_code(code)
    src = contiguous(src)
    shape = getattr(src, "shape", ())
    expected = None
    if len(shape) in (2, 3):
        expected = output_shape(c, (shape[0], shape[1]))
        want_cn = 1 if len(expected) == 2 else expected[2]
        if dstCn not in (0, want_cn):
            raise UnsupportedError(f"dstCn: code {code!r} gives {want_cn} channel(s), got dstCn={dstCn!r}")
    return into_dst(dst, expected, lambda out: _color_convert(src, c, out=out, backend=backend))


@function
def remap(src, map1, map2, interpolation, dst=None, borderMode=BORDER_CONSTANT, borderValue=0, *,
          backend=None):
    """``cv2.remap``. Maps as cv2 takes them: float32 ``map1``/``map2`` HxW (x and y);
    ``map1`` float32 HxWx2 (x, y pairs) with ``map2`` None; or fixed-point ``map1`` int16
    HxWx2 (CV_16SC2, integer x, y) with ``map2`` uint16 HxW (the interpolation table index
    ``(fy << 5) | fx`` in 1/32 pixel) or None, from ``cv2.convertMaps`` (NumPy only).

    Fixed-point maps are converted to float32 maps on each call (pass float maps where speed
    matters): INTER_NEAREST then gives cv2's pixels exactly; INTER_LINEAR gives cv2's result
    on the equivalent float maps, from which cv2's own fixed-point path (15-bit weights)
    differs by 1 on under 1% of pixels.
    """
    interp = _interpolation(interpolation, "interpolation")
    border = _border(borderMode)
    src = contiguous(src)
    map_x, map_y = _split_maps(map1, map2, interp)
    cn = channels(src)
    expected = None
    if cn is not None:
        h, w = map_x.shape
        expected = (h, w) if cn == 1 else (h, w, cn)
    value = _scalar(borderValue)
    return into_dst(dst, expected, lambda out: _remap(src, map_x, map_y, interp, border, value,
                                                      out=out, backend=backend))


@function
def warpPerspective(src, M, dsize, dst=None, flags=INTER_LINEAR, borderMode=BORDER_CONSTANT,
                    borderValue=0, *, backend=None):
    """``cv2.warpPerspective``: ``flags`` is INTER_NEAREST or INTER_LINEAR, optionally with
    WARP_INVERSE_MAP; ``dsize`` (width, height), (0, 0) meaning the source size."""
    if isinstance(flags, bool) or not isinstance(flags, numbers.Integral):
        raise UnsupportedError(f"flags: expected an integer, got {flags!r}")
    flags = int(flags)
    if flags & ~(_INTER_MASK | WARP_INVERSE_MAP):
        raise UnsupportedError(f"flags: only INTER_NEAREST/INTER_LINEAR | WARP_INVERSE_MAP, got {flags}")
    interp = _interpolation(flags & _INTER_MASK, "flags")
    border = _border(borderMode)
    src = contiguous(src)
    shape = getattr(src, "shape", ())
    try:
        if tuple(int(v) for v in dsize) == (0, 0) and len(shape) >= 2:
            dsize = (shape[1], shape[0])
    except (TypeError, ValueError):
        pass  # the public function reports the bad dsize
    cn = channels(src)
    expected = None
    try:
        w, h = int(dsize[0]), int(dsize[1])
        if cn is not None:
            expected = (h, w) if cn == 1 else (h, w, cn)
    except (TypeError, ValueError, IndexError):
        pass
    inverse, value = bool(flags & WARP_INVERSE_MAP), _scalar(borderValue)
    return into_dst(dst, expected, lambda out: _warp_perspective(
        src, M, dsize, interp, inverse, border, value, out=out, backend=backend))


def _interpolation(v, name):
    ok = isinstance(v, numbers.Integral) and not isinstance(v, bool)
    if not ok or int(v) not in (INTER_NEAREST, INTER_LINEAR):
        raise UnsupportedError(
            f"{name}: only INTER_NEAREST (0) and INTER_LINEAR (1) are supported, got {v!r}")
    return int(v)


def _border(v):
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or int(v) not in _BORDERS:
        raise UnsupportedError(
            f"borderMode: only BORDER_CONSTANT, BORDER_REPLICATE and BORDER_REFLECT_101 are "
            f"supported, got {v!r}"
        )
    return int(v)


def _scalar(v):
    """cv2's Scalar conversion: a number is (v, 0, 0, 0)."""
    if isinstance(v, numbers.Real) and not isinstance(v, bool):
        return (v, 0, 0, 0)
    return v


def _split_maps(map1, map2, interp):
    """float32 x and y maps (HxW each, C-contiguous) from any map layout cv2.remap takes."""
    m1 = contiguous(as_input(map1, "map1"))
    if numpy_dtype(m1) == np.int16:
        return _fixed_point_maps(m1, map2, interp)
    if map2 is None:
        if m1.ndim == 3 and m1.shape[2] == 2:
            m1 = check_array(m1, "map1", dtypes=(np.float32,))
            return contiguous(m1[:, :, 0]), contiguous(m1[:, :, 1])
        raise UnsupportedError("map2: required unless map1 is an HxWx2 float32 or int16 map")
    m1 = check_array(m1, "map1", ndim=2, dtypes=(np.float32,))
    m2 = check_array(contiguous(map2), "map2", shape=tuple(m1.shape), dtypes=(np.float32,))
    return m1, m2


def _fixed_point_maps(m1, map2, interp):
    """cv2's CV_16SC2 ``map1`` and CV_16UC1 ``map2`` as float32 x and y, read as cv::remap
    reads them (INTER_TAB_SIZE 32): with fx = map2 & 31 and fy = (map2 >> 5) & 31, INTER_LINEAR
    samples at x = map1[..., 0] + fx / 32, y = map1[..., 1] + fy / 32 (exact in float32);
    INTER_NEAREST takes map1's pixel moved by OpenCV's NNDeltaTab, +1 where the fraction is
    below one half (fx < 16, fy < 16), cv2's own rule. Without ``map2`` map1 holds whole
    pixels (cv2 5.0 returns the border value there under INTER_LINEAR; this the pixels)."""
    m2 = None if map2 is None else contiguous(as_input(map2, "map2"))
    if not isinstance(m1, np.ndarray) or not (m2 is None or isinstance(m2, np.ndarray)):
        raise UnsupportedError("map1: fixed-point maps (CV_16SC2) are supported as NumPy arrays; "
                               "pass float32 maps for device arrays")
    m1 = check_array(m1, "map1", shape=(None, None, 2), dtypes=(np.int16,))
    x = m1[:, :, 0].astype(np.float32)
    y = m1[:, :, 1].astype(np.float32)
    if m2 is not None:
        m2 = check_array(m2, "map2", shape=m1.shape[:2], dtypes=(np.uint16, np.int16))
        a = m2.astype(np.int32) & (_INTER_TAB_SIZE * _INTER_TAB_SIZE - 1)
        fx, fy = a & (_INTER_TAB_SIZE - 1), a >> _INTER_BITS
        if interp == INTER_NEAREST:
            x += fx < _INTER_TAB_SIZE // 2
            y += fy < _INTER_TAB_SIZE // 2
        else:
            x += fx.astype(np.float32) / _INTER_TAB_SIZE
            y += fy.astype(np.float32) / _INTER_TAB_SIZE
    return x, y


__all__ = [
    "cvtColor",
    "remap",
    "warpPerspective",
    "INTER_NEAREST",
    "INTER_LINEAR",
    "WARP_INVERSE_MAP",
    "BORDER_CONSTANT",
    "BORDER_REPLICATE",
    "BORDER_REFLECT_101",
    "BORDER_REFLECT101",
    "BORDER_DEFAULT",
    *_COLOR_CONSTANTS,
]
