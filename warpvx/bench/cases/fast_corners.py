"""Benchmark cases of :func:`warpvx.fast_corners`."""

from __future__ import annotations

import numpy as np

from ...features import fast_corners
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """FAST-9/16 at threshold 20 with NMS; OpenCV's FastFeatureDetector beside it."""
    gray = gray_of(image_bgr)
    h, w = gray.shape

    def prepare(backend_name):
        src = place(gray, backend_name)
        return lambda: fast_corners(src, 20, True, backend=backend_name)

    def opencv():
        import cv2

        det = cv2.FastFeatureDetector_create(20, True)
        return lambda: det.detect(gray)

    return [BenchCase("fast_corners", "threshold 20, nonmax", (w, h), prepare, opencv,
                      bytes_moved=h * w)]
