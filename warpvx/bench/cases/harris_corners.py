"""Benchmark cases of :func:`warpvx.harris_corners`."""

from __future__ import annotations

import numpy as np

from ...features import harris_corners
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """goodFeaturesToTrack (Harris, 1000 corners, quality 0.01, distance 10, block 3)."""
    gray = gray_of(image_bgr)
    h, w = gray.shape

    def prepare(backend_name):
        src = place(gray, backend_name)
        return lambda: harris_corners(src, 1000, 0.01, 10, 3, 0.04, backend=backend_name)

    def opencv():
        import cv2

        return lambda: cv2.goodFeaturesToTrack(gray, 1000, 0.01, 10, blockSize=3,
                                               useHarrisDetector=True, k=0.04)

    return [BenchCase("harris_corners", "max 1000, Harris", (w, h), prepare, opencv)]
