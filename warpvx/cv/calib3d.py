"""warpvx.cv.calib3d: ``cv2.findHomography`` with cv2's names, arguments and return values
for ``method=RANSAC`` (see warpvx.cv; other methods and a given ``mask`` go to cv2)."""

from __future__ import annotations

import cv2 as _cv2
import numpy as np

from ..arrays import to_numpy
from ..homography import find_homography
from ._arrays import contiguous
from ._fallback import function

_DEFAULT_THRESHOLD = 3.0  # what cv2 uses for a threshold <= 0


@function
def findHomography(srcPoints, dstPoints, method=0, ransacReprojThreshold=3.0, mask=None,
                   maxIters=2000, confidence=0.995, *, backend=None):
    """``cv2.findHomography``: returns (H float64 3x3 or None, mask uint8 [N, 1]).

    ``method=RANSAC`` runs :func:`warpvx.find_homography` (seed 0); no model gives
    ``(None, zeros)`` as cv2. Other methods (0, LMEDS, RHO, USAC_*) and an output ``mask``
    array are cv2's own. Points as cv2 takes them: [N, 2] or [N, 1, 2] float32/float64
    (integer points are converted to float32).
    """
    if method != _cv2.RANSAC or mask is not None:
        return _cv2.findHomography(srcPoints, dstPoints, method, ransacReprojThreshold, mask,
                                   maxIters, confidence)
    src, dst = (_float_points(p) for p in (srcPoints, dstPoints))
    threshold = ransacReprojThreshold if ransacReprojThreshold > 0 else _DEFAULT_THRESHOLD
    h, inliers = find_homography(src, dst, ransac_reproj_threshold=threshold, max_iters=maxIters,
                                 confidence=confidence, backend=backend)
    h, inliers = to_numpy(h), to_numpy(inliers)
    inliers = inliers.reshape(-1, 1)
    if h[2, 2] == 0:  # warpvx's "no model"
        return None, inliers
    return h, inliers


def _float_points(p):
    p = contiguous(p)
    if isinstance(p, (list, tuple)):
        p = np.asarray(p, np.float32)
    if isinstance(p, np.ndarray) and p.dtype not in (np.float32, np.float64):
        p = p.astype(np.float32)
    return p


__all__ = ["findHomography"]
