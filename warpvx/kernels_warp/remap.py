"""Warp remap: ``dst[y, x] = src(map_x[y, x], map_y[y, x])``.

Sampling (nearest/bilinear, borders, rounding) is the shared code of
:mod:`warpvx.kernels_warp._sampling`, which follows ``cv2.remap`` (OpenCV >= 4.11, float32).
When the output width is a multiple of 4 and the output starts on a 4-byte boundary, one
thread samples 4 consecutive output pixels and writes them as 32-bit words (more memory
requests in flight per thread, no byte stores); otherwise one thread per output pixel.
"""

from __future__ import annotations

import warp as wp

from ._launch import array_key, as_view, as_words, launch_cached, view
from ._sampling import (INTER_NEAREST, SAMPLERS, Sampling, SourceImage, load_float, sampling,
                        source_image, store_pixel, store_quad)

# Inference only: no adjoint kernels (halves JIT time). No implicit FMA contraction: the
# sampling code fuses explicitly where OpenCV does, so CPU and CUDA builds agree bit for bit.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})


def make_kernels(channels: int):
    """``(per-pixel kernel, quad kernel)`` remapping images of ``channels`` channels (a
    compile-time constant: one pair per count, made once at import).

    The maps are read raw (:func:`load_float`, through the read-only cache) at
    ``y * width + x``: the launch covers the output, which has the maps' shape (the public
    function checks), and the maps are C-contiguous, so every index lies inside them.
    """
    sample_nearest, sample_linear = SAMPLERS[channels]

    @wp.kernel
    def remap_pixels(
        src: SourceImage,
        map_x: wp.array2d(dtype=wp.float32),
        map_y: wp.array2d(dtype=wp.float32),
        how: Sampling,
        dst: wp.array2d(dtype=wp.uint8),
    ):
        """One output pixel per thread; ``dst`` is the output as rows of width * C bytes."""
        y, x = wp.tid()
        i = y * map_x.shape[1] + x
        sx = load_float(map_x.ptr, i)
        sy = load_float(map_y.ptr, i)
        if how.interpolation == INTER_NEAREST:
            p = sample_nearest(src, sx, sy, how)
        else:
            p = sample_linear(src, sx, sy, how)
        store_pixel(dst, wp.static(channels), y, x, p)

    @wp.kernel
    def remap_quads(
        src: SourceImage,
        map_x: wp.array2d(dtype=wp.float32),
        map_y: wp.array2d(dtype=wp.float32),
        how: Sampling,
        dst: wp.array2d(dtype=wp.uint32),
    ):
        """Output pixels 4q..4q+3 of row y per thread (the width is a multiple of 4); ``dst``
        is the output as rows of words. The interpolation branch is taken once per thread, so
        each branch is straight-line code whose reads the compiler can issue together."""
        y, q = wp.tid()
        i = y * map_x.shape[1] + 4 * q
        mx = map_x.ptr
        my = map_y.ptr
        sx = wp.vec4(load_float(mx, i), load_float(mx, i + 1), load_float(mx, i + 2), load_float(mx, i + 3))
        sy = wp.vec4(load_float(my, i), load_float(my, i + 1), load_float(my, i + 2), load_float(my, i + 3))
        if how.interpolation == INTER_NEAREST:
            p = wp.vec4ui(
                sample_nearest(src, sx[0], sy[0], how),
                sample_nearest(src, sx[1], sy[1], how),
                sample_nearest(src, sx[2], sy[2], how),
                sample_nearest(src, sx[3], sy[3], how),
            )
        else:
            p = wp.vec4ui(
                sample_linear(src, sx[0], sy[0], how),
                sample_linear(src, sx[1], sy[1], how),
                sample_linear(src, sx[2], sy[2], how),
                sample_linear(src, sx[3], sy[3], how),
            )
        store_quad(dst, wp.static(channels), y, q, p)

    return remap_pixels, remap_quads


#: ``{(channels, quads): kernel}``: the per-pixel (quads False) and quad kernels.
KERNELS = {(c, quads): k for c in (1, 3, 4) for quads, k in zip((False, True), make_kernels(c))}


def channels_of(a) -> int:
    """Channels of an HxW (1) or HxWxC image."""
    return 1 if a.ndim == 2 else a.shape[2]


def output_plan(out):
    """``(quads, launch dim, make output view)`` of an output image: quads when its rows can
    be written as words, 4 pixels per thread; else one pixel per thread, rows of bytes."""
    h, w = out.shape[0], out.shape[1]
    if w % 4 == 0 and out.ptr % 4 == 0:
        return True, (h, w // 4), lambda: as_words(out)
    row = w * channels_of(out)
    return False, (h, w), lambda: view(out, wp.uint8, (h, row), (row, 1))


def remap(src, map_x, map_y, interpolation, border, border_value, *, out=None):
    """Remap a uint8 image on Warp.

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC (C = 3, 4) source image.
    map_x, map_y : wp.array
        float32 arrays of the output's height and width: source x and y of each output pixel.
    interpolation : int
        0 nearest, 1 linear (OpenCV's INTER_* values).
    border : int
        0 constant, 1 replicate, 4 reflect101 (OpenCV's BORDER_* values).
    border_value : tuple of 4 float
        Per-channel border value, already saturated to [0, 255] integers.
    out : wp.array, optional
        uint8 output of shape ``map_x.shape`` (+ ``(C,)``) on ``src.device``.

    Returns
    -------
    wp.array
        The remapped image (``out`` when given).
    """
    h, w = map_x.shape
    if out is None:
        shape = (h, w) if src.ndim == 2 else (h, w, src.shape[2])
        out = wp.empty(shape, dtype=wp.uint8, device=src.device)
    interpolation, border = int(interpolation), int(border)
    quads, dim, dst = output_plan(out)
    kernel = KERNELS[channels_of(src), quads]

    def args():
        return ([source_image(src), as_view(map_x), as_view(map_y),
                 sampling(interpolation, border, border_value)], [dst()])

    key = (array_key(src), array_key(map_x), array_key(map_y), interpolation, border,
           tuple(border_value), array_key(out))
    launch_cached(kernel, dim, args, None, src.device, key)
    return out
