"""warpvx.cv.orb: ORB_create and a Hamming BFMatcher (see warpvx.cv).

Same names, arguments and return values as ``cv2``; the factories also take ``backend=`` as a
keyword. Strided views are copied once (see :mod:`warpvx.cv`). The ORB detector extracts
ORB-SLAM2's way (:func:`warpvx.orb`), not OpenCV's, but returns at most ``nfeatures`` as cv2.
"""

from __future__ import annotations

import numpy as np

from .. import matching, orb_extractor
from ..check import check_float, check_int
from ..errors import UnsupportedError, WarpvxTypeError
from ..keypoints import Keypoints
from ._arrays import contiguous
from .features2d import _check_mask, _to_gray

NORM_HAMMING = 6
NORM_HAMMING2 = 7
ORB_HARRIS_SCORE = 0
ORB_FAST_SCORE = 1
ORB_kHarrisScore = ORB_HARRIS_SCORE
ORB_kFastScore = ORB_FAST_SCORE

_CV_8U = 0
# ORB-SLAM2's per-cell fallback FAST threshold.
_MIN_TH_FAST = 7


class ORB:
    """cv2.ORB look-alike over :func:`warpvx.orb` (ORB-SLAM2's extractor).

    Differences from cv2's ORB, by design: keypoints come from ORB-SLAM2's extractor (FAST per
    30x30 cell at ``fastThreshold``, falling back to threshold 7 in a cell that has no corner,
    then the quadtree spread); keypoints are ranked by FAST score whatever ``scoreType``. As
    cv2, ``detect``/``detectAndCompute`` return at most ``nfeatures``: where ORB-SLAM2's
    quadtree over-shoots (:func:`warpvx.orb` may return a few more), the strongest by
    ``response`` are kept, in extraction order (ties keep the earlier one). ``edgeThreshold``
    only sets the border ``compute`` drops keypoints within (detection keeps ORB-SLAM2's
    19 px). ``WTA_K`` other than 2, ``firstLevel`` other than 0, ``patchSize`` other than 31
    and masks raise :class:`warpvx.UnsupportedError`.
    """

    def __init__(self, nfeatures=500, scaleFactor=1.2, nlevels=8, edgeThreshold=31,
                 firstLevel=0, WTA_K=2, scoreType=ORB_HARRIS_SCORE, patchSize=31,
                 fastThreshold=20, *, backend=None):
        self.setMaxFeatures(nfeatures)
        self.setScaleFactor(scaleFactor)
        self.setNLevels(nlevels)
        self.setEdgeThreshold(edgeThreshold)
        self.setFirstLevel(firstLevel)
        self.setWTA_K(WTA_K)
        self.setScoreType(scoreType)
        self.setPatchSize(patchSize)
        self.setFastThreshold(fastThreshold)
        self.backend = backend

    # --- Feature2D -------------------------------------------------------------------------

    def detect(self, image, mask=None):
        """Keypoints (tuple of cv2.KeyPoint); a colour image is converted BGR2GRAY as cv2."""
        _check_mask(mask)
        kps, _ = self._extract(image)
        return tuple(kps.to_cv())

    def compute(self, image, keypoints, descriptors=None):
        """(keypoints kept, uint8 [N, 32] or None when none): descriptors of given keypoints.

        As cv2: keypoints closer than ``edgeThreshold`` to the image border are dropped
        (``KeyPointsFilter::runByImageBorder``); the rest are described with their own
        ``angle`` on pyramid level ``octave``. ``keypoints`` None or empty gives ``((), None)``.
        """
        gray = _to_gray(image, self.backend)
        kept = self._inside_border(gray, () if keypoints is None else keypoints)
        if not kept:
            return (), None
        desc = orb_extractor.orb_compute(gray, Keypoints.from_cv(kept), self._scale,
                                         backend=self.backend)
        return tuple(kept), self._host(desc, descriptors)

    def detectAndCompute(self, image, mask, descriptors=None, useProvidedKeypoints=False):
        """(tuple of cv2.KeyPoint, uint8 [N, 32] or None when none)."""
        _check_mask(mask)
        if useProvidedKeypoints:
            raise UnsupportedError("useProvidedKeypoints: use compute(image, keypoints) instead")
        kps, desc = self._extract(image)
        if len(kps) == 0:
            return (), None
        return tuple(kps.to_cv()), self._host(desc, descriptors)

    def descriptorSize(self):
        return 32

    def descriptorType(self):
        return _CV_8U

    def defaultNorm(self):
        return NORM_HAMMING

    def getDefaultName(self):
        return "Feature2D.ORB"

    def empty(self):
        return False

    # --- parameters ------------------------------------------------------------------------

    def setMaxFeatures(self, maxFeatures):
        self._nfeatures = check_int(maxFeatures, "nfeatures", min_value=1)

    def getMaxFeatures(self):
        return self._nfeatures

    def setScaleFactor(self, scaleFactor):
        self._scale = check_float(scaleFactor, "scaleFactor", min_value=1.0, strict_min=True)

    def getScaleFactor(self):
        return self._scale

    def setNLevels(self, nlevels):
        self._nlevels = check_int(nlevels, "nlevels", min_value=1)

    def getNLevels(self):
        return self._nlevels

    def setEdgeThreshold(self, edgeThreshold):
        self._edge = check_int(edgeThreshold, "edgeThreshold", min_value=0)

    def getEdgeThreshold(self):
        return self._edge

    def setFirstLevel(self, firstLevel):
        if check_int(firstLevel, "firstLevel") != 0:
            raise UnsupportedError(f"firstLevel: only 0 is supported, got {firstLevel}")
        self._first = 0

    def getFirstLevel(self):
        return self._first

    def setWTA_K(self, wta_k):
        if check_int(wta_k, "WTA_K") != 2:
            raise UnsupportedError(f"WTA_K: only 2 (pairwise BRIEF tests) is supported, got "
                                   f"{wta_k}")
        self._wta_k = 2

    def getWTA_K(self):
        return self._wta_k

    def setScoreType(self, scoreType):
        if scoreType not in (ORB_HARRIS_SCORE, ORB_FAST_SCORE) or isinstance(scoreType, bool):
            raise UnsupportedError(f"scoreType: expected ORB_HARRIS_SCORE or ORB_FAST_SCORE, got "
                                   f"{scoreType!r}")
        self._score_type = int(scoreType)

    def getScoreType(self):
        return self._score_type

    def setPatchSize(self, patchSize):
        if check_int(patchSize, "patchSize") != 31:
            raise UnsupportedError(f"patchSize: only 31 (the pattern's patch) is supported, got "
                                   f"{patchSize}")
        self._patch = 31

    def getPatchSize(self):
        return self._patch

    def setFastThreshold(self, fastThreshold):
        self._fast = check_int(fastThreshold, "fastThreshold", min_value=0, max_value=255)

    def getFastThreshold(self):
        return self._fast

    # --- helpers ---------------------------------------------------------------------------

    def _extract(self, image):
        """Host keypoints and descriptors (NumPy uint8 [N, 32]), at most ``nfeatures``."""
        gray = _to_gray(image, self.backend)
        kps, desc = orb_extractor.orb(gray, self._nfeatures, self._scale, self._nlevels,
                                      self._fast, _MIN_TH_FAST, backend=self.backend)
        kps = kps.to("host")
        desc = desc if isinstance(desc, np.ndarray) else desc.numpy()
        if len(kps) > self._nfeatures:
            keep = np.sort(np.argsort(-kps.response, kind="stable")[:self._nfeatures])
            kps, desc = kps.take(keep), desc[keep]
        return kps, desc

    def _inside_border(self, gray, keypoints) -> list:
        kps = list(keypoints)
        for k in kps[:1]:
            if not hasattr(k, "pt"):
                raise WarpvxTypeError(f"keypoints: expected cv2.KeyPoint items, got "
                                      f"{type(k).__name__}")
        h, w = int(gray.shape[0]), int(gray.shape[1])
        b = self._edge
        if b <= 0:
            return kps
        if h <= 2 * b or w <= 2 * b:
            return []
        return [k for k in kps if b <= k.pt[0] < w - b and b <= k.pt[1] < h - b]

    @staticmethod
    def _host(desc, dst):
        host = desc if isinstance(desc, np.ndarray) else desc.numpy()
        if dst is not None and isinstance(dst, np.ndarray) and dst.shape == host.shape:
            np.copyto(dst, host)
            return dst
        return host


