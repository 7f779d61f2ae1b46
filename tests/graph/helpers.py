"""Helpers shared by the graph tests."""

from __future__ import annotations

import cv2
import numpy as np


def homography(prev_pts, next_pts, status):
    """The RANSAC homography of the points tracked (``status == 1``), the identity when fewer
    than 8 were tracked or OpenCV finds none: the user node of the parity graphs."""
    ok = status.reshape(-1) == 1
    if ok.sum() < 8:
        return np.eye(3)
    H, _ = cv2.findHomography(prev_pts[ok], next_pts[ok], cv2.RANSAC, 3.0)
    return np.eye(3) if H is None else H
