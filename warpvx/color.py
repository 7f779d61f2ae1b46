"""Colour conversion (OpenCV's ``cvtColor`` for uint8 images).

Codes are cv2's integers or their names (``"BGR2GRAY"``, ``"COLOR_BGR2GRAY"``); see
:data:`CODES`. Arithmetic, bit-exact with OpenCV:

- to gray: ``Y = (3735*B + 19235*G + 9798*R + 2^14) >> 15`` (ITU-R BT.601 weights in 15-bit
  fixed point, as OpenCV's ``RGB2Gray<uchar>``); alpha is ignored.
- channel swaps / alpha: copy with R and B exchanged as named; a new alpha is 255.
- NV12 / NV21 (one (H*3/2) x W uint8 plane: H rows of Y, then H/2 rows of interleaved
  U,V (NV12) or V,U (NV21) at half resolution) to BGR/RGB(A), ITU-R BT.601 limited range in
  20-bit fixed point as OpenCV's ``YUV420sp2RGB``::

      y' = max(Y - 16, 0) * 1220542,  u = U - 128,  v = V - 128
      R = (y' + 1673527 v + 2^19) >> 20
      G = (y' - 852492 v - 409993 u + 2^19) >> 20
      B = (y' + 2116026 u + 2^19) >> 20        (each saturated to [0, 255])
"""

from __future__ import annotations

import numbers

import numpy as np

from ._color_codes import _SPECS, ColorCode, code_spec, output_shape  # noqa: F401
from .backend import resolve_backend
from .callmemo import CallMemo
from .check import check_array, check_image
from .errors import ShapeError, UnsupportedError
from .registry import dispatch


#: Accepted names (without the ``COLOR_`` prefix) and their cv2 integer codes.
CODES = {
    "BGR2BGRA": 0, "RGB2RGBA": 0, "BGRA2BGR": 1, "RGBA2RGB": 1,
    "BGR2RGBA": 2, "RGB2BGRA": 2, "RGBA2BGR": 3, "BGRA2RGB": 3,
    "BGR2RGB": 4, "RGB2BGR": 4, "BGRA2RGBA": 5, "RGBA2BGRA": 5,
    "BGR2GRAY": 6, "RGB2GRAY": 7, "GRAY2BGR": 8, "GRAY2RGB": 8,
    "GRAY2BGRA": 9, "GRAY2RGBA": 9, "BGRA2GRAY": 10, "RGBA2GRAY": 11,
    "YUV2RGB_NV12": 90, "YUV2BGR_NV12": 91, "YUV2RGB_NV21": 92, "YUV2BGR_NV21": 93,
    "YUV420sp2RGB": 92, "YUV420sp2BGR": 93,
    "YUV2RGBA_NV12": 94, "YUV2BGRA_NV12": 95, "YUV2RGBA_NV21": 96, "YUV2BGRA_NV21": 97,
    "YUV420sp2RGBA": 96, "YUV420sp2BGRA": 97,
    "YUV2GRAY_NV12": 106, "YUV2GRAY_NV21": 106, "YUV420sp2GRAY": 106,
}
_BY_UPPER = {k.upper(): v for k, v in CODES.items()}
# Every exact spelling in CODES, with and without COLOR_, for a lookup without normalising.
_BY_SPELLING = {**CODES, **{f"COLOR_{k}": v for k, v in CODES.items()}}


def resolve_code(code) -> int:
    """cv2's integer for ``code`` (an int or a name with or without ``COLOR_``)."""
    t = type(code)
    if t is int and code in _SPECS:
        return code
    if t is str:
        hit = _BY_SPELLING.get(code)
        if hit is not None:
            return hit
    if isinstance(code, str):
        key = code.strip().upper()
        if key.startswith("COLOR_"):
            key = key[len("COLOR_"):]
        if key in _BY_UPPER:
            return _BY_UPPER[key]
    elif isinstance(code, numbers.Integral) and not isinstance(code, bool) and int(code) in _SPECS:
        return int(code)
    raise UnsupportedError(
        f"code: unsupported colour conversion {code!r}; supported: {', '.join(CODES)} "
        f"(names, with or without COLOR_, or cv2's integers)"
    )


_memo = CallMemo("color_convert")


def color_convert(src, code, *, out=None, backend=None, stream=None):
    """Convert a uint8 image between colour spaces, as ``cv2.cvtColor(src, code)``.

    Parameters
    ----------
    src : array
        uint8, C-contiguous. Gray inputs HxW (or HxWx1); colour inputs HxWx3 or HxWx4 (any
        code from 3 or 4 channels accepts both, alpha ignored); NV12/NV21 inputs one
        (H*3/2) x W plane with H and W even.
    code : int or str
        A cv2 code (``cv2.COLOR_BGR2GRAY``) or its name (``"BGR2GRAY"``,
        ``"COLOR_BGR2GRAY"``); see :data:`CODES` and the module docstring for the arithmetic.
    out : array, optional
        uint8 output of the converted shape (HxW for gray results).
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    array
        uint8 HxW (gray) or HxWxC, of the input's kind (NumPy or ``wp.array``).

    Raises
    ------
    UnsupportedError
        ``code`` is unknown.
    DTypeError, ShapeError, WarpvxValueError
        Bad ``src`` (dtype, channel count for the code, empty, odd NV12 size, not contiguous)
        or ``out``.
    """
    key = _memo.key((src,), (code,), out, backend, stream)
    done = _memo.replay(key, out)
    if done is not None:
        return done
    be = resolve_backend(backend, like=src)
    c = resolve_code(code)
    spec = _SPECS[c]
    src = check_image(src, "src", dtypes=(np.uint8,), channels=spec.src_channels)
    if src.ndim == 3 and src.shape[2] == 1:
        src = src.reshape((src.shape[0], src.shape[1]))
    if spec.kind in ("nv", "luma"):
        rows, width = src.shape
        if rows % 3 != 0 or width % 2 != 0:
            raise ShapeError(
                f"src: an NV12/NV21 plane must have H*3/2 rows and an even width W (H even), "
                f"got shape {tuple(src.shape)}"
            )
    if out is not None:
        check_array(out, "out", shape=output_shape(c, tuple(src.shape)), dtypes=(np.uint8,))
    return _memo.run(key, lambda: dispatch("color_convert", be, src, c, out=out, stream=stream), out)
