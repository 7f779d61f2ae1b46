"""FAST-9/16 corners on the CPU: OpenCV's detector, plus scores without NMS, sorted."""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import UnsupportedError
from ..keypoints import Keypoints

# The FAST-9/16 circle in OpenCV's order, (dx, dy).
CIRCLE = np.array([(0, 3), (1, 3), (2, 2), (3, 1), (3, 0), (3, -1), (2, -2), (1, -3),
                   (0, -3), (-1, -3), (-2, -2), (-3, -1), (-3, 0), (-3, 1), (-2, 2), (-1, 3)])


def _arc_min(d: np.ndarray) -> np.ndarray:
    """Minimum over each cyclic arc of 9 (arc starting at column k), by doubling."""
    m2 = np.minimum(d, np.roll(d, -1, axis=1))
    m4 = np.minimum(m2, np.roll(m2, -2, axis=1))
    m8 = np.minimum(m4, np.roll(m4, -4, axis=1))
    return np.minimum(m8, np.roll(d, -8, axis=1))


def fast_scores(src: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """OpenCV's FAST-9/16 score of corners at (x, y) (3 px inside ``src``).

    cornerScore<16> equals ``max(A, B) - 1`` for a corner, where A (B) is the best over the 16
    arcs of 9 contiguous circle pixels of the arc's smallest ``centre - p`` (``p - centre``).
    """
    v = src[y, x].astype(np.int16)[:, None]
    ring = src[y[:, None] + CIRCLE[None, :, 1], x[:, None] + CIRCLE[None, :, 0]]
    d = v - ring.astype(np.int16)  # [N, 16]
    best = np.maximum(_arc_min(d).max(axis=1), _arc_min(-d).max(axis=1))
    return (best - 1).astype(np.float32)


def fast_corners(src: np.ndarray, threshold: int, nonmax: bool, *, out=None) -> Keypoints:
    """FAST-9/16 keypoints of a gray uint8 image, sorted by (score desc, y, x).

    OpenCV finds the corners; their scores are recomputed here in NumPy (equal to OpenCV's
    with NMS, and reported too without NMS, where cv2 leaves the response 0), which avoids a
    Python loop over ``cv2.KeyPoint`` objects.

    ``out`` is refused: the keypoint count depends on the data.
    """
    if out is not None:
        raise UnsupportedError("out: fast_corners returns a data-dependent number of keypoints; "
                               "it takes no out=")
    detector = cv2.FastFeatureDetector_create(int(threshold), bool(nonmax),
                                              cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)
    found = detector.detect(src)
    if len(found) == 0:
        return Keypoints.empty()
    pts = cv2.KeyPoint_convert(found).reshape(-1, 2)
    x = pts[:, 0].astype(np.intp)
    y = pts[:, 1].astype(np.intp)
    response = fast_scores(src, x, y)
    order = np.lexsort((x, y, -response))
    return Keypoints.from_arrays(x[order], y[order], response=response[order])
