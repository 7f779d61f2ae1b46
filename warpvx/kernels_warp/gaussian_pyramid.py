"""Warp Gaussian pyramid: repeated ``cv2.pyrDown``, one fused launch per level (the shared
separable filter of :mod:`warpvx.kernels_warp._filtering` with the [1 4 6 4 1] taps at
stride 2, bit-exact).
"""

from __future__ import annotations

import warp as wp

from ._filtering import filter_launches, pyr_down_edge, pyr_down_taps
from ._launch import run_direct, run_pyramid_into


def gaussian_pyramid(src, levels, *, out=None, sizes=None):
    """Build ``levels`` images: ``src`` then each ``pyrDown`` of the previous one.

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC.
    levels : int
        Number of images, >= 1 (already validated against the image size).
    out : list of wp.array, optional
        ``levels`` arrays on ``src.device``: ``out[0]`` is ``src`` (not written); ``out[l]``
        receives level ``l`` (of the level's size). Reused frame after frame, so the whole
        pyramid's launches are recorded once and replayed.
    sizes : list of (int, int), optional
        (width, height) of each level when not the default ``((w+1)//2, (h+1)//2)`` chain:
        any size within ``cv2.pyrDown``'s ``dstsize`` rule (``|2 * dw - w| <= 2``, same for h).

    Returns
    -------
    list of wp.array
        ``[src, level1, ...]`` (the ``out`` arrays when given).
    """
    taps = pyr_down_taps()
    if out is not None:
        return run_pyramid_into("pyramid", src, out, levels, lambda pyramid: _launches(pyramid, taps))
    pyramid = [src]
    for lvl in range(1, levels):
        prev = pyramid[-1]
        w, h = sizes[lvl] if sizes is not None else ((prev.shape[1] + 1) // 2, (prev.shape[0] + 1) // 2)
        pyramid.append(wp.empty((h, w) + tuple(prev.shape[2:]), dtype=wp.uint8, device=src.device))
    run_direct(_launches(pyramid, taps), src.device)
    return pyramid


def _launches(pyramid, taps) -> list:
    """The launches computing ``pyramid[l]`` from ``pyramid[l-1]``, level by level."""
    launches = []
    for prev, dst in zip(pyramid[:-1], pyramid[1:]):
        launches += filter_launches(prev, taps, dst, pyr_down_edge(prev.shape[1], dst.shape[1]))
    return launches
