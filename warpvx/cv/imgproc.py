"""warpvx.cv.imgproc: ``cvtColor``, ``remap``, ``warpPerspective`` under cv2's names.

Same argument order, defaults, constants and results as ``cv2`` for the supported subset:
uint8 images; float32 maps; INTER_NEAREST / INTER_LINEAR; BORDER_CONSTANT / BORDER_REPLICATE /
BORDER_REFLECT_101. Anything else raises :class:`warpvx.UnsupportedError` naming the
argument. ``dst`` is written and returned when its shape and dtype fit (cv2 reallocates
otherwise, and so do these). Each function also takes ``backend=`` (see :mod:`warpvx.backend`).
A scalar ``borderValue`` is cv2's ``Scalar(v)``, i.e. ``(v, 0, 0, 0)``.
Known difference: ``warpPerspective`` rejects a singular or non-finite ``M`` (cv2 warps
through whatever its inversion gives).
"""

from __future__ import annotations

import numbers

import numpy as np

from ..arrays import as_input, is_contiguous, numpy_dtype
from ..check import check_array
from ..color import CODES, output_shape, resolve_code
from ..color import color_convert as _color_convert
from ..errors import UnsupportedError
from ..geometry import remap as _remap
from ..geometry import warp_perspective as _warp_perspective

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
_BORDERS = (BORDER_CONSTANT, BORDER_REPLICATE, BORDER_REFLECT_101)


def cvtColor(src, code, dst=None, dstCn=0, *, backend=None):
    """``cv2.cvtColor`` for uint8 images (codes of :data:`warpvx.color.CODES`).

    Returns HxW for gray results, HxWxC otherwise, of the input's kind.
    """
    c = resolve_code(code)
    shape = getattr(src, "shape", ())
    expected = None
    if len(shape) in (2, 3):
        expected = output_shape(c, (shape[0], shape[1]))
        want_cn = 1 if len(expected) == 2 else expected[2]
        if dstCn not in (0, want_cn):
            raise UnsupportedError(f"dstCn: code {code!r} gives {want_cn} channel(s), got dstCn={dstCn!r}")
    out = dst if _fits(dst, expected) else None
    return _color_convert(src, c, out=out, backend=backend)


def remap(src, map1, map2, interpolation, dst=None, borderMode=BORDER_CONSTANT, borderValue=0, *,
          backend=None):
    """``cv2.remap`` with float32 maps: ``map1``/``map2`` HxW (x and y), or ``map1`` HxWx2
    (x, y pairs; NumPy only) with ``map2`` None. Fixed-point maps (CV_16SC2) are unsupported.
    """
    interp = _interpolation(interpolation, "interpolation")
    border = _border(borderMode)
    map_x, map_y = _split_maps(map1, map2)
    channels = _channels(src)
    expected = None
    if channels is not None:
        h, w = map_x.shape
        expected = (h, w) if channels == 1 else (h, w, channels)
    out = dst if _fits(dst, expected) else None
    return _remap(src, map_x, map_y, interp, border, _scalar(borderValue), out=out, backend=backend)


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
    shape = getattr(src, "shape", ())
    try:
        if tuple(int(v) for v in dsize) == (0, 0) and len(shape) >= 2:
            dsize = (shape[1], shape[0])
    except (TypeError, ValueError):
        pass  # the public function reports the bad dsize
    channels = _channels(src)
    expected = None
    try:
        w, h = int(dsize[0]), int(dsize[1])
        if channels is not None:
            expected = (h, w) if channels == 1 else (h, w, channels)
    except (TypeError, ValueError, IndexError):
        pass
    out = dst if _fits(dst, expected) else None
    return _warp_perspective(src, M, dsize, interp, bool(flags & WARP_INVERSE_MAP), border,
                             _scalar(borderValue), out=out, backend=backend)


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


def _split_maps(map1, map2):
    m1 = as_input(map1, "map1")
    if numpy_dtype(m1) == np.int16 or (m1.ndim == 3 and m1.shape[-1] == 2 and numpy_dtype(m1) != np.float32):
        raise UnsupportedError("map1: fixed-point maps (CV_16SC2) are not supported; pass float32 maps")
    if map2 is None:
        if m1.ndim == 3 and m1.shape[2] == 2:
            if not isinstance(m1, np.ndarray):
                raise UnsupportedError(
                    "map1: an HxWx2 map is supported for NumPy arrays only; pass two HxW maps")
            m1 = check_array(m1, "map1", dtypes=(np.float32,))
            return np.ascontiguousarray(m1[..., 0]), np.ascontiguousarray(m1[..., 1])
        raise UnsupportedError("map2: required unless map1 is an HxWx2 float32 map")
    m1 = check_array(m1, "map1", ndim=2, dtypes=(np.float32,))
    m2 = check_array(map2, "map2", shape=tuple(m1.shape), dtypes=(np.float32,))
    return m1, m2


def _channels(src):
    shape = getattr(src, "shape", ())
    if len(shape) == 2 or (len(shape) == 3 and shape[2] == 1):
        return 1
    if len(shape) == 3:
        return shape[2]
    return None


def _fits(dst, shape) -> bool:
    """Whether ``dst`` can take a result of ``shape`` in place (uint8, contiguous)."""
    if dst is None or shape is None:
        return False
    try:
        arr = as_input(dst, "dst")
    except Exception:  # noqa: BLE001 - anything unusable is simply not written, as cv2
        return False
    return tuple(arr.shape) == tuple(shape) and numpy_dtype(arr) == np.uint8 and is_contiguous(arr)


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
