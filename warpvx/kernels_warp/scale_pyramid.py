"""Warp bilinear resize (``cv2.resize`` INTER_LINEAR on uint8, bit-exact) and the ORB-SLAM2
scale pyramid built from it, one launch per level, a thread per output column and
:data:`RESIZE_ROWS` rows.

OpenCV's arithmetic (``resize.cpp``, ``resizeGeneric_`` with ``HResizeLinear`` and the SIMD
``VResizeLinearVec_32s8u``); the taps and weights of every output column and row are computed
once on the host (:func:`linear_taps`, cached per size) as OpenCV computes its tables:

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

import functools

import numpy as np
import warp as wp

from .._pyramid_sizes import resize_scales, scale_pyramid_sizes
from ._filtering import as_rows, fit_block
from ._launch import array_key, run_direct, run_pyramid_into, run_recorded

_DBL_EPSILON = 2.220446049250313e-16

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})


def linear_taps(dst_len: int, src_len: int, scale: float, pin: bool) -> np.ndarray:
    """int32 [dst_len, 4]: ``(s0, s1, w0, w1)`` per output index, OpenCV's arithmetic.

    ``f = float32((d + 0.5) * scale - 0.5)`` (double product), ``s = floor(f)``, ``f -= s``;
    ``pin`` (x): a coordinate left of 0 or at/after the last pixel is pinned there with
    ``f = 0``, else (y) the taps are clamped into the image with ``f`` kept; 11-bit weights
    ``w0 = cvRound((1 - f) * 2048)``, ``w1 = cvRound(f * 2048)`` (float32, half to even).
    """
    d = np.arange(dst_len, dtype=np.float64)
    f = ((d + 0.5) * scale - 0.5).astype(np.float32)
    s = np.floor(f).astype(np.int64)
    f = (f - s.astype(np.float32)).astype(np.float32)
    if pin:
        low, high = s < 0, s >= src_len - 1
        s = np.where(low, 0, np.where(high, src_len - 1, s))
        f = np.where(low | high, np.float32(0.0), f).astype(np.float32)
    s0 = np.clip(s, 0, src_len - 1)
    s1 = np.clip(s + 1, 0, src_len - 1)
    w0 = np.rint((np.float32(1.0) - f) * np.float32(2048.0))
    w1 = np.rint(f * np.float32(2048.0))
    return np.ascontiguousarray(np.stack([s0, s1, w0, w1], axis=1).astype(np.int32))


_TABLES: dict = {}


def resize_tables(src_size, dst_size, scales, device):
    """``(x taps, y taps)`` of a resize, as ``wp.vec4i`` arrays on ``device`` (built on the host
    once per sizes and scales, then kept)."""
    key = (device.alias, src_size, dst_size, scales)
    tables = _TABLES.get(key)
    if tables is None:
        (sw, sh), (dw, dh), (scale_x, scale_y) = src_size, dst_size, scales
        tables = _TABLES[key] = (
            wp.array(linear_taps(dw, sw, scale_x, True), dtype=wp.vec4i, device=device),
            wp.array(linear_taps(dh, sh, scale_y, False), dtype=wp.vec4i, device=device),
        )
    return tables


@wp.func
def average_cut_block(src: wp.array2d(dtype=wp.uint8), channels: int, src_width: int, dy: int, dx: int,
                      c: int) -> wp.uint8:
    """OpenCV's INTER_AREA 2x edge pixel: ``cvRound(sum / count)`` over the block's pixels
    inside the image (channel ``c``)."""
    nx = wp.min(2, src_width - 2 * dx)
    ny = wp.min(2, src.shape[0] - 2 * dy)
    s = int(0)
    for j in range(ny):
        for i in range(nx):
            s += int(src[2 * dy + j, (2 * dx + i) * channels + c])
    v = wp.rint(wp.float32(s) / wp.float32(nx * ny))
    return wp.uint8(wp.clamp(int(v), 0, 255))


#: Output rows per thread of :func:`resize_kernel`: the column's taps are read once per
#: thread, and fewer threads carry less fixed cost.
RESIZE_ROWS = 4


@functools.cache
def resize_kernel(rows: int):
    """The bilinear resize kernel writing ``rows`` output rows per thread.

    Launched over ``(ceil(dst_rows / rows), dst_cols)``: thread (by, xc) writes rows
    ``by*rows ...`` of column ``xc`` (pixel ``xc // channels``, channel ``xc % channels``),
    its taps and weights read from the tables of :func:`linear_taps`. Rows past the image
    are computed on its last row (so every load is unconditional) and not stored.
    """

    @wp.kernel(enable_backward=False, module="unique")
    def resize_linear(
        src: wp.array2d(dtype=wp.uint8),
        channels: int,
        x_taps: wp.array(dtype=wp.vec4i),
        y_taps: wp.array(dtype=wp.vec4i),
        area2: int,
        dst: wp.array2d(dtype=wp.uint8),
    ):
        by, xc = wp.tid()
        dx = xc // channels
        c = xc - dx * channels
        src_width = src.shape[1] // channels
        src_height = src.shape[0]
        tx = x_taps[dx]
        i0 = tx[0] * channels + c
        i1 = tx[1] * channels + c
        cut_x = area2 != 0 and 2 * dx + 1 >= src_width
        for r in range(wp.static(rows)):
            dy = by * wp.static(rows) + r
            y = wp.min(dy, dst.shape[0] - 1)
            ty = y_taps[y]
            h0 = int(src[ty[0], i0]) * tx[2] + int(src[ty[0], i1]) * tx[3]
            h1 = int(src[ty[1], i0]) * tx[2] + int(src[ty[1], i1]) * tx[3]
            v = (((h0 >> 4) * ty[2]) >> 16) + (((h1 >> 4) * ty[3]) >> 16)
            out = wp.uint8(wp.clamp((v + 2) >> 2, 0, 255))
            if cut_x or (area2 != 0 and 2 * y + 1 >= src_height):
                out = average_cut_block(src, channels, src_width, y, dx, c)
            if dy < dst.shape[0]:
                dst[dy, xc] = out

    return resize_linear


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
        uint8 output of the target shape on ``src.device`` (reused: the launch is recorded
        once and replayed).

    Returns
    -------
    wp.array
        The resized image (``out`` when given).
    """
    (dw, dh), scales = resize_scales((src.shape[1], src.shape[0]), dsize, fx, fy)
    if out is None:
        out = wp.empty((dh, dw) + tuple(src.shape[2:]), dtype=wp.uint8, device=src.device)
        run_direct([_resize_launch(src, out, scales)], src.device)
        return out
    key = ("resize", array_key(src), array_key(out), scales)
    run_recorded(key, lambda: [_resize_launch(src, out, scales)], src.device)
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
        Reused frame after frame, so the whole pyramid's launches are recorded once and
        replayed.

    Returns
    -------
    list of wp.array
        ``[src, level1, ...]`` (the ``out`` arrays when given).
    """
    if out is not None:
        return run_pyramid_into("scale_pyramid", src, out, levels, _pyramid_launches)
    sizes = scale_pyramid_sizes(src.shape[1], src.shape[0], levels, scale_factor)
    pyramid = [src] + [wp.empty((h, w) + tuple(src.shape[2:]), dtype=wp.uint8, device=src.device)
                       for w, h in sizes[1:]]
    run_direct(_pyramid_launches(pyramid), src.device)
    return pyramid


def _pyramid_launches(pyramid) -> list:
    """The launches resizing ``pyramid[l-1]`` into ``pyramid[l]`` (to its size), level by level."""
    launches = []
    for prev, dst in zip(pyramid[:-1], pyramid[1:]):
        _, scales = resize_scales((prev.shape[1], prev.shape[0]), (dst.shape[1], dst.shape[0]))
        launches.append(_resize_launch(prev, dst, scales))
    return launches


def _resize_launch(src, out, scales) -> tuple:
    """``(kernel, dim, inputs, outputs)`` resizing ``src`` into ``out`` with source steps
    ``scales`` (x, y)."""
    scale_x, scale_y = scales
    src2d, channels = as_rows(src)
    dst2d, _ = as_rows(out)
    x_taps, y_taps = resize_tables((src.shape[1], src.shape[0]), (out.shape[1], out.shape[0]), tuple(scales),
                                   src.device)
    # OpenCV's fast INTER_AREA path when both scales are exactly 2.
    area2 = int(abs(scale_x - 2.0) < _DBL_EPSILON and abs(scale_y - 2.0) < _DBL_EPSILON)
    rows, _ = fit_block(RESIZE_ROWS, 1, dst2d.shape[0], dst2d.shape[1], src.device)
    return (resize_kernel(rows), ((dst2d.shape[0] + rows - 1) // rows, dst2d.shape[1]),
            [src2d, channels, x_taps, y_taps, area2], [dst2d])
