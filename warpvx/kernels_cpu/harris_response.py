"""Harris and minimum-eigenvalue corner responses on the CPU (OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np


def harris_response(src: np.ndarray, block_size: int, ksize: int, k: float, *,
                    score: str = "harris", out=None) -> np.ndarray:
    """``cv2.cornerHarris`` (or ``cv2.cornerMinEigenVal``) with BORDER_REFLECT_101."""
    if score == "min_eigen":
        return cv2.cornerMinEigenVal(src, block_size, dst=out, ksize=ksize,
                                     borderType=cv2.BORDER_REFLECT_101)
    return cv2.cornerHarris(src, block_size, ksize, k, dst=out,
                            borderType=cv2.BORDER_REFLECT_101)
