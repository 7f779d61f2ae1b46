"""The stabilizer's 3x3 chain on the device, and the warp by a matrix the device computed.

:func:`follow_motion` is :func:`warpvx.apps.stabilize.follow_motion` (as_motion, accumulate,
smooth_transform, truncate_transform) as one single-thread kernel in float64, so the matrix
never visits the host; :func:`warp_by_device_matrix` is
:mod:`warpvx.kernels_warp.warp_perspective` (linear, constant border 0: what the stabilizer
uses) reading its dst->src matrix from a device array the chain wrote, instead of a launch
parameter. Same arithmetic as the host chain except the 3x3 inverses and determinant (cofactor
formulas here, LAPACK's LU there): they differ in the last float64 bits, which can flip the
float32 rounding of the sampling matrix on rare frames (the tolerance of the device path's
equality test).
"""

from __future__ import annotations

import warp as wp

from ._launch import Recorded
from ._sampling import (BORDER_CONSTANT, INTER_LINEAR, SAMPLERS, Sampling, SourceImage, sampling,
                        source_image, store_pixel, store_quad)
from .remap import output_plan
from .warp_perspective import project

# Forward-only; no FMA contraction, so the chain rounds as NumPy's elementwise arithmetic.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

MIN_DET = wp.constant(wp.float64(1.0e-9))  # as_motion: |det H| under this is no model
COVER_EPS = wp.constant(wp.float64(1.0e-6))  # _covers' tolerance (px)
TRUNCATE_STEPS = 12  # truncate_transform's bisection steps


@wp.struct
class Chain:
    """Constants of the chain: ``weights`` (float64 [L], oldest first), ``lag`` (frames),
    ``crop`` (fraction) with its matrix ``crop_matrix`` (float64 3x3), frame ``width`` and
    ``height`` (px), ``cut_threshold`` (``is_cut``'s, a fraction of the diagonal; inf: none)."""

    weights: wp.array(dtype=wp.float64)
    lag: int
    crop: wp.float64
    crop_matrix: wp.mat33d
    width: wp.float64
    height: wp.float64
    cut_threshold: wp.float64


@wp.func
def all_finite(m: wp.mat33d) -> bool:
    ok = True
    for i in range(3):
        for j in range(3):
            if not wp.isfinite(m[i, j]):
                ok = False
    return ok


@wp.func
def nan_matrix() -> wp.mat33d:
    nan = wp.float64(wp.nan)
    return wp.mat33d(nan, nan, nan, nan, nan, nan, nan, nan, nan)


@wp.func
def motion_of(h: wp.mat33d) -> wp.mat33d:
    """``as_motion``: ``h / h[2,2]``; the identity for no model (zeros, non-finite, singular)."""
    if not all_finite(h) or h[2, 2] == wp.float64(0.0) or wp.abs(wp.determinant(h)) < MIN_DET:
        return wp.identity(3, dtype=wp.float64)
    return h / h[2, 2]


@wp.func
def covers(m: wp.mat33d, chain: Chain) -> bool:
    """``_covers``: the four output corners map (through inv(m)) inside the input frame."""
    inv = wp.inverse(m)
    w1 = chain.width - wp.float64(1.0)
    h1 = chain.height - wp.float64(1.0)
    ok = True
    for k in range(4):
        x = wp.where(k == 1 or k == 2, w1, wp.float64(0.0))
        y = wp.where(k >= 2, h1, wp.float64(0.0))
        p = inv * wp.vec3d(x, y, wp.float64(1.0))
        sx = p[0] / p[2]
        sy = p[1] / p[2]
        if sx < -COVER_EPS or sx > w1 + COVER_EPS or sy < -COVER_EPS or sy > h1 + COVER_EPS:
            ok = False
    return ok


@wp.func
def is_cut(m: wp.mat33d, chain: Chain) -> bool:
    """``is_cut``: a frame corner moved by more than ``cut_threshold`` of the diagonal, or
    sent to or past the line at infinity."""
    w1 = chain.width - wp.float64(1.0)
    h1 = chain.height - wp.float64(1.0)
    limit = chain.cut_threshold * wp.sqrt(chain.width * chain.width + chain.height * chain.height)
    cut = False
    for k in range(4):
        x = wp.where(k == 1 or k == 2, w1, wp.float64(0.0))
        y = wp.where(k >= 2, h1, wp.float64(0.0))
        p = m * wp.vec3d(x, y, wp.float64(1.0))
        if not p[2] > wp.float64(0.0):
            cut = True
        elif wp.length(wp.vec2d(p[0] / p[2] - x, p[1] / p[2] - y)) > limit:
            cut = True
    return cut and wp.isfinite(chain.cut_threshold)


@wp.func
def window_entry(history: wp.array(dtype=wp.mat33d), t: wp.mat33d, i: int, n: int) -> wp.mat33d:
    """Entry ``i`` of the smoothing window of ``n`` matrices: the last ``n - 1`` of ``history``
    then ``t``."""
    if i == n - 1:
        return t
    return history[history.shape[0] + 1 - n + i]


@wp.func
def window_entry(history: wp.array(dtype=wp.int32), t: int, i: int, n: int) -> int:
    """The same entry of the window's segment indices."""
    if i == n - 1:
        return t
    return history[history.shape[0] + 1 - n + i]


