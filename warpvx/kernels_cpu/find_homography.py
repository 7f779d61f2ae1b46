"""RANSAC homography on OpenCV (``cv2.findHomography(..., cv2.RANSAC)``)."""

from __future__ import annotations

import cv2
import numpy as np

MIN_SPREAD_RATIO = 1e-6  # smaller/larger singular value of centred points under which they are collinear


def find_homography(src: np.ndarray, dst: np.ndarray, ransac_reproj_threshold: float,
                    max_iters: int, confidence: float, seed: int, *, out=None) -> tuple:
    """(float64 [3, 3] H, uint8 [N] mask) of float32/float64 [N, 2] points, N >= 4.

    OpenCV's RANSAC, then its DLT refit and Levenberg-Marquardt refinement on the inliers;
    the mask is RANSAC's. OpenCV draws its samples from a generator of its own with a fixed
    seed, so the result is deterministic and ``seed`` is not used (nor is the global
    ``cv2.setRNGSeed`` state). No model (OpenCV returns None, or its inliers are fewer than
    4 distinct points or lie on one line in either image, where OpenCV may still return a
    matrix): H zeros, mask all 0. ``out``: optional (H, mask) arrays to fill.
    """
    h, mask = cv2.findHomography(src, dst, cv2.RANSAC, ransac_reproj_threshold,
                                 maxIters=max_iters, confidence=confidence)
    h_out, mask_out = out if out is not None else (np.empty((3, 3), np.float64),
                                                   np.empty(src.shape[0], np.uint8))
    inliers = None if mask is None else mask.reshape(-1) != 0
    if (h is None or not np.all(np.isfinite(h)) or not _general_position(src[inliers])
            or not _general_position(dst[inliers])):
        h_out[...] = 0.0
        mask_out[...] = 0
    else:
        h_out[...] = h
        mask_out[...] = inliers
    return h_out, mask_out


def _general_position(pts: np.ndarray) -> bool:
    """At least 4 distinct points, not all on one line (to a relative 1e-6)."""
    if len(np.unique(pts, axis=0)) < 4:
        return False
    centred = pts.astype(np.float64) - pts.mean(axis=0, dtype=np.float64)
    sv = np.linalg.svd(centred, compute_uv=False)
    return bool(sv[1] > MIN_SPREAD_RATIO * sv[0])


__all__ = ["find_homography"]
