"""Pyramid level sizes and ``cv::resize``'s size/scale rule (neutral module).

Shared by :mod:`warpvx.pyramid` (validation) and the kernels (``scale_pyramid``, ORB), which
must not import the public module.
"""

from __future__ import annotations

import numpy as np


def gaussian_pyramid_sizes(width: int, height: int, levels: int) -> list[tuple[int, int]]:
    """(width, height) of each level of :func:`warpvx.pyramid.gaussian_pyramid`: ``((w+1)//2, (h+1)//2)``."""
    sizes = [(int(width), int(height))]
    for _ in range(1, levels):
        w, h = sizes[-1]
        sizes.append(((w + 1) // 2, (h + 1) // 2))
    return sizes


def scale_pyramid_sizes(width: int, height: int, levels: int, scale_factor: float) -> list[tuple[int, int]]:
    """(width, height) of each level of :func:`warpvx.pyramid.scale_pyramid`, as ORB-SLAM2 computes them.

    float32 throughout: ``s_l = s_{l-1} * f`` (``f = float32(scale_factor)``),
    ``inv_l = 1 / s_l``, size ``cvRound(float32(w) * inv_l)`` (half to even). Entries may be 0
    when ``levels`` is too large for the image (:func:`warpvx.pyramid.scale_pyramid` rejects that).
    """
    f = np.float32(scale_factor)
    scale = np.float32(1.0)
    sizes = []
    for lvl in range(levels):
        if lvl > 0:
            scale = np.float32(scale * f)
        inv = np.float32(np.float32(1.0) / scale)
        sizes.append((int(np.rint(np.float32(width) * inv)), int(np.rint(np.float32(height) * inv))))
    return sizes


def resize_scales(src_size, dsize=None, fx=0.0, fy=0.0):
    """``((dw, dh), (scale_x, scale_y))`` as ``cv::resize`` derives them.

    From ``dsize`` (w, h) when given and non-zero: ``inv = dw / sw``; else from ``fx``, ``fy``:
    ``inv = fx``, ``dw = cvRound(sw * fx)`` (half to even). Then ``scale = 1 / inv`` (double),
    the source step per output pixel.
    """
    sw, sh = src_size
    if dsize is not None and dsize[0] > 0 and dsize[1] > 0:
        dw, dh = int(dsize[0]), int(dsize[1])
        inv_x, inv_y = dw / sw, dh / sh
    else:
        inv_x, inv_y = float(fx), float(fy)
        dw, dh = int(round(sw * inv_x)), int(round(sh * inv_y))
    return (dw, dh), (1.0 / inv_x, 1.0 / inv_y)
