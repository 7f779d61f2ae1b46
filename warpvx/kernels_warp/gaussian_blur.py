"""Warp Gaussian blur: OpenCV's bit-exact 8-bit separable filter (the shared two-pass filter of
:mod:`warpvx.kernels_warp._filtering`: one fused launch up to radius 7, else two launches
through a cached scratch image).
"""

from __future__ import annotations

import warp as wp

from ..modes import FILTER_BORDERS, mode_code
from ._filtering import blur_taps, launch_filter


def _pair(v):
    return (v, v) if not isinstance(v, (tuple, list)) else (v[0], v[1])


def gaussian_blur(src, ksize, sigma, border, *, out=None):
    """Blur a uint8 image as ``cv2.GaussianBlur`` (8-bit path, bit-exact).

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC.
    ksize : int or (int, int)
        Odd kernel size (width, height), each 1..31.
    sigma : float or (float, float)
        Standard deviation (x, y); <= 0 derives it from the size as OpenCV; a y value <= 0
        means the x value.
    border : str or int
        ``"constant"`` (zeros), ``"replicate"``, ``"reflect"``, ``"reflect101"`` or cv2's
        integer code.
    out : wp.array, optional
        uint8 output of ``src``'s shape on ``src.device``; may be ``src`` itself.

    Returns
    -------
    wp.array
        The blurred image (``out`` when given).
    """
    kx, ky = _pair(ksize)
    sx, sy = _pair(sigma)
    if sy <= 0:
        sy = sx
    code = mode_code(border, "border", FILTER_BORDERS)
    taps = blur_taps(int(kx), int(ky), float(sx), float(sy), code)
    if out is None:
        return launch_filter(src, taps, wp.empty(src.shape, dtype=wp.uint8, device=src.device))
    if out.ptr == src.ptr:
        # In place: every output pixel reads its neighbours, so filter into a scratch image.
        tmp = launch_filter(src, taps, wp.empty(src.shape, dtype=wp.uint8, device=src.device))
        wp.copy(out, tmp)
        return out
    # A caller-owned output is usually reused frame after frame: replay a recorded launch.
    return launch_filter(src, taps, out, cache=True)
