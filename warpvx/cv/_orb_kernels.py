"""Warp kernels of :class:`warpvx.cv.ORB` (OpenCV's ORB arithmetic), in one module so one
compile serves them; imported only when an ORB call runs on a Warp device.

``resize_linear_exact``  ``cv2.resize`` INTER_LINEAR_EXACT on uint8, bit-exact (taps from
                         :func:`warpvx.cv._orb_levels.exact_taps`)
``blur_rows7``,         ORB's 7x7, sigma 2 Gaussian as OpenCV's float separable filter takes
``blur_columns7``        it (rows, then columns with the symmetric sum, float32, cvRound),
                         BORDER_REFLECT_101, inside an unblurred reflected margin

(Its rotated BRIEF is :func:`warpvx.kernels_warp.orb.brief.describe_points`, shared with the
ORB stage nodes.)
"""

from __future__ import annotations

import warp as wp

from ..kernels_warp._sampling import BORDER_REFLECT_101, border_index, read_reflect101

wp.set_module_options({"enable_backward": False})

TAPS = wp.constant(7)
HALF = wp.constant(3)


@wp.kernel
def resize_linear_exact(src: wp.array2d(dtype=wp.uint8), x_taps: wp.array(dtype=wp.vec3i),
                        y_taps: wp.array(dtype=wp.vec3i), dst: wp.array2d(dtype=wp.uint8)):
    """dst[y, x] = (H0 (256 - cy) + H1 cy + 2^15) >> 16, H = p0 (256 - cx) + p1 cx."""
    y, x = wp.tid()
    tx = x_taps[x]
    ty = y_taps[y]
    h0 = int(src[ty[0], tx[0]]) * (256 - tx[2]) + int(src[ty[0], tx[1]]) * tx[2]
    h1 = int(src[ty[1], tx[0]]) * (256 - tx[2]) + int(src[ty[1], tx[1]]) * tx[2]
    dst[y, x] = wp.uint8((h0 * (256 - ty[2]) + h1 * ty[2] + 32768) >> 16)


@wp.kernel
def blur_rows7(src: wp.array2d(dtype=wp.uint8), k: wp.array(dtype=wp.float32),
               rows: wp.array2d(dtype=wp.float32)):
    """OpenCV's row filter: rows[y, x] = sum of k[i] src[y, x + i - 3], in order, float32."""
    y, x = wp.tid()
    s = float(0.0)
    for i in range(TAPS):
        s += k[i] * float(read_reflect101(src, y, x + i - HALF))
    rows[y, x] = s


@wp.kernel
def blur_columns7(src: wp.array2d(dtype=wp.uint8), rows: wp.array2d(dtype=wp.float32),
                  k: wp.array(dtype=wp.float32), margin: int, dst: wp.array2d(dtype=wp.uint8)):
    """``dst`` is the level with ``margin`` px around: inside, the column filter over
    :func:`blur_rows7`, k[3] r[0] + sum_d k[3 + d] (r[d] + r[-d]), rounded half to even and
    saturated (OpenCV's SymmColumnFilter, Cast<float, uchar>); the margin, ``src`` reflected
    unblurred (what OpenCV's bordered pyramid holds there)."""
    py, px = wp.tid()
    y = py - margin
    x = px - margin
    h = src.shape[0]
    if y < 0 or x < 0 or y >= h or x >= src.shape[1]:
        dst[py, px] = wp.uint8(read_reflect101(src, y, x))
        return
    s = k[HALF] * rows[y, x]
    for d in range(1, HALF + 1):
        below = rows[border_index(y + d, h, BORDER_REFLECT_101), x]
        above = rows[border_index(y - d, h, BORDER_REFLECT_101), x]
        s += k[HALF + d] * (below + above)
    dst[py, px] = wp.uint8(wp.clamp(int(wp.rint(s)), 0, 255))

