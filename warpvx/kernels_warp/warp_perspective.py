"""Warp perspective warp: each output pixel maps back through a 3x3 matrix, then is sampled
with the shared code of :mod:`warpvx.kernels_warp._sampling` (as ``cv2.remap``).

Coordinates follow OpenCV >= 4.11: the dst->src matrix is rounded to float32 and, for output
pixel (x, y), ``X = fma(M00, x, M01*y + M02)`` (likewise Y, W) in float32, then
``sx = X / W``, ``sy = Y / W``. W == 0 gives a non-finite coordinate: the pixel takes the
border value (as OpenCV under a constant border; see ``_sampling``).
"""

from __future__ import annotations

import warp as wp

from ._sampling import fma32, sample_color_into, sample_gray

# Inference only: no adjoint kernels (halves JIT time). No implicit FMA contraction: the
# sampling code fuses explicitly where OpenCV does, so CPU and CUDA builds agree bit for bit.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def project(m: wp.mat33, x: int, y: int) -> wp.vec2:
    xf = float(x)
    yf = float(y)
    sx = fma32(m[0, 0], xf, m[0, 1] * yf + m[0, 2])
    sy = fma32(m[1, 0], xf, m[1, 1] * yf + m[1, 2])
    sw = fma32(m[2, 0], xf, m[2, 1] * yf + m[2, 2])
    return wp.vec2(sx / sw, sy / sw)


@wp.kernel
def warp_perspective_gray(
    src: wp.array2d(dtype=wp.uint8),
    m: wp.mat33,
    interpolation: int,
    border: int,
    bval: float,
    dst: wp.array2d(dtype=wp.uint8),
):
    y, x = wp.tid()
    p = project(m, x, y)
    dst[y, x] = sample_gray(src, p[0], p[1], interpolation, border, bval)


@wp.kernel
def warp_perspective_color(
    src: wp.array3d(dtype=wp.uint8),
    m: wp.mat33,
    interpolation: int,
    border: int,
    bval: wp.vec4,
    dst: wp.array3d(dtype=wp.uint8),
):
    y, x = wp.tid()
    p = project(m, x, y)
    sample_color_into(src, p[0], p[1], interpolation, border, bval, dst, y, x)


def warp_perspective(src, m_inv, dsize, interpolation, border, border_value, *, out=None):
    """Warp a uint8 image through a homography on Warp.

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC (C = 3, 4) source image.
    m_inv : sequence of 9 float
        The dst->src matrix in row order (the public function inverts src->dst matrices).
    dsize : (int, int)
        Output (width, height).
    interpolation, border, border_value
        As :func:`warpvx.kernels_warp.remap.remap`.
    out : wp.array, optional
        uint8 output (height, width[, C]) on ``src.device``.

    Returns
    -------
    wp.array
        The warped image (``out`` when given).
    """
    w, h = int(dsize[0]), int(dsize[1])
    if out is None:
        shape = (h, w) if src.ndim == 2 else (h, w, src.shape[2])
        out = wp.empty(shape, dtype=wp.uint8, device=src.device)
    m = wp.mat33(*[float(v) for v in m_inv])
    if src.ndim == 2:
        wp.launch(
            warp_perspective_gray,
            dim=(h, w),
            inputs=[src, m, int(interpolation), int(border), float(border_value[0])],
            outputs=[out],
            device=src.device,
        )
    else:
        wp.launch(
            warp_perspective_color,
            dim=(h, w),
            inputs=[src, m, int(interpolation), int(border), wp.vec4(*border_value)],
            outputs=[out],
            device=src.device,
        )
    return out
