"""CPU Gaussian blur: ``cv2.GaussianBlur`` (its 8-bit path is bit-exact fixed point)."""

from __future__ import annotations

import cv2
import numpy as np

from ..modes import FILTER_BORDERS, mode_code


def _pair(v):
    return (v, v) if not isinstance(v, (tuple, list)) else (v[0], v[1])


def gaussian_blur(src: np.ndarray, ksize, sigma, border, *, out=None) -> np.ndarray:
    """Blur a uint8 image; arguments as :func:`warpvx.kernels_warp.gaussian_blur.gaussian_blur`."""
    kx, ky = _pair(ksize)
    sx, sy = _pair(sigma)
    code = mode_code(border, "border", FILTER_BORDERS)
    return cv2.GaussianBlur(src, (int(kx), int(ky)), float(sx), dst=out, sigmaY=float(sy),
                            borderType=code)
