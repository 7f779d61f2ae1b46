"""Benchmark cases of :func:`warpvx.orb`."""

from __future__ import annotations

import numpy as np

from ...orb_extractor import MIN_LEVEL_SIZE, orb
from ...pyramid import scale_pyramid_sizes
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """ORB-SLAM2 extraction, 2000 features at 1.2 over 8 levels (fewer on an image too small
    for 8); ``cv2.ORB_create(2000, 1.2, levels).detectAndCompute`` beside it. The harness runs
    it at 1920x1080 and at KITTI's 1241x376."""
    import cv2

    gray = gray_of(image_bgr)
    h, w = gray.shape
    levels = 8
    while levels > 1 and min(scale_pyramid_sizes(w, h, levels, 1.2)[-1]) < MIN_LEVEL_SIZE:
        levels -= 1
    if min(h, w) < MIN_LEVEL_SIZE:
        return []

    def prepare(backend_name):
        src = place(gray, backend_name)
        return lambda: orb(src, 2000, 1.2, levels, 20, 7, backend=backend_name)

    def opencv():
        det = cv2.ORB_create(2000, 1.2, levels)
        return lambda: det.detectAndCompute(gray, None)

    return [BenchCase("orb", f"2000 features, {levels} levels", (w, h), prepare, opencv,
                      bytes_moved=h * w)]
