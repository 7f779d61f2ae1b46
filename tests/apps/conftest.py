"""Fixtures of the app tests: a private calibration cache, short real clips."""

from __future__ import annotations


import numpy as np
import pytest

from tests.images import CLIP, bgr, clip_frames  # noqa: F401  (CLIP: used by the app tests)



@pytest.fixture(scope="session")
def bikes():
    """The first 16 frames of the bundled hand-held clip, halved to 320x136 (BGR uint8)."""
    return clip_frames(16)


@pytest.fixture(scope="session")
def astronaut():
    """A real static scene: scikit-image's astronaut (BGR uint8 512x512)."""
    return bgr("astronaut")


def static_frames(image, n, size=(160, 120)):
    """``n`` identical frames: the centre ``size`` crop of ``image`` (a static camera)."""
    w, h = size
    y, x = (image.shape[0] - h) // 2, (image.shape[1] - w) // 2
    return [np.ascontiguousarray(image[y:y + h, x:x + w]) for _ in range(n)]
