"""Benchmark cases of :func:`warpvx.match_hamming`."""

from __future__ import annotations

import numpy as np

from ...matching import match_hamming
from ..inputs import gray_of
from . import BenchCase, place


def orb_descriptors(image_bgr: np.ndarray, n: int = 2000) -> tuple:
    """OpenCV ORB descriptors (uint8 Nx32) of the photo and of a rotated (10 deg), scaled (0.9)
    copy of it."""
    import cv2

    gray = gray_of(image_bgr)
    h, w = gray.shape
    m = cv2.getRotationMatrix2D((w / 2, h / 2), 10, 0.9)
    other = cv2.warpAffine(gray, m, (w, h), flags=cv2.INTER_LINEAR)
    orb = cv2.ORB_create(n)
    _, d1 = orb.detectAndCompute(gray, None)
    _, d2 = orb.detectAndCompute(other, None)
    return np.ascontiguousarray(d1), np.ascontiguousarray(d2)


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """2000 x 2000 real ORB descriptors; cv2.BFMatcher(NORM_HAMMING) beside it."""
    d1, d2 = orb_descriptors(image_bgr)
    h, w = image_bgr.shape[:2]

    def case(cross_check):
        def prepare(backend_name):
            q, t = place(d1, backend_name), place(d2, backend_name)
            return lambda: match_hamming(q, t, cross_check, backend=backend_name)

        def opencv():
            import cv2

            bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=cross_check)
            return lambda: bf.match(d1, d2)

        label = f"{d1.shape[0]}x{d2.shape[0]}" + (" cross check" if cross_check else "")
        return BenchCase("match_hamming", label, (w, h), prepare, opencv,
                         bytes_moved=(d1.size + d2.size))

    return [case(False), case(True)]
