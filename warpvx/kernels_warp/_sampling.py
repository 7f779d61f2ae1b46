"""Shared image sampling for Warp kernels: border handling and nearest/bilinear taps.

Used by ``remap`` and ``warp_perspective`` (and any later kernel that samples a uint8 image at
real coordinates). The arithmetic follows OpenCV >= 4.11 (``warp_common.scalar.hpp``), which
samples in float32 rather than with the older 1/32-px fixed-point tables:

- pixel centres at integer coordinates;
- nearest: ``ix = cvRound(sx)`` (round half to even);
- linear: ``ix = floor(sx)``, ``ax = sx - ix``; ``v0 = fma(ax, p01 - p00, p00)``,
  ``v1 = fma(ax, p11 - p10, p10)``, ``v = fma(ay, v1 - v0, v0)`` in float32, stored as
  ``saturate(cvRound(v))``;
- border ``constant``: every tap outside the image reads the border value;
  ``replicate``: clamp; ``reflect101``: ``gfedcb|abcdefgh|gfedcba`` (replicate on a
  1-pixel axis, as OpenCV).

A non-finite coordinate (NaN, inf; also W == 0 in a perspective warp) has no source pixel:
the output takes the border value under every border mode (OpenCV gives the same under
``constant``, and 0 for linear sampling under the others). Finite coordinates beyond +-1e9
are clamped there (still far outside). Every tap is resolved into the image before it is
read: no input can read out of bounds.
"""

from __future__ import annotations

import warp as wp

# OpenCV's integer values, so cv2 constants pass straight through.
INTER_NEAREST = wp.constant(0)
INTER_LINEAR = wp.constant(1)
BORDER_CONSTANT = wp.constant(0)
BORDER_REPLICATE = wp.constant(1)
BORDER_REFLECT_101 = wp.constant(4)

# Coordinates are clamped to +-1e9 before the int conversion (an out-of-range float->int
# conversion differs between CPU and GPU).
COORD_LIMIT = wp.constant(1.0e9)


@wp.func
def split_coord(v: float) -> tuple[int, float]:
    """``(floor(v), v - floor(v))`` of a finite ``v``."""
    c = wp.clamp(v, -COORD_LIMIT, COORD_LIMIT)
    f = wp.floor(c)
    return int(f), c - f


@wp.func
def round_coord(v: float) -> int:
    """``cvRound(v)`` (half to even) of a finite ``v``."""
    return int(wp.rint(wp.clamp(v, -COORD_LIMIT, COORD_LIMIT)))


@wp.func
def is_finite_point(sx: float, sy: float) -> bool:
    return wp.isfinite(sx) and wp.isfinite(sy)


@wp.func
def border_index(p: int, n: int, border: int) -> int:
    """Index ``p`` on an axis of length ``n`` after the border rule; -1 means "use the
    border value" (constant border only). The result is always in [-1, n)."""
    if p >= 0 and p < n:
        return p
    if border == BORDER_CONSTANT:
        return -1
    if border == BORDER_REPLICATE or n == 1:
        return wp.clamp(p, 0, n - 1)
    # reflect101: period 2(n-1), mirrored about 0 and n-1 without repeating the edge.
    period = 2 * (n - 1)
    q = p % period
    if q < 0:
        q = q + period
    if q >= n:
        q = period - q
    return q


@wp.func
def nearest_tap(sx: float, sy: float, width: int, height: int, border: int) -> wp.vec2i:
    """Resolved ``(x, y)`` of the nearest source pixel (-1 entries: border value)."""
    x = border_index(round_coord(sx), width, border)
    y = border_index(round_coord(sy), height, border)
    return wp.vec2i(x, y)


@wp.func
def linear_taps(sx: float, sy: float, width: int, height: int, border: int) -> tuple[wp.vec4i, float, float]:
    """Resolved ``(x0, x1, y0, y1)`` of the 2x2 neighbourhood and the weights ``(ax, ay)``."""
    ix, ax = split_coord(sx)
    iy, ay = split_coord(sy)
    taps = wp.vec4i(
        border_index(ix, width, border),
        border_index(ix + 1, width, border),
        border_index(iy, height, border),
        border_index(iy + 1, height, border),
    )
    return taps, ax, ay


@wp.func
def fma32(a: float, b: float, c: float) -> float:
    """``a*b + c`` rounded once to float32, as the ``v_fma`` of OpenCV's vector paths.

    Computed in float64, where the product of two float32 is exact, so the result does not
    depend on whether the compiler contracts (CUDA does, Warp's CPU build does not); a plain
    ``a*b + c`` differs by an ulp now and then, which flips rounding ties.
    """
    return wp.float32(wp.float64(a) * wp.float64(b) + wp.float64(c))


