"""CPU colour conversion: ``cv2.cvtColor``."""

from __future__ import annotations

import cv2
import numpy as np


def color_convert(src: np.ndarray, code: int, *, out=None) -> np.ndarray:
    """Convert with OpenCV; ``code`` is cv2's integer (validated by the public function).
    Returns ``out`` when given."""
    res = cv2.cvtColor(src, code, dst=out)
    return res if out is None else out
