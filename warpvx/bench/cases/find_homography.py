"""Benchmark cases of :func:`warpvx.find_homography`."""

from __future__ import annotations

import numpy as np

from ...homography import find_homography
from ..inputs import gray_of
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """ORB matches (2000 features, cross-checked) between the photo and a perspective view of
    it; 2000 hypotheses, threshold 3 px; cv2.findHomography(RANSAC) beside it."""
    import cv2

    gray = gray_of(image_bgr)
    h, w = gray.shape
    corners = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    moved = corners + np.float32([[0.04 * w, 0.02 * h], [-0.03 * w, 0.05 * h],
                                  [-0.05 * w, -0.03 * h], [0.02 * w, -0.04 * h]])
    view = cv2.warpPerspective(gray, cv2.getPerspectiveTransform(corners, moved), (w, h))
    orb = cv2.ORB_create(2000)
    k1, d1 = orb.detectAndCompute(gray, None)
    k2, d2 = orb.detectAndCompute(view, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(d1, d2)
    src = np.float32([k1[m.queryIdx].pt for m in matches])
    dst = np.float32([k2[m.trainIdx].pt for m in matches])

    def prepare(backend_name):
        s, d = place(src, backend_name), place(dst, backend_name)
        return lambda: find_homography(s, d, backend=backend_name)

    def opencv():
        return lambda: cv2.findHomography(src, dst, cv2.RANSAC, 3.0)

    return [BenchCase("find_homography", f"{len(src)} ORB matches", (w, h), prepare, opencv,
                      bytes_moved=2 * src.nbytes + len(src) + 72)]
