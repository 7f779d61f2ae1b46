"""warpvx.cv.features2d: FAST, cornerHarris, cornerMinEigenVal, goodFeaturesToTrack (see warpvx.cv).

Same names, arguments and return values as ``cv2``; every function (and the detector factory)
also takes ``backend=`` as a keyword. Strided views are copied once (see :mod:`warpvx.cv`).
"""

from __future__ import annotations

import numpy as np

from .. import features
from ..arrays import as_input, is_warp_array, to_numpy
from ..check import check_array, check_choice, check_float, check_image, check_int
from ..errors import UnsupportedError, WarpvxTypeError
from ._arrays import contiguous
from ._fallback import function, method

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


def _host_mask(mask, shape):
    """``mask`` as a uint8 NumPy array of ``shape`` (HxW), or None."""
    if mask is None:
        return None
    m = check_array(contiguous(to_numpy(as_input(mask, "mask"))), "mask", shape=tuple(shape[:2]),
                    dtypes=(np.uint8,))
    return m.reshape(shape[:2])


def keep_in_mask(keypoints, mask, shape):
    """``keypoints`` (cv2.KeyPoint) whose rounded position is nonzero in ``mask`` (cv2's
    ``KeyPointsFilter::runByPixelsMask``); all of them when ``mask`` is None."""
    m = _host_mask(mask, shape)
    if m is None:
        return tuple(keypoints)
    return tuple(k for k in keypoints if m[int(k.pt[1] + 0.5), int(k.pt[0] + 0.5)])


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

    @method
    def detect(self, image, mask=None):
        """Keypoints as a tuple of ``cv2.KeyPoint``, in raster order (as cv2); with a uint8
        ``mask`` (HxW) only those where it is nonzero, as cv2.

        A colour image is converted with BGR2GRAY first (as cv2). Without NMS the response is
        0, as cv2 leaves it.
        """
        gray = _to_gray(image, self.backend)
        if self._type != FAST_FEATURE_DETECTOR_TYPE_9_16:
            raise UnsupportedError(f"type: only FAST_FEATURE_DETECTOR_TYPE_9_16 is accelerated, "
                                   f"got {self._type}")
        threshold = min(max(self._threshold, 0), 255)  # cv::FAST clamps it
        kps = features.fast_corners(gray, threshold, self._nonmax, backend=self.backend)
        host = kps.numpy()
        order = np.lexsort((host.x, host.y))
        host = host.take(order)
        if not self._nonmax:
            host.response = np.zeros_like(host.response)
        return keep_in_mask(host.to_cv(), mask, gray.shape)

    def _cv2_twin(self):
        import cv2

        return cv2.FastFeatureDetector_create(self._threshold, self._nonmax, self._type)

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
        self._type = check_choice(type, "type", (FAST_FEATURE_DETECTOR_TYPE_5_8,
                                                 FAST_FEATURE_DETECTOR_TYPE_7_12,
                                                 FAST_FEATURE_DETECTOR_TYPE_9_16))

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


@function
def cornerHarris(src, blockSize, ksize, k, dst=None, borderType=_REFLECT_101, *, backend=None):
    """cv2.cornerHarris for uint8 gray images (float32 map); BORDER_REFLECT_101 only."""
    _check_border(borderType)
    return features.harris_response(contiguous(src), blockSize, ksize, k, out=dst, backend=backend)


@function
def cornerMinEigenVal(src, blockSize, dst=None, ksize=3, borderType=_REFLECT_101, *,
                      backend=None):
    """cv2.cornerMinEigenVal for uint8 gray images (float32 map); BORDER_REFLECT_101 only."""
    _check_border(borderType)
    return features.harris_response(contiguous(src), blockSize, ksize, 0.0, score="min_eigen",
                                    out=dst, backend=backend)


