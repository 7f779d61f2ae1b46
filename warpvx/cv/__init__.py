"""OpenCV-compatible drop-ins: ``from warpvx import cv as cv2``.

Same names, argument order, constants and return types as ``cv2`` for the accelerated subset:
imgproc (colour, geometric transforms), pyramids (pyrDown, resize, GaussianBlur), features2d
(FAST, Harris, goodFeaturesToTrack), orb (ORB, BFMatcher), video (pyramidal LK), calib3d
(findHomography with RANSAC). Every
accelerated function also takes ``backend=`` as a keyword. A call with a code, flag, dtype or
``cv2.UMat`` the subset does not cover runs on cv2 itself, with one
:class:`CvFallbackWarning` per function and argument (see :mod:`warpvx.cv._fallback`); input
cv2 rejects too raises warpvx's error naming the argument.

Every other name falls through to ``cv2`` itself (``cv.imread``, ``cv.getPerspectiveTransform``,
``cv.KeyPoint``, ``cv.error``, ``cv.COLOR_BGR2HSV``...), so a working OpenCV script keeps
working: ``getattr`` and ``dir()`` see both, warpvx's names first (``from warpvx.cv import *``
imports only warpvx's own).

Arrays are taken as OpenCV takes them: a strided NumPy view (an ROI slice ``img[y0:y1, x0:x1]``,
a channel flip ``bgr[:, :, ::-1]``, a column of points) is copied once into a C-contiguous array
before the call (and so is a strided ``wp.array``); a strided ``dst`` of the right shape and
dtype is written through, as cv2 writes into views. ``remap`` also takes cv2's fixed-point
maps (CV_16SC2 with an optional interpolation table, from ``cv2.convertMaps``).
"""

import cv2 as _cv2

from ._fallback import CvFallbackWarning  # noqa: F401

from .imgproc import *  # noqa: F401,F403
from .pyramids import *  # noqa: F401,F403
from .features2d import *  # noqa: F401,F403
from .video import *  # noqa: F401,F403
from .orb import *  # noqa: F401,F403
from .calib3d import *  # noqa: F401,F403


def __getattr__(name):
    """Names warpvx does not accelerate are cv2's own (module ``__getattr__``, PEP 562)."""
    try:
        return getattr(_cv2, name)
    except AttributeError:
        raise AttributeError(f"module 'warpvx.cv' (nor cv2) has no attribute {name!r}") from None


def __dir__():
    return sorted(set(globals()) | set(dir(_cv2)))
