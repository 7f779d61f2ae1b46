"""CPU bilinear resize (``cv2.resize`` INTER_LINEAR) and the ORB-SLAM2 scale pyramid on it."""

from __future__ import annotations

import cv2
import numpy as np

from .._pyramid_sizes import resize_scales, scale_pyramid_sizes


def resize(src: np.ndarray, dsize=None, fx=0.0, fy=0.0, *, out=None) -> np.ndarray:
    """``cv2.resize(src, dsize, fx=fx, fy=fy, interpolation=INTER_LINEAR)``; arguments as
    :func:`warpvx.kernels_warp.scale_pyramid.resize`."""
    (dw, dh), _ = resize_scales((src.shape[1], src.shape[0]), dsize, fx, fy)
    if dsize is not None and dsize[0] > 0 and dsize[1] > 0:
        return cv2.resize(src, (dw, dh), dst=out, interpolation=cv2.INTER_LINEAR)
    return cv2.resize(src, None, dst=out, fx=float(fx), fy=float(fy), interpolation=cv2.INTER_LINEAR)


def scale_pyramid(src: np.ndarray, levels: int, scale_factor: float, *, out=None) -> list:
    """ORB-SLAM2's pyramid; arguments as :func:`warpvx.kernels_warp.scale_pyramid.scale_pyramid`."""
    sizes = scale_pyramid_sizes(src.shape[1], src.shape[0], levels, scale_factor)
    pyramid = [src]
    for lvl in range(1, levels):
        dst = out[lvl] if out is not None else None
        pyramid.append(cv2.resize(pyramid[-1], sizes[lvl], dst=dst, interpolation=cv2.INTER_LINEAR))
    return pyramid
