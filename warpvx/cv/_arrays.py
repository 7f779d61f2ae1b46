"""Arrays taken and written as cv2 does: strided views in, ``dst`` filled in place."""

from __future__ import annotations

import numpy as np

from ..arrays import as_input, contiguous, is_contiguous, numpy_dtype  # noqa: F401  (contiguous: used by the drop-ins)


def channels(src):
    """1 for HxW or HxWx1, C for HxWxC, None for anything else (left to the callee)."""
    shape = getattr(src, "shape", ())
    if len(shape) == 2 or (len(shape) == 3 and shape[2] == 1):
        return 1
    if len(shape) == 3:
        return shape[2]
    return None


def fits(dst, shape) -> bool:
    """Whether ``dst`` can take a uint8 result of ``shape`` in place (strided or not)."""
    if dst is None or shape is None:
        return False
    try:
        arr = as_input(dst, "dst")
    except Exception:  # noqa: BLE001 - anything unusable is simply not written, as cv2
        return False
    return tuple(arr.shape) == tuple(shape) and numpy_dtype(arr) == np.uint8


def into_dst(dst, shape, compute):
    """cv2's ``dst``: ``compute(out)`` writes into ``dst`` when it fits ``shape`` (uint8).

    A contiguous ``dst`` is passed as ``out``; a strided NumPy one (an ROI of a larger image)
    is filled from a fresh result and returned, as cv2 writes through views. A ``dst`` that
    does not fit is ignored and the fresh result returned (cv2 reallocates it).
    """
    if not fits(dst, shape):
        return compute(None)
    if is_contiguous(as_input(dst, "dst")):
        return compute(dst)
    result = compute(None)
    if isinstance(dst, np.ndarray):
        np.copyto(dst, result if isinstance(result, np.ndarray) else result.numpy())
        return dst
    return result
