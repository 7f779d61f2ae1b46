"""goodFeaturesToTrack on the CPU (OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import UnsupportedError


def harris_corners(src: np.ndarray, max_corners: int, quality_level: float,
                   min_distance: float, block_size: int, k: float, *, ksize: int = 3,
                   score: str = "harris", out=None) -> np.ndarray:
    """``cv2.goodFeaturesToTrack`` as float32 [N, 2] (x, y), strongest first.

    ``out`` is refused: the corner count depends on the data (the Warp kernels take a
    graph's Counted buffers).
    """
    if out is not None:
        raise UnsupportedError("out: harris_corners returns a data-dependent number of corners; "
                               "the CPU backend takes no out=")
    pts = cv2.goodFeaturesToTrack(src, max(int(max_corners), 0), quality_level, min_distance,
                                  mask=None, blockSize=block_size, gradientSize=ksize,
                                  useHarrisDetector=score == "harris", k=k)
    if pts is None:
        return np.zeros((0, 2), np.float32)
    return np.ascontiguousarray(pts.reshape(-1, 2), dtype=np.float32)
