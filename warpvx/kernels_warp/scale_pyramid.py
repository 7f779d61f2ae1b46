"""Warp bilinear resize (``cv2.resize`` INTER_LINEAR on uint8, bit-exact) and the ORB-SLAM2
scale pyramid built from it, one launch per level, one thread per output pixel.

OpenCV's arithmetic (``resize.cpp``, ``resizeGeneric_`` with ``HResizeLinear`` and the SIMD
``VResizeLinearVec_32s8u``), reproduced per output pixel:

- source coordinate ``f = float((d + 0.5) * scale - 0.5)`` (the product in double, then
  float32), ``s = floor(f)``, ``f -= s``; along x a coordinate left of 0 or at/after the last
  column is pinned there with ``f = 0``; rows are clamped into the image;
- 11-bit weights ``a0 = cvRound((1 - f) * 2048)``, ``a1 = cvRound(f * 2048)``;
- horizontal sums ``H = p0 * a0 + p1 * a1`` (exact int), vertical
  ``((H0 >> 4) * b0 >> 16) + ((H1 >> 4) * b1 >> 16)`` then ``(v + 2) >> 2`` saturated, as
  OpenCV's vector path computes every pixel (its scalar formula differs by 1 in places).

``scale = 1 / inv_scale`` with ``inv_scale = dsize / ssize``, or ``1 / fx`` when the size comes
from ``fx``, exactly as ``cv::resize`` derives it. When both scales are exactly 2 OpenCV switches
to its fast INTER_AREA path: the same values inside the image, but an output pixel whose 2x2
block is cut by the image edge (odd source size, ``fx = 0.5``) is the mean of its pixels inside,
rounded half to even; the ``area2`` flag reproduces that.
"""

from __future__ import annotations

import warp as wp

from ..pyramid import resize_scales, scale_pyramid_sizes
from ._filtering import array_key, as_rows, launch_cached

_DBL_EPSILON = 2.220446049250313e-16

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})


@wp.func
def linear_coord(d: int, scale: wp.float64) -> tuple[int, wp.float32]:
    """``(floor(f), f - floor(f))`` of the source coordinate of output index ``d``."""
    f = wp.float32((wp.float64(d) + wp.float64(0.5)) * scale - wp.float64(0.5))
    s = int(wp.floor(f))
    return s, f - wp.float32(s)


@wp.func
def weight_q11(f: wp.float32) -> int:
    """``saturate_cast<short>(f * 2048)`` (round half to even)."""
    return int(wp.rint(f * wp.float32(2048.0)))


@wp.func
def average_cut_block(src: wp.array2d(dtype=wp.uint8), channels: int, src_width: int, dy: int, dx: int,
                      dst: wp.array2d(dtype=wp.uint8)):
    """OpenCV's INTER_AREA 2x edge pixel: ``cvRound(sum / count)`` over the block's pixels
    inside the image."""
    nx = wp.min(2, src_width - 2 * dx)
    ny = wp.min(2, src.shape[0] - 2 * dy)
    for c in range(channels):
        s = int(0)
        for j in range(ny):
            for i in range(nx):
                s += int(src[2 * dy + j, (2 * dx + i) * channels + c])
        v = wp.rint(wp.float32(s) / wp.float32(nx * ny))
        dst[dy, dx * channels + c] = wp.uint8(wp.clamp(int(v), 0, 255))


