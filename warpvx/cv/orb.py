"""warpvx.cv.orb: ORB_create and a Hamming BFMatcher (see warpvx.cv).

Same names, arguments and return values as ``cv2``; the factories also take ``backend=`` as a
keyword. Strided views are copied once (see :mod:`warpvx.cv`). The ORB detector is OpenCV's
algorithm (Harris-ranked FAST per level, :mod:`warpvx.cv._orb_detect`) on warpvx primitives;
ORB-SLAM2's extractor stays :func:`warpvx.orb`.
"""

from __future__ import annotations

import numpy as np

from .. import matching
from ..backend import resolve_backend
from ..check import check_float, check_int
from ..errors import ShapeError, UnsupportedError, WarpvxTypeError, WarpvxValueError
from ..keypoints import Keypoints, check_keypoints
from ..orb_extractor import MAX_LEVELS
from . import _orb_detect, _orb_levels
from ._arrays import contiguous
from ._fallback import method
from .features2d import _host_mask, _to_gray

NORM_HAMMING = 6
NORM_HAMMING2 = 7
ORB_HARRIS_SCORE = _orb_detect.HARRIS_SCORE
ORB_FAST_SCORE = _orb_detect.FAST_SCORE
ORB_kHarrisScore = ORB_HARRIS_SCORE
ORB_kFastScore = ORB_FAST_SCORE

_CV_8U = 0


