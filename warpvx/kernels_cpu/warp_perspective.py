"""CPU perspective warp: ``cv2.warpPerspective`` with the dst->src matrix."""

from __future__ import annotations

import cv2
import numpy as np


def warp_perspective(src: np.ndarray, m_inv, dsize, interpolation: int, border: int, border_value,
                     *, out=None) -> np.ndarray:
    """Warp a uint8 image with OpenCV.

    ``m_inv`` is the 3x3 matrix mapping destination to source pixels as 9 floats in row
    order (the public function inverts a src->dst matrix beforehand), ``dsize`` is
    (width, height); the other arguments are those of :func:`warpvx.kernels_cpu.remap.remap`.
    Returns ``out`` when given.
    """
    m = np.asarray(m_inv, dtype=np.float64).reshape(3, 3)
    res = cv2.warpPerspective(src, m, tuple(dsize), dst=out, flags=interpolation | cv2.WARP_INVERSE_MAP,
                              borderMode=border, borderValue=tuple(float(v) for v in border_value))
    return res if out is None else out