@wp.kernel
def resize_linear(
    src: wp.array2d(dtype=wp.uint8),
    channels: int,
    src_width: int,
    scale_x: wp.float64,
    scale_y: wp.float64,
    area2: int,
    dst: wp.array2d(dtype=wp.uint8),
):
    dy, dx = wp.tid()
    src_height = src.shape[0]
    if area2 != 0:
        if 2 * dx + 1 >= src_width or 2 * dy + 1 >= src_height:
            average_cut_block(src, channels, src_width, dy, dx, dst)
            return
    sx, fx = linear_coord(dx, scale_x)
    if sx < 0:
        sx = 0
        fx = wp.float32(0.0)
    if sx >= src_width - 1:
        sx = src_width - 1
        fx = wp.float32(0.0)
    sx1 = wp.min(sx + 1, src_width - 1)
    a0 = weight_q11(wp.float32(1.0) - fx)
    a1 = weight_q11(fx)
    sy, fy = linear_coord(dy, scale_y)
    b0 = weight_q11(wp.float32(1.0) - fy)
    b1 = weight_q11(fy)
    y0 = wp.clamp(sy, 0, src_height - 1)
    y1 = wp.clamp(sy + 1, 0, src_height - 1)
    for c in range(channels):
        i0 = sx * channels + c
        i1 = sx1 * channels + c
        h0 = int(src[y0, i0]) * a0 + int(src[y0, i1]) * a1
        h1 = int(src[y1, i0]) * a0 + int(src[y1, i1]) * a1
        v = (((h0 >> 4) * b0) >> 16) + (((h1 >> 4) * b1) >> 16)
        dst[dy, dx * channels + c] = wp.uint8(wp.clamp((v + 2) >> 2, 0, 255))


def resize(src, dsize=None, fx=0.0, fy=0.0, *, out=None):
    """Resize a uint8 image bilinearly as ``cv2.resize(src, dsize, fx=fx, fy=fy,
    interpolation=INTER_LINEAR)`` (bit-exact).

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC.
    dsize : (int, int) or None
        Output (width, height); None or (0, 0) takes the size from ``fx``, ``fy`` (> 0).
    out : wp.array, optional
        uint8 output of the target shape on ``src.device``.

    Returns
    -------
    wp.array
        The resized image (``out`` when given).
    """
    (dw, dh), (scale_x, scale_y) = resize_scales((src.shape[1], src.shape[0]), dsize, fx, fy)
    cache = out is not None  # caller-owned buffers are reused: replay a recorded launch
    if out is None:
        out = wp.empty((dh, dw) + tuple(src.shape[2:]), dtype=wp.uint8, device=src.device)
    src2d, channels = as_rows(src)
    dst2d, _ = as_rows(out)
    area2 = int(abs(scale_x - 2.0) < _DBL_EPSILON and abs(scale_y - 2.0) < _DBL_EPSILON)
    inputs = [src2d, channels, int(src.shape[1]), wp.float64(scale_x), wp.float64(scale_y), area2]
    if cache:
        launch_cached(resize_linear, (dh, dw), inputs, [dst2d], src.device,
                      (array_key(src2d), array_key(dst2d), channels, scale_x, scale_y))
    else:
        wp.launch(resize_linear, dim=(dh, dw), inputs=inputs, outputs=[dst2d], device=src.device)
    return out


def scale_pyramid(src, levels, scale_factor, *, out=None):
    """ORB-SLAM2's image pyramid: level ``l`` is level ``l-1`` resized INTER_LINEAR to
    :func:`warpvx.pyramid.scale_pyramid_sizes` (``cvRound(w / scale_factor^l)``).

    Parameters
    ----------
    src : wp.array
        uint8 HxW or HxWxC.
    levels : int
        Number of images, >= 1 (already validated against the image size).
    scale_factor : float
        > 1.
    out : list of wp.array, optional
        ``levels`` arrays on ``src.device`` of the level shapes; ``out[0]`` is ``src``.

    Returns
    -------
    list of wp.array
        ``[src, level1, ...]`` (the ``out`` arrays when given).
    """
    sizes = scale_pyramid_sizes(src.shape[1], src.shape[0], levels, scale_factor)
    pyramid = [src]
    for lvl in range(1, levels):
        dst = out[lvl] if out is not None else None
        pyramid.append(resize(pyramid[-1], sizes[lvl], out=dst))
    return pyramid
