"""warpvx.cv.features2d: FAST, cornerHarris, cornerMinEigenVal, goodFeaturesToTrack (see warpvx.cv).

Same names, arguments and return values as ``cv2``; every function (and the detector factory)
also takes ``backend=`` as a keyword. Strided views are copied once (see :mod:`warpvx.cv`).
"""

from __future__ import annotations

import numpy as np

from .. import features
from ..arrays import as_input, is_warp_array
from ..check import check_choice, check_image
from ..errors import UnsupportedError, WarpvxTypeError
from ._arrays import contiguous

FAST_FEATURE_DETECTOR_TYPE_5_8 = 0
FAST_FEATURE_DETECTOR_TYPE_7_12 = 1
FAST_FEATURE_DETECTOR_TYPE_9_16 = 2
FastFeatureDetector_TYPE_5_8 = FAST_FEATURE_DETECTOR_TYPE_5_8
FastFeatureDetector_TYPE_7_12 = FAST_FEATURE_DETECTOR_TYPE_7_12
FastFeatureDetector_TYPE_9_16 = FAST_FEATURE_DETECTOR_TYPE_9_16

# Border types accepted by the corner functions: BORDER_REFLECT_101 (= BORDER_DEFAULT), with
# or without BORDER_ISOLATED (which changes nothing for a whole image).
_REFLECT_101 = 4
_ISOLATED = 16


def _check_type(type_) -> int:
    if type_ != FAST_FEATURE_DETECTOR_TYPE_9_16:
        raise UnsupportedError(
            f"type: only FAST_FEATURE_DETECTOR_TYPE_9_16 ({FAST_FEATURE_DETECTOR_TYPE_9_16}) is "
            f"supported, got {type_!r}"
        )
    return int(type_)


def _check_mask(mask) -> None:
    if mask is not None:
        raise UnsupportedError("mask: masks are not supported; pass None")


def _check_border(border_type) -> None:
    ok = isinstance(border_type, (int, np.integer)) and not isinstance(border_type, bool)
    if not ok or (int(border_type) & ~_ISOLATED) != _REFLECT_101:
        raise UnsupportedError(
            f"borderType: only BORDER_DEFAULT / BORDER_REFLECT_101 ({_REFLECT_101}) is "
            f"supported, got {border_type!r}"
        )


def _to_gray(image, backend):
    """cv2's FastFeatureDetector converts a non-8UC1 image with COLOR_BGR2GRAY."""
    arr = as_input(contiguous(image), "image")
    if len(arr.shape) == 3 and arr.shape[2] in (3, 4):
        arr = check_image(arr, "image", dtypes=(np.uint8,), channels=(3, 4))
        code = "BGR2GRAY" if arr.shape[2] == 3 else "BGRA2GRAY"
        if isinstance(arr, np.ndarray):
            import cv2

            flag = cv2.COLOR_BGR2GRAY if code == "BGR2GRAY" else cv2.COLOR_BGRA2GRAY
            return cv2.cvtColor(arr, flag)
        from ..color import color_convert

        return color_convert(arr, code, backend=backend)
    return arr


class FastFeatureDetector:
    """cv2.FastFeatureDetector look-alike over :func:`warpvx.fast_corners`."""

    def __init__(self, threshold=10, nonmaxSuppression=True, type=FAST_FEATURE_DETECTOR_TYPE_9_16,
                 *, backend=None):
        self.setThreshold(threshold)
        self.setNonmaxSuppression(nonmaxSuppression)
        self.setType(type)
        self.backend = backend

    def detect(self, image, mask=None):
        """Keypoints as a tuple of ``cv2.KeyPoint``, in raster order (as cv2).

        A colour image is converted with BGR2GRAY first (as cv2). Without NMS the response is
        0, as cv2 leaves it.
        """
        _check_mask(mask)
        gray = _to_gray(image, self.backend)
        threshold = min(max(self._threshold, 0), 255)  # cv::FAST clamps it
        kps = features.fast_corners(gray, threshold, self._nonmax, backend=self.backend)
        host = kps.numpy()
        order = np.lexsort((host.x, host.y))
        host = host.take(order)
        if not self._nonmax:
            host.response = np.zeros_like(host.response)
        return tuple(host.to_cv())

    def setThreshold(self, threshold):
        if isinstance(threshold, bool) or not isinstance(threshold, (int, np.integer)):
            raise WarpvxTypeError(f"threshold: expected an integer, got {threshold!r}")
        self._threshold = int(threshold)

    def getThreshold(self):
        return self._threshold

    def setNonmaxSuppression(self, f):
        self._nonmax = bool(f)

    def getNonmaxSuppression(self):
        return self._nonmax

    def setType(self, type):
        self._type = _check_type(type)

    def getType(self):
        return self._type

    def getDefaultName(self):
        return "Feature2D.FastFeatureDetector"

    def empty(self):
        return False


def FastFeatureDetector_create(threshold=10, nonmaxSuppression=True,
                               type=FAST_FEATURE_DETECTOR_TYPE_9_16, *, backend=None):
    """cv2.FastFeatureDetector_create (FAST-9/16 only); the threshold is clamped to [0, 255]
    at ``detect``, as cv2 does."""
    return FastFeatureDetector(threshold, nonmaxSuppression, type, backend=backend)


def cornerHarris(src, blockSize, ksize, k, dst=None, borderType=_REFLECT_101, *, backend=None):
    """cv2.cornerHarris for uint8 gray images (float32 map); BORDER_REFLECT_101 only."""
    _check_border(borderType)
    return features.harris_response(contiguous(src), blockSize, ksize, k, out=dst, backend=backend)


def cornerMinEigenVal(src, blockSize, dst=None, ksize=3, borderType=_REFLECT_101, *,
                      backend=None):
    """cv2.cornerMinEigenVal for uint8 gray images (float32 map); BORDER_REFLECT_101 only."""
    _check_border(borderType)
    return features.harris_response(contiguous(src), blockSize, ksize, 0.0, score="min_eigen",
                                    out=dst, backend=backend)


def goodFeaturesToTrack(image, maxCorners, qualityLevel, minDistance, corners=None, mask=None,
                        blockSize=3, useHarrisDetector=False, k=0.04, *, gradientSize=3,
                        backend=None):
    """cv2.goodFeaturesToTrack: float32 [N, 1, 2] (x, y), strongest first, or None when no
    corner is found (as cv2). Masks are not supported. Output kind follows the input."""
    _check_mask(mask)
    if corners is not None:
        raise UnsupportedError("corners: an output array is not supported; use the return value")
    score = check_choice(bool(useHarrisDetector), "useHarrisDetector",
                         {True: "harris", False: "min_eigen"})
    pts = features.harris_corners(contiguous(image), maxCorners, qualityLevel, minDistance, blockSize, k,
                                  ksize=gradientSize, score=score, backend=backend)
    n = int(pts.shape[0])
    if n == 0:
        return None
    return pts.reshape((n, 1, 2)) if is_warp_array(pts) else pts.reshape(n, 1, 2)


__all__ = [
    "FAST_FEATURE_DETECTOR_TYPE_5_8",
    "FAST_FEATURE_DETECTOR_TYPE_7_12",
    "FAST_FEATURE_DETECTOR_TYPE_9_16",
    "FastFeatureDetector_TYPE_5_8",
    "FastFeatureDetector_TYPE_7_12",
    "FastFeatureDetector_TYPE_9_16",
    "FastFeatureDetector",
    "FastFeatureDetector_create",
    "cornerHarris",
    "cornerMinEigenVal",
    "goodFeaturesToTrack",
]