@wp.func
def lerp2(p00: float, p01: float, p10: float, p11: float, ax: float, ay: float) -> float:
    """Bilinear blend in OpenCV's order of operations (each step one fused multiply-add)."""
    v0 = fma32(ax, p01 - p00, p00)
    v1 = fma32(ax, p11 - p10, p10)
    return fma32(ay, v1 - v0, v0)


@wp.func
def saturate_u8(v: float) -> wp.uint8:
    """``saturate_cast<uchar>(v)``: round half to even, clamp to [0, 255]."""
    return wp.uint8(wp.clamp(int(wp.rint(v)), 0, 255))


@wp.func
def texel_gray(src: wp.array2d(dtype=wp.uint8), x: int, y: int, bval: float) -> float:
    if x < 0 or y < 0:
        return bval
    return float(src[y, x])


@wp.func
def texel_color(src: wp.array3d(dtype=wp.uint8), x: int, y: int, c: int, bval: float) -> float:
    if x < 0 or y < 0:
        return bval
    return float(src[y, x, c])


@wp.func
def sample_gray(
    src: wp.array2d(dtype=wp.uint8), sx: float, sy: float, interpolation: int, border: int, bval: float
) -> wp.uint8:
    """One gray output pixel sampled at ``(sx, sy)``."""
    if not is_finite_point(sx, sy):
        return saturate_u8(bval)
    width = src.shape[1]
    height = src.shape[0]
    if interpolation == INTER_NEAREST:
        t = nearest_tap(sx, sy, width, height, border)
        return saturate_u8(texel_gray(src, t[0], t[1], bval))
    taps, ax, ay = linear_taps(sx, sy, width, height, border)
    p00 = texel_gray(src, taps[0], taps[2], bval)
    p01 = texel_gray(src, taps[1], taps[2], bval)
    p10 = texel_gray(src, taps[0], taps[3], bval)
    p11 = texel_gray(src, taps[1], taps[3], bval)
    return saturate_u8(lerp2(p00, p01, p10, p11, ax, ay))


@wp.func
def blend_color(
    src: wp.array3d(dtype=wp.uint8), taps: wp.vec4i, ax: float, ay: float, c: int, bval: float
) -> wp.uint8:
    """Channel ``c`` of the bilinear sample at resolved ``taps``."""
    p00 = texel_color(src, taps[0], taps[2], c, bval)
    p01 = texel_color(src, taps[1], taps[2], c, bval)
    p10 = texel_color(src, taps[0], taps[3], c, bval)
    p11 = texel_color(src, taps[1], taps[3], c, bval)
    return saturate_u8(lerp2(p00, p01, p10, p11, ax, ay))


@wp.func
def sample_color_into(
    src: wp.array3d(dtype=wp.uint8),
    sx: float,
    sy: float,
    interpolation: int,
    border: int,
    bval: wp.vec4,
    dst: wp.array3d(dtype=wp.uint8),
    dy: int,
    dx: int,
):
    """Sample every channel (3 or 4) at ``(sx, sy)`` into ``dst[dy, dx, :]``; the taps are
    computed once, and channels are spelled out so ``bval`` stays in registers."""
    four = dst.shape[2] == 4
    if not is_finite_point(sx, sy):
        dst[dy, dx, 0] = saturate_u8(bval[0])
        dst[dy, dx, 1] = saturate_u8(bval[1])
        dst[dy, dx, 2] = saturate_u8(bval[2])
        if four:
            dst[dy, dx, 3] = saturate_u8(bval[3])
        return
    width = src.shape[1]
    height = src.shape[0]
    if interpolation == INTER_NEAREST:
        t = nearest_tap(sx, sy, width, height, border)
        dst[dy, dx, 0] = saturate_u8(texel_color(src, t[0], t[1], 0, bval[0]))
        dst[dy, dx, 1] = saturate_u8(texel_color(src, t[0], t[1], 1, bval[1]))
        dst[dy, dx, 2] = saturate_u8(texel_color(src, t[0], t[1], 2, bval[2]))
        if four:
            dst[dy, dx, 3] = saturate_u8(texel_color(src, t[0], t[1], 3, bval[3]))
        return
    taps, ax, ay = linear_taps(sx, sy, width, height, border)
    dst[dy, dx, 0] = blend_color(src, taps, ax, ay, 0, bval[0])
    dst[dy, dx, 1] = blend_color(src, taps, ax, ay, 1, bval[1])
    dst[dy, dx, 2] = blend_color(src, taps, ax, ay, 2, bval[2])
    if four:
        dst[dy, dx, 3] = blend_color(src, taps, ax, ay, 3, bval[3])