@function
def goodFeaturesToTrack(image, maxCorners, qualityLevel, minDistance, corners=None, mask=None,
                        blockSize=3, useHarrisDetector=False, k=0.04, *, gradientSize=3,
                        backend=None):
    """cv2.goodFeaturesToTrack: float32 [N, 1, 2] (x, y), strongest first, or None when no
    corner is found (as cv2). Output kind follows the input (NumPy with a ``mask``).

    ``mask`` (uint8 HxW): as cv2, the quality threshold is taken from the strongest response
    inside it and only pixels where it is nonzero are corners (the 3x3 maxima are still taken
    over the whole map). The response map is computed on the backend, the selection on the host.
    """
    if corners is not None:
        raise UnsupportedError("corners: an output array is not supported; use the return value")
    score = check_choice(bool(useHarrisDetector), "useHarrisDetector",
                         {True: "harris", False: "min_eigen"})
    image = contiguous(image)
    if mask is not None:
        pts = _masked_corners(image, mask, maxCorners, qualityLevel, minDistance, blockSize, k,
                              gradientSize, score, backend)
    else:
        pts = features.harris_corners(image, maxCorners, qualityLevel, minDistance, blockSize, k,
                                      ksize=gradientSize, score=score, backend=backend)
    n = int(pts.shape[0])
    if n == 0:
        return None
    return pts.reshape((n, 1, 2)) if is_warp_array(pts) else pts.reshape(n, 1, 2)


def _masked_corners(image, mask, max_corners, quality_level, min_distance, block_size, k, ksize,
                    score, backend):
    """OpenCV's corner selection (featureselect.cpp) on the backend's response map, with a mask:
    float32 [N, 2] (x, y) on the host."""
    max_corners = check_int(max_corners, "maxCorners")
    quality_level = check_float(quality_level, "qualityLevel", min_value=0.0, strict_min=True)
    min_distance = check_float(min_distance, "minDistance", min_value=0.0)
    resp = to_numpy(features.harris_response(image, block_size, ksize, k, score=score,
                                             backend=backend)).reshape(image.shape[:2])
    m = _host_mask(mask, resp.shape).astype(bool)
    if not m.any():
        return np.zeros((0, 2), np.float32)
    thresholded = np.where(resp > np.float32(float(resp[m].max()) * quality_level), resp, 0)
    import cv2

    peaks = (thresholded != 0) & (thresholded == cv2.dilate(thresholded, None)) & m
    peaks[[0, -1], :] = False  # candidates lie 1 px inside the image, as OpenCV
    peaks[:, [0, -1]] = False
    ys, xs = np.nonzero(peaks)
    values = thresholded[ys, xs]
    order = np.lexsort((-(ys * resp.shape[1] + xs), -values))  # ties: later pixel first
    xs, ys = xs[order], ys[order]
    limit = len(xs) if max_corners <= 0 else min(int(max_corners), len(xs))
    if min_distance < 1:
        return np.stack([xs[:limit], ys[:limit]], 1).astype(np.float32)
    return _spread(xs, ys, limit, min_distance)


def _spread(xs, ys, limit, min_distance):
    """OpenCV's greedy min-distance pass over ranked candidates: cells ``round(min_distance)``
    wide, each candidate checked against kept ones in the 3x3 neighbouring cells."""
    cell = int(np.rint(min_distance))
    grid: dict = {}
    kept = []
    d2 = float(min_distance) ** 2
    for x, y in zip(xs.tolist(), ys.tolist()):
        cx, cy = x // cell, y // cell
        near = (p for gy in (cy - 1, cy, cy + 1) for gx in (cx - 1, cx, cx + 1)
                for p in grid.get((gx, gy), ()))
        if any((x - px) ** 2 + (y - py) ** 2 < d2 for px, py in near):
            continue
        grid.setdefault((cx, cy), []).append((x, y))
        kept.append((x, y))
        if len(kept) == limit:
            break
    return np.asarray(kept, np.float32).reshape(-1, 2)


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
