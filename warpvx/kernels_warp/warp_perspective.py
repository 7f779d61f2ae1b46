"""Warp perspective warp: each output pixel maps back through a 3x3 matrix, then is sampled
with the shared code of :mod:`warpvx.kernels_warp._sampling` (as ``cv2.remap``).

Coordinates follow OpenCV >= 4.11: the dst->src matrix is rounded to float32 and, for output
pixel (x, y), ``X = fma(M00, x, M01*y + M02)`` (likewise Y, W) in float32, then
``sx = X / W``, ``sy = Y / W``. W == 0 gives a non-finite coordinate: the pixel takes the
border value (as OpenCV under a constant border; see ``_sampling``). As in
:mod:`warpvx.kernels_warp.remap`, one thread handles 4 output pixels when the output rows can
be written as 32-bit words.
"""

from __future__ import annotations

import warp as wp

from ._launch import array_key, launch_cached
from ._sampling import (INTER_NEAREST, SAMPLERS, Sampling, SourceImage, fma32, sampling,
                        source_image, store_pixel, store_quad)
from .remap import channels_of, output_plan

# Inference only: no adjoint kernels (halves JIT time). No implicit FMA contraction: the
# sampling code fuses explicitly where OpenCV does, so CPU and CUDA builds agree bit for bit.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})


@wp.func
def project(m: wp.mat33, xf: float, yf: float) -> wp.vec2:
    """Source coordinates of output pixel (x, y), given as floats (exact: x, y < 2^24)."""
    sx = fma32(m[0, 0], xf, m[0, 1] * yf + m[0, 2])
    sy = fma32(m[1, 0], xf, m[1, 1] * yf + m[1, 2])
    sw = fma32(m[2, 0], xf, m[2, 1] * yf + m[2, 2])
    return wp.vec2(sx / sw, sy / sw)


def make_kernels(channels: int):
    """``(per-pixel kernel, quad kernel)`` warping images of ``channels`` channels (a
    compile-time constant: one pair per count, made once at import)."""
    sample_nearest, sample_linear = SAMPLERS[channels]

    @wp.func
    def warp_linear(src: SourceImage, m: wp.mat33, x: float, y: float, how: Sampling) -> wp.uint32:
        p = project(m, x, y)
        return sample_linear(src, p[0], p[1], how)

    @wp.func
    def warp_nearest(src: SourceImage, m: wp.mat33, x: float, y: float, how: Sampling) -> wp.uint32:
        p = project(m, x, y)
        return sample_nearest(src, p[0], p[1], how)

    @wp.kernel
    def warp_perspective_pixels(
        src: SourceImage,
        m: wp.mat33,
        how: Sampling,
        dst: wp.array2d(dtype=wp.uint8),
    ):
        """One output pixel per thread; ``dst`` is the output as rows of width * C bytes."""
        y, x = wp.tid()
        if how.interpolation == INTER_NEAREST:
            p = warp_nearest(src, m, float(x), float(y), how)
        else:
            p = warp_linear(src, m, float(x), float(y), how)
        store_pixel(dst, wp.static(channels), y, x, p)

    @wp.kernel
    def warp_perspective_quads(
        src: SourceImage,
        m: wp.mat33,
        how: Sampling,
        dst: wp.array2d(dtype=wp.uint32),
    ):
        """Output pixels 4q..4q+3 of row y per thread; ``dst`` is the output as rows of
        words (one interpolation branch per thread, as in remap)."""
        y, q = wp.tid()
        # One int->float conversion per thread (quarter rate on GPUs); x + k is exact.
        xf = float(4 * q)
        yf = float(y)
        if how.interpolation == INTER_NEAREST:
            p = wp.vec4ui(
                warp_nearest(src, m, xf, yf, how),
                warp_nearest(src, m, xf + 1.0, yf, how),
                warp_nearest(src, m, xf + 2.0, yf, how),
                warp_nearest(src, m, xf + 3.0, yf, how),
            )
        else:
            p = wp.vec4ui(
                warp_linear(src, m, xf, yf, how),
                warp_linear(src, m, xf + 1.0, yf, how),
                warp_linear(src, m, xf + 2.0, yf, how),
                warp_linear(src, m, xf + 3.0, yf, how),
            )
        store_quad(dst, wp.static(channels), y, q, p)

    return warp_perspective_pixels, warp_perspective_quads


#: ``{(channels, quads): kernel}``: the per-pixel (quads False) and quad kernels.
KERNELS = {(c, quads): k for c in (1, 3, 4) for quads, k in zip((False, True), make_kernels(c))}


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
    interpolation, border = int(interpolation), int(border)
    m_inv = tuple(m_inv)
    quads, dim, dst = output_plan(out)
    kernel = KERNELS[channels_of(src), quads]

    def args():
        m = wp.mat33(*[float(v) for v in m_inv])
        return [source_image(src), m, sampling(interpolation, border, border_value)], [dst()]

    key = (array_key(src), m_inv, interpolation, border, tuple(border_value), array_key(out))
    launch_cached(kernel, dim, args, None, src.device, key)
    return out