class ORB:
    """cv2.ORB look-alike: OpenCV's ORB algorithm on warpvx primitives.

    Detection is OpenCV's (:func:`warpvx.cv._orb_detect.detect`): per level, FAST at
    ``fastThreshold``, keypoints within ``edgeThreshold`` px of the level's border dropped,
    those where the level's ``mask`` is zero dropped, the best ``2 n_l`` by FAST score kept,
    then the best ``n_l`` by Harris score (``scoreType`` ORB_HARRIS_SCORE; ORB_FAST_SCORE keeps
    the best ``n_l`` by FAST score), n_l = ``nfeatures`` split over ``nlevels`` by
    ``scaleFactor``; angle by intensity centroid; rotated BRIEF (``WTA_K`` 2) on the level
    blurred 7x7, sigma 2 (:mod:`warpvx.cv._orb_levels`). OpenCV's arithmetic throughout
    (INTER_LINEAR_EXACT pyramid, integer Harris, float separable blur): keypoints equal cv2's
    (OpenCV 5.0; 7 real photos x 2 sizes, 12,000 keypoints) and so do descriptors, but for a
    float rounding now and then (cos/sin of the angle on ``cpu``: one bit of 12,000 descriptors;
    on Warp also the float32 blur: a few pixels of a photo, 3 descriptors). As cv2, ties at the
    cut-off score are all kept, so a level may hold a few more than n_l; keypoints come level by
    level, each level in raster order (cv2: the order ``nth_element`` leaves). ``compute``
    describes given keypoints the same way, on as many levels as their largest ``octave`` needs.

    ``WTA_K`` other than 2, ``firstLevel`` other than 0, ``patchSize`` other than 31 and
    ``cv2.UMat`` images run on cv2's ORB with the same parameters
    (:class:`warpvx.cv.CvFallbackWarning`, once).
    """

    def __init__(self, nfeatures=500, scaleFactor=1.2, nlevels=8, edgeThreshold=31,
                 firstLevel=0, WTA_K=2, scoreType=ORB_HARRIS_SCORE, patchSize=31,
                 fastThreshold=20, *, backend=None):
        self.setMaxFeatures(nfeatures)
        # cv2.ORB_create takes scaleFactor as a C float (setScaleFactor as a double).
        # Checked before the cast, so the error quotes the value given.
        scale = check_float(scaleFactor, "scaleFactor", min_value=1.0, strict_min=True,
                            max_value=float(np.finfo(np.float32).max))
        self.setScaleFactor(float(np.float32(scale)))
        self.setNLevels(nlevels)
        self.setEdgeThreshold(edgeThreshold)
        self.setFirstLevel(firstLevel)
        self.setWTA_K(WTA_K)
        self.setScoreType(scoreType)
        self.setPatchSize(patchSize)
        self.setFastThreshold(fastThreshold)
        self.backend = backend

    # --- Feature2D -------------------------------------------------------------------------

    @method
    def detect(self, image, mask=None):
        """Keypoints (tuple of cv2.KeyPoint); a colour image is converted BGR2GRAY as cv2."""
        return tuple(self._detect(image, mask)[2].to_cv())

    @method
    def compute(self, image, keypoints, descriptors=None):
        """(keypoints kept, uint8 [N, 32] or None when none): descriptors of given keypoints.

        As cv2: keypoints closer than ``edgeThreshold`` to the image border are dropped
        (``KeyPointsFilter::runByImageBorder``); the rest are described with their own
        ``angle`` on pyramid level ``octave``. ``keypoints`` None or empty gives ``((), None)``.
        """
        self._check_accelerated()
        gray = _to_gray(image, self.backend)
        kept = self._inside_border(gray, () if keypoints is None else keypoints)
        if not kept:
            return (), None
        kps = check_keypoints(Keypoints.from_cv(kept), n_levels=MAX_LEVELS)
        scales = _orb_detect.layer_scales(self._scale, int(kps.octave.max()) + 1)
        sizes = _orb_detect.level_sizes(int(gray.shape[1]), int(gray.shape[0]), scales)
        if min(min(s) for s in sizes) < 1:
            raise ShapeError(f"keypoints: octave {len(sizes) - 1} has no pyramid level in an "
                             f"image of {gray.shape[1]}x{gray.shape[0]} (WxH)")
        be = resolve_backend(self.backend, like=gray)
        levels = _orb_levels.exact_pyramid(_orb_detect.on_backend(gray, be), sizes)
        desc = _orb_detect.describe_keypoints(levels, kps, self._scale)
        return tuple(kept), self._host(desc, descriptors)

    @method
    def detectAndCompute(self, image, mask, descriptors=None, useProvidedKeypoints=False):
        """(tuple of cv2.KeyPoint, uint8 [N, 32] or None when none). ``mask``: uint8 HxW or
        None; as cv2, each pyramid level is masked by its resized copy (only 255 kept)."""
        if useProvidedKeypoints:
            raise UnsupportedError("useProvidedKeypoints: use compute(image, keypoints) instead")
        _, levels, kps = self._detect(image, mask)
        if len(kps) == 0:
            return (), None
        desc = _orb_detect.describe_keypoints(levels, kps, self._scale)
        return tuple(kps.to_cv()), self._host(desc, descriptors)

    def write(self, fs, name=None):
        """cv2's Algorithm.write (FileStorage), through an equivalent cv2.ORB."""
        twin = self._cv2_twin()
        return twin.write(fs) if name is None else twin.write(fs, name)

    def read(self, node):
        """cv2's Algorithm.read: the parameters from a FileNode written by ``write``."""
        twin = self._cv2_twin()
        twin.read(node)
        self._set_all(twin)

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
        self._first = check_int(firstLevel, "firstLevel", min_value=0)

    def getFirstLevel(self):
        return self._first

    def setWTA_K(self, wta_k):
        self._wta_k = check_int(wta_k, "WTA_K", min_value=2, max_value=4)

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
        self._patch = check_int(patchSize, "patchSize", min_value=2)

    def getPatchSize(self):
        return self._patch

    def setFastThreshold(self, fastThreshold):
        self._fast = check_int(fastThreshold, "fastThreshold", min_value=0, max_value=255)

    def getFastThreshold(self):
        return self._fast

    # --- helpers ---------------------------------------------------------------------------

    _PARAMS = ("MaxFeatures", "ScaleFactor", "NLevels", "EdgeThreshold", "FirstLevel", "WTA_K",
               "ScoreType", "PatchSize", "FastThreshold")

    def _cv2_twin(self):
        """A cv2.ORB with these parameters (what calls warpvx does not accelerate run on)."""
        import cv2

        twin = cv2.ORB_create()
        for p in self._PARAMS:
            getattr(twin, "set" + p)(getattr(self, "get" + p)())
        return twin

    def _set_all(self, other):
        """Copy every parameter from ``other`` (a cv2.ORB) into self."""
        for p in self._PARAMS:
            getattr(self, "set" + p)(getattr(other, "get" + p)())

    def _check_accelerated(self):
        for name, value, accelerated in (("WTA_K", self._wta_k, 2), ("firstLevel", self._first, 0),
                                         ("patchSize", self._patch, 31)):
            if value != accelerated:
                raise UnsupportedError(f"{name}: only {accelerated} is accelerated, got {value}")

    def _detect(self, image, mask):
        """(gray image, pyramid levels, host Keypoints): OpenCV's ORB detection with these
        parameters."""
        self._check_accelerated()
        gray = _to_gray(image, self.backend)
        levels, kps = _orb_detect.detect(gray, self._nfeatures, self._scale, self._nlevels,
                                         self._edge, self._score_type, self._fast,
                                         _host_mask(mask, gray.shape), backend=self.backend)
        return gray, levels, kps

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
    """cv2.ORB_create: OpenCV's ORB on warpvx primitives; see :class:`ORB`."""
    return ORB(nfeatures, scaleFactor, nlevels, edgeThreshold, firstLevel, WTA_K, scoreType,
               patchSize, fastThreshold, backend=backend)