@wp.kernel
def follow_motion(homography: wp.array2d(dtype=wp.float64), live: wp.array(dtype=wp.int32),
                  chain: Chain, history: wp.array(dtype=wp.mat33d), segments: wp.array(dtype=wp.int32),
                  record: wp.array(dtype=wp.mat33d), sampling_matrix: wp.array(dtype=wp.mat33)):
    """One thread: record = (H_k, T_k, smoothing transform, warp, segment index of frame k in
    [0, 0] of a mat33d); ``history`` (T_{k-m} .. T_{k-1}, NaN before the video) and
    ``segments`` (their segment indices, 0 before the video) shifted by one with frame k;
    ``sampling_matrix[0]`` the float32 dst->src matrix of the warp."""
    one = wp.float64(1.0)
    h = wp.mat33d()
    for i in range(3):
        for j in range(3):
            h[i, j] = homography[i, j]
    motion = motion_of(h)
    prev = history[history.shape[0] - 1]
    segment = segments[segments.shape[0] - 1]
    t = wp.identity(3, dtype=wp.float64)
    if live[0] == 0:
        t = nan_matrix()
    elif all_finite(prev):
        if is_cut(motion, chain):
            segment = segment + 1  # t restarts at the identity
        else:
            t = motion * prev
            t = t / t[2, 2]
    n = chain.weights.shape[0]
    s = wp.identity(3, dtype=wp.float64)
    tj = window_entry(history, t, n - 1 - chain.lag, n)
    sj = window_entry(segments, segment, n - 1 - chain.lag, n)
    if all_finite(tj):
        inv = wp.inverse(tj)
        acc = wp.mat33d()
        total = wp.float64(0.0)
        for i in range(n):
            ti = window_entry(history, t, i, n)
            if all_finite(ti) and window_entry(segments, segment, i, n) == sj:
                m = ti * inv
                wi = chain.weights[i]
                acc = acc + wi * (m / m[2, 2])
                total = total + wi
        s = acc / total
    c = chain.crop_matrix
    warp = c * s
    if chain.crop != wp.float64(0.0) and not covers(warp, chain):
        eye = wp.identity(3, dtype=wp.float64)
        lo = wp.float64(0.0)
        hi = one
        for _step in range(TRUNCATE_STEPS):
            mid = wp.float64(0.5) * (lo + hi)
            if covers(c * ((one - mid) * s + mid * eye), chain):
                hi = mid
            else:
                lo = mid
        warp = c * ((one - hi) * s + hi * eye)
    for i in range(history.shape[0] - 1):
        history[i] = history[i + 1]
        segments[i] = segments[i + 1]
    history[history.shape[0] - 1] = t
    segments[segments.shape[0] - 1] = segment
    record[0] = motion
    record[1] = t
    record[2] = s
    record[3] = warp
    record[4] = wp.mat33d(wp.float64(segment), wp.float64(0.0), wp.float64(0.0), wp.float64(0.0),
                          wp.float64(0.0), wp.float64(0.0), wp.float64(0.0), wp.float64(0.0),
                          wp.float64(0.0))
    sampling_matrix[0] = wp.mat33(wp.inverse(warp))


sample_linear = SAMPLERS[3][1]


@wp.func
def warp_pixel(src: SourceImage, m: wp.mat33, x: float, y: float, how: Sampling) -> wp.uint32:
    p = project(m, x, y)
    return sample_linear(src, p[0], p[1], how)


@wp.kernel
def warp_by_device_matrix_quads(src: SourceImage, matrix: wp.array(dtype=wp.mat33), how: Sampling,
                                dst: wp.array2d(dtype=wp.uint32)):
    """Output pixels 4q..4q+3 of row y (BGR, rows as words), as ``warp_perspective_quads``."""
    y, q = wp.tid()
    m = matrix[0]
    xf = float(4 * q)
    yf = float(y)
    p = wp.vec4ui(warp_pixel(src, m, xf, yf, how), warp_pixel(src, m, xf + 1.0, yf, how),
                  warp_pixel(src, m, xf + 2.0, yf, how), warp_pixel(src, m, xf + 3.0, yf, how))
    store_quad(dst, 3, y, q, p)


@wp.kernel
def warp_by_device_matrix_pixels(src: SourceImage, matrix: wp.array(dtype=wp.mat33),
                                 how: Sampling, dst: wp.array2d(dtype=wp.uint8)):
    """One output pixel (x, y) per thread (BGR, rows of bytes), as ``warp_perspective_pixels``."""
    y, x = wp.tid()
    store_pixel(dst, 3, y, x, warp_pixel(src, matrix[0], float(x), float(y), how))


def warp_by_device_matrix(src, matrix, out) -> Recorded:
    """A recorded launch warping BGR uint8 ``src`` (HxWx3 ``wp.array``) into ``out`` (same
    size) through ``matrix[0]`` (``wp.array`` of one ``wp.mat33``, dst->src), bilinear,
    constant border 0; replay it with ``.launch()``."""
    quads, dim, dst = output_plan(out)
    kernel = warp_by_device_matrix_quads if quads else warp_by_device_matrix_pixels
    return Recorded(kernel, dim, src.device, src=source_image(src), matrix=matrix,
                    how=sampling(INTER_LINEAR, BORDER_CONSTANT, (0.0, 0.0, 0.0, 0.0)), dst=dst())


__all__ = ["Chain", "follow_motion", "warp_by_device_matrix"]
