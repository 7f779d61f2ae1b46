"""Fixtures of the graph tests: a private calibration cache, small real frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tests.images import bgr

SIZE = (128, 96)  # (width, height): small, so Warp's single-threaded CPU kernels stay quick


@pytest.fixture(scope="session")
def frames():
    """Four frames of a real photo panning by a few pixels (BGR uint8 96x128)."""
    src = cv2.resize(bgr("astronaut"), (SIZE[0] + 16, SIZE[1] + 16), interpolation=cv2.INTER_AREA)
    out = []
    for i in range(4):
        M = np.float32([[1, 0, -8 + 1.5 * i], [0, 1, -8 + 0.75 * i]])
        out.append(cv2.warpAffine(src, M, SIZE, borderMode=cv2.BORDER_REFLECT))
    return out
