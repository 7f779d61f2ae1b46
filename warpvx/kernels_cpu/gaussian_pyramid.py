"""CPU Gaussian pyramid: repeated ``cv2.pyrDown``."""

from __future__ import annotations

import cv2
import numpy as np


def gaussian_pyramid(src: np.ndarray, levels: int, *, out=None, sizes=None) -> list:
    """``[src, pyrDown(src), pyrDown(pyrDown(src)), ...]``, ``levels`` images; arguments as
    :func:`warpvx.kernels_warp.gaussian_pyramid.gaussian_pyramid`."""
    pyramid = [src]
    for lvl in range(1, levels):
        prev = pyramid[-1]
        dst = out[lvl] if out is not None else None
        if sizes is not None:
            size = tuple(sizes[lvl])
        elif dst is not None:
            size = (dst.shape[1], dst.shape[0])
        else:
            size = ((prev.shape[1] + 1) // 2, (prev.shape[0] + 1) // 2)
        pyramid.append(cv2.pyrDown(prev, dst=dst, dstsize=size))
    return pyramid
