"""OpenCV-compatible drop-ins: ``from warpvx import cv as cv2`` for the supported subset.

Same names, argument order, constants and return types as ``cv2``; a clear
:class:`warpvx.UnsupportedError` for codes and flags outside the subset. Split like OpenCV's
own modules: imgproc (colour, geometric transforms), pyramids (pyrDown, resize),
features2d (FAST, Harris, goodFeaturesToTrack, ORB, BFMatcher), video (pyramidal LK).
Every function also takes ``backend=`` as a keyword.
"""

from .imgproc import *  # noqa: F401,F403
from .pyramids import *  # noqa: F401,F403
from .features2d import *  # noqa: F401,F403
from .video import *  # noqa: F401,F403
from .orb import *  # noqa: F401,F403
