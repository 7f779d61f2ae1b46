"""CPU perspective warp: ``cv2.warpPerspective`` with the dst->src matrix.

When the matrix takes some output pixel to a horizon (W near 0) or far beyond the image,
``cv2.warpPerspective`` samples source pixels where W == 0 and can loop for seconds per pixel
under ``reflect101``; such matrices are sampled instead through :func:`remap` with maps
computed as the Warp kernel computes them, so the coordinate rule of
:mod:`warpvx.kernels_cpu.remap` (that of the Warp backends) applies.
"""

from __future__ import annotations

import cv2
import numpy as np

from .remap import coord_limit, remap

#: W (the homogeneous coordinate) must stay this far from 0, relative to the size of its
#: terms, over the whole output for OpenCV's own warp: float32 rounding then keeps its sign.
W_MARGIN = 1e-4


def warp_perspective(src: np.ndarray, m_inv, dsize, interpolation: int, border: int, border_value,
                     *, out=None) -> np.ndarray:
    """Warp a uint8 image with OpenCV.

    ``m_inv`` is the 3x3 matrix mapping destination to source pixels as 9 floats in row
    order (the public function inverts a src->dst matrix beforehand), ``dsize`` is
    (width, height); the other arguments are those of :func:`warpvx.kernels_cpu.remap.remap`.
    Returns ``out`` when given.
    """
    m = np.asarray(m_inv, dtype=np.float64).reshape(3, 3)
    if not _tame(m, dsize, src.shape, border):
        map_x, map_y = project_maps(m, dsize)
        return remap(src, map_x, map_y, interpolation, border, border_value, out=out)
    res = cv2.warpPerspective(src, m, tuple(dsize), dst=out, flags=interpolation | cv2.WARP_INVERSE_MAP,
                              borderMode=border, borderValue=tuple(float(v) for v in border_value))
    return res if out is None else out


def _tame(m: np.ndarray, dsize, src_shape, border: int) -> bool:
    """Whether every output pixel maps to a coordinate within the remap limits, W keeping one
    sign. X, Y and W are affine in the output pixel, so their extremes over the output lie at
    its corners, and ``|X / W| <= max |X| / min |W|``."""
    w, h = int(dsize[0]), int(dsize[1])
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [0, h - 1, 1], [w - 1, h - 1, 1]], np.float64)
    x, y, wc = m @ corners.T
    size = np.abs(m[2]) @ np.abs(corners.T)
    if not (np.all(wc > W_MARGIN * size) or np.all(wc < -W_MARGIN * size)):
        return False
    min_w = np.abs(wc).min()
    return bool(np.abs(x).max() / min_w <= coord_limit(src_shape[1], border)
                and np.abs(y).max() / min_w <= coord_limit(src_shape[0], border))


def project_maps(m: np.ndarray, dsize) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) of the dst->src matrix ``m`` over a (width, height) output, as
    the Warp kernel computes them: ``m`` rounded to float32, ``X = fma(m00, x, m01*y + m02)``
    (likewise Y, W), ``X / W``. The fma is taken in float64 and rounded to float32 (exact
    but for rare double roundings). W == 0 gives inf or NaN."""
    w, h = int(dsize[0]), int(dsize[1])
    m32 = m.astype(np.float32)
    xs = np.arange(w, dtype=np.float64)
    ys = np.arange(h, dtype=np.float32)[:, None]

    def row(r):
        c = (m32[r, 1] * ys + m32[r, 2]).astype(np.float64)
        return (np.float64(m32[r, 0]) * xs + c).astype(np.float32)

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        wv = row(2)
        return row(0) / wv, row(1) / wv