def ORB_create(nfeatures=500, scaleFactor=1.2, nlevels=8, edgeThreshold=31, firstLevel=0,
               WTA_K=2, scoreType=ORB_HARRIS_SCORE, patchSize=31, fastThreshold=20, *,
               backend=None):
    """cv2.ORB_create, extracting ORB-SLAM2's way (FAST threshold 7 as the per-cell fallback);
    see :class:`ORB`."""
    return ORB(nfeatures, scaleFactor, nlevels, edgeThreshold, firstLevel, WTA_K, scoreType,
               patchSize, fastThreshold, backend=backend)


def _dmatch(q, t, d):
    import cv2

    return cv2.DMatch(int(q), int(t), 0, float(d))


class BFMatcher:
    """cv2.BFMatcher for NORM_HAMMING over :func:`warpvx.match_hamming` (brute force)."""

    def __init__(self, normType=NORM_HAMMING, crossCheck=False, *, backend=None):
        if isinstance(normType, bool) or normType != NORM_HAMMING:
            raise UnsupportedError(f"normType: only NORM_HAMMING ({NORM_HAMMING}) is supported, "
                                   f"got {normType!r}")
        self.crossCheck = bool(crossCheck)
        self.backend = backend

    def match(self, queryDescriptors, trainDescriptors, mask=None):
        """Best match per query (tuple of cv2.DMatch in query order, as cv2); with crossCheck
        only the mutual best ones."""
        _check_mask(mask)
        pairs, dist = matching.match_hamming(contiguous(queryDescriptors),
                                             contiguous(trainDescriptors), self.crossCheck,
                                             backend=self.backend)
        pairs = pairs if isinstance(pairs, np.ndarray) else pairs.numpy()
        dist = dist if isinstance(dist, np.ndarray) else dist.numpy()
        return tuple(_dmatch(q, t, d) for (q, t), d in zip(pairs, dist))

    def knnMatch(self, queryDescriptors, trainDescriptors, k=2, mask=None, compactResult=False):
        """The k (1 or 2) nearest per query, nearest first: a tuple of tuples of cv2.DMatch."""
        _check_mask(mask)
        if self.crossCheck:
            raise UnsupportedError("crossCheck: knnMatch with crossCheck=True is not supported")
        idx, dist = matching.knn_match_hamming(contiguous(queryDescriptors),
                                               contiguous(trainDescriptors), k,
                                               backend=self.backend)
        idx = idx if isinstance(idx, np.ndarray) else idx.numpy()
        dist = dist if isinstance(dist, np.ndarray) else dist.numpy()
        return tuple(tuple(_dmatch(q, t, d) for t, d in zip(idx[q], dist[q]))
                     for q in range(idx.shape[0]))

    def getDefaultName(self):
        return "DescriptorMatcher.BFMatcher"

    def empty(self):
        return False

    def isMaskSupported(self):
        return False


def BFMatcher_create(normType=NORM_HAMMING, crossCheck=False, *, backend=None):
    """cv2.BFMatcher_create (NORM_HAMMING only)."""
    return BFMatcher(normType, crossCheck, backend=backend)


__all__ = [
    "NORM_HAMMING",
    "NORM_HAMMING2",
    "ORB_HARRIS_SCORE",
    "ORB_FAST_SCORE",
    "ORB_kHarrisScore",
    "ORB_kFastScore",
    "ORB",
    "ORB_create",
    "BFMatcher",
    "BFMatcher_create",
]