def _dmatch(q, t, img, d):
    import cv2

    return cv2.DMatch(int(q), int(t), int(img), float(d))


class BFMatcher:
    """cv2.BFMatcher for NORM_HAMMING over :func:`warpvx.match_hamming` (brute force).

    Train descriptors are given to ``match``/``knnMatch`` or added with ``add`` (then matches
    carry ``imgIdx``, as cv2). Other norms, masks, ``k`` above 2, ``knnMatch`` with
    ``crossCheck`` and ``cv2.UMat`` descriptors run on cv2's BFMatcher (with the same train
    set; :class:`warpvx.cv.CvFallbackWarning`, once).
    """

    def __init__(self, normType=NORM_HAMMING, crossCheck=False, *, backend=None):
        if isinstance(normType, bool) or not isinstance(normType, (int, np.integer)):
            raise WarpvxTypeError(f"normType: expected an integer, got {normType!r}")
        self.normType = int(normType)
        self.crossCheck = bool(crossCheck)
        self.backend = backend
        self._train = []

    @method
    def match(self, queryDescriptors, trainDescriptors=None, mask=None):
        """Best match per query (tuple of cv2.DMatch in query order, as cv2); with crossCheck
        only the mutual best ones."""
        train, images = self._train_set(trainDescriptors, mask)
        pairs, dist = matching.match_hamming(contiguous(queryDescriptors), train, self.crossCheck,
                                             backend=self.backend)
        pairs = pairs if isinstance(pairs, np.ndarray) else pairs.numpy()
        dist = dist if isinstance(dist, np.ndarray) else dist.numpy()
        return tuple(_dmatch(q, *images(t), d) for (q, t), d in zip(pairs, dist))

    @method
    def knnMatch(self, queryDescriptors, trainDescriptors=None, k=2, mask=None,
                 compactResult=False):
        """The k (1 or 2) nearest per query, nearest first: a tuple of tuples of cv2.DMatch."""
        if self.crossCheck:
            raise UnsupportedError("crossCheck: knnMatch with crossCheck=True is not accelerated")
        train, images = self._train_set(trainDescriptors, mask)
        idx, dist = matching.knn_match_hamming(contiguous(queryDescriptors), train, k,
                                               backend=self.backend)
        idx = idx if isinstance(idx, np.ndarray) else idx.numpy()
        dist = dist if isinstance(dist, np.ndarray) else dist.numpy()
        return tuple(tuple(_dmatch(q, *images(t), d) for t, d in zip(idx[q], dist[q]))
                     for q in range(idx.shape[0]))

    def add(self, descriptors):
        """Append train descriptor sets (a list of uint8 [N, 32]), as cv2's ``add``."""
        if not isinstance(descriptors, (list, tuple)):
            raise WarpvxTypeError(f"descriptors: expected a list of arrays, got "
                                  f"{type(descriptors).__name__}")
        self._train.extend(descriptors)

    def getTrainDescriptors(self):
        return tuple(self._train)

    def clear(self):
        self._train = []

    def train(self):
        """Nothing to build for brute force (as cv2)."""

    def empty(self):
        return len(self._train) == 0

    def isMaskSupported(self):
        return True

    def getDefaultName(self):
        return "DescriptorMatcher.BFMatcher"

    def _cv2_twin(self):
        import cv2

        twin = cv2.BFMatcher(self.normType, self.crossCheck)
        if self._train:
            twin.add(list(self._train))
        return twin

    def _train_set(self, train, mask):
        """(train descriptors, index -> (trainIdx, imgIdx)) for a match call."""
        if self.normType != NORM_HAMMING:
            raise UnsupportedError(f"normType: only NORM_HAMMING ({NORM_HAMMING}) is "
                                   f"accelerated, got {self.normType}")
        if mask is not None and (not isinstance(mask, (list, tuple)) or len(mask)):
            raise UnsupportedError("mask: match masks are not accelerated")
        if train is not None:
            return contiguous(train), lambda t: (t, 0)
        if not self._train:
            raise WarpvxValueError("trainDescriptors: none given and none added")
        sets = [np.asarray(contiguous(d)) for d in self._train]
        starts = np.cumsum([0] + [len(d) for d in sets])

        def images(t):
            img = int(np.searchsorted(starts, t, side="right")) - 1
            return t - starts[img], img

        return np.concatenate(sets), images


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
