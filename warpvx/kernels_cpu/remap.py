"""CPU remap: ``cv2.remap`` with float32 maps."""

from __future__ import annotations

import cv2
import numpy as np


def remap(src: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, interpolation: int, border: int,
          border_value, *, out=None) -> np.ndarray:
    """Remap a uint8 image with OpenCV.

    Arguments are those of :func:`warpvx.kernels_warp.remap.remap` on host arrays
    (``interpolation`` and ``border`` are OpenCV's integer values, ``border_value`` a
    4-tuple). Returns ``out`` when given. Pixels whose map entry is NaN or inf get
    ``border_value`` (warpvx's definition; OpenCV's own result there depends on its code path).
    """
    bval = tuple(float(v) for v in border_value)
    if map_x.ctypes.data == map_y.ctypes.data:
        # OpenCV >= 4.11 takes one buffer passed as both maps for an interleaved (x, y) map.
        map_y = map_y.copy()
    res = cv2.remap(src, map_x, map_y, interpolation, dst=out, borderMode=border, borderValue=bval)
    if out is not None:
        res = out
    # cv2.checkRange is a fast multi-threaded scan; the mask is built only when it fails.
    if not (cv2.checkRange(map_x)[0] and cv2.checkRange(map_y)[0]):
        bad = ~(np.isfinite(map_x) & np.isfinite(map_y))
        res[bad] = np.asarray(bval[: 1 if res.ndim == 2 else res.shape[2]], dtype=np.uint8)
    return res
