"""Pyramidal Lucas-Kanade sparse optical flow on Warp (OpenCV's ``calcOpticalFlowPyrLK``).

One thread block per point (:data:`BLOCK_DIM` lanes; one lane on Warp's CPU device), one
launch per pyramid level, coarse to fine. The lanes of a block split the integration window
between them and combine their partial sums with block reductions (``wp.tile_sum``); every
lane then holds the same sums, so the iteration and its exit tests run in lock step.

Arithmetic follows OpenCV's ``LKTrackerInvoker`` (``modules/video/src/lkpyramid.cpp``):

- Scharr derivatives of the previous level (3/10/3, int16, BORDER_REFLECT_101 inside the
  image, zero outside it as OpenCV's ``BORDER_CONSTANT`` padding of the derivative image);
  computed on the fly at the window samples instead of as a derivative image per level.
- Bilinear window sampling with fixed-point weights (``W_BITS = 14``, rounded half to even);
  image samples are kept as value * 32 (``>> 9``), derivatives as value (``>> 14``); image
  reads outside the level reflect (BORDER_REFLECT_101, OpenCV's pyramid padding).
- Sums in float32 scaled by ``2**-20``; minimum eigenvalue test
  ``(A11 + A22 - sqrt((A11 - A22)^2 + 4 A12^2)) / (2 * win_w * win_h) < min_eig_threshold``
  or ``det < FLT_EPSILON`` loses the point; the iteration stops when ``|delta|^2 <= eps^2`` or
  when two consecutive steps cancel (then half of the last step is taken back).
- Points whose window leaves the level by more than a window (``floor(p - half) < -win`` or
  ``>= size``) are lost; status is only cleared at level 0, as OpenCV does.
- ``err``: mean absolute difference between the window in ``prev`` and the tracked window in
  ``next`` (in gray levels), 0 for lost points.
"""

from __future__ import annotations

import warp as wp

from ._sampling import BORDER_REFLECT_101, border_index

BLOCK_DIM = 64
"""Lanes per point on CUDA (Warp's CPU device runs one lane per block)."""

FLT_SCALE = wp.constant(1.0 / float(1 << 20))
FLT_EPSILON = wp.constant(1.1920928955078125e-07)
COORD_LIMIT = wp.constant(1.0e7)  # beyond this a coordinate is lost before any int conversion


@wp.struct
class TrackParams:
    """Per-level parameters of :func:`track_points_level`."""

    win_w: int
    win_h: int
    level: int
    max_level: int
    max_iters: int
    eps2: wp.float64  # squared step threshold, compared in double as OpenCV's ddot
    min_eig_threshold: float
    use_initial_flow: int


@wp.func
def load_reflect(img: wp.array2d(dtype=wp.uint8), r: int, c: int) -> int:
    """Pixel ``(r, c)`` of ``img`` with BORDER_REFLECT_101 outside it."""
    r = border_index(r, img.shape[0], BORDER_REFLECT_101)
    c = border_index(c, img.shape[1], BORDER_REFLECT_101)
    return int(img[r, c])


@wp.func
def sample_fixed(
    img: wp.array2d(dtype=wp.uint8), r: int, c: int, iw00: int, iw01: int, iw10: int, iw11: int
) -> int:
    """Fixed-point bilinear sample at ``(r + b, c + a)`` scaled by 32 (OpenCV's ``>> (W_BITS - 5)``)."""
    h = img.shape[0]
    w = img.shape[1]
    s = int(0)
    if r >= 0 and c >= 0 and r + 1 < h and c + 1 < w:
        s = (
            int(img[r, c]) * iw00
            + int(img[r, c + 1]) * iw01
            + int(img[r + 1, c]) * iw10
            + int(img[r + 1, c + 1]) * iw11
        )
    else:
        s = (
            load_reflect(img, r, c) * iw00
            + load_reflect(img, r, c + 1) * iw01
            + load_reflect(img, r + 1, c) * iw10
            + load_reflect(img, r + 1, c + 1) * iw11
        )
    return (s + 256) >> 9


@wp.func
def scharr_column(img: wp.array2d(dtype=wp.uint8), r: int, c: int) -> wp.vec4i:
    """Vertical Scharr pass of column ``c`` for rows ``r`` and ``r + 1``.

    Returns (smooth(r), diff(r), smooth(r + 1), diff(r + 1)) with smooth = 3 [1 0 1] + 10 and
    diff = I(row + 1) - I(row - 1), rows and column reflected (BORDER_REFLECT_101).
    """
    p0 = load_reflect(img, r - 1, c)
    p1 = load_reflect(img, r, c)
    p2 = load_reflect(img, r + 1, c)
    p3 = load_reflect(img, r + 2, c)
    return wp.vec4i((p0 + p2) * 3 + p1 * 10, p2 - p0, (p1 + p3) * 3 + p2 * 10, p3 - p1)


@wp.func
def inside(img: wp.array2d(dtype=wp.uint8), r: int, c: int) -> int:
    if r >= 0 and r < img.shape[0] and c >= 0 and c < img.shape[1]:
        return 1
    return 0


@wp.func
def sample_scharr_fixed(
    img: wp.array2d(dtype=wp.uint8), r: int, c: int, iw00: int, iw01: int, iw10: int, iw11: int
) -> wp.vec2i:
    """Fixed-point bilinear sample of the Scharr derivatives (Ix, Iy) at ``(r + b, c + a)``.

    The derivative image is OpenCV's ``calcScharrDeriv`` of the level (int16 values) padded
    with zeros outside the level, so each of the four taps is masked by :func:`inside`.
    """
    cm = scharr_column(img, r, c - 1)
    c0 = scharr_column(img, r, c)
    c1 = scharr_column(img, r, c + 1)
    c2 = scharr_column(img, r, c + 2)
    m00 = inside(img, r, c)
    m01 = inside(img, r, c + 1)
    m10 = inside(img, r + 1, c)
    m11 = inside(img, r + 1, c + 1)
    ix00 = (c1[0] - cm[0]) * m00
    iy00 = ((cm[1] + c1[1]) * 3 + c0[1] * 10) * m00
    ix01 = (c2[0] - c0[0]) * m01
    iy01 = ((c0[1] + c2[1]) * 3 + c1[1] * 10) * m01
    ix10 = (c1[2] - cm[2]) * m10
    iy10 = ((cm[3] + c1[3]) * 3 + c0[3] * 10) * m10
    ix11 = (c2[2] - c0[2]) * m11
    iy11 = ((c0[3] + c2[3]) * 3 + c1[3] * 10) * m11
    sx = ix00 * iw00 + ix01 * iw01 + ix10 * iw10 + ix11 * iw11
    sy = iy00 * iw00 + iy01 * iw01 + iy10 * iw10 + iy11 * iw11
    return wp.vec2i((sx + 8192) >> 14, (sy + 8192) >> 14)


@wp.func
def bilinear_weights(fx: float, fy: float) -> wp.vec4i:
    """OpenCV's 14-bit bilinear weights (iw00, iw01, iw10, iw11) for fractions (fx, fy)."""
    iw00 = int(wp.rint((1.0 - fx) * (1.0 - fy) * 16384.0))
    iw01 = int(wp.rint(fx * (1.0 - fy) * 16384.0))
    iw10 = int(wp.rint((1.0 - fx) * fy * 16384.0))
    return wp.vec4i(iw00, iw01, iw10, 16384 - iw00 - iw01 - iw10)


@wp.func
def coords_usable(x: float, y: float) -> bool:
    """Finite and small enough to convert to int (others are lost, never read)."""
    return wp.isfinite(x) and wp.isfinite(y) and wp.abs(x) < COORD_LIMIT and wp.abs(y) < COORD_LIMIT


@wp.func
def window_outside(ix: int, iy: int, win_w: int, win_h: int, w: int, h: int) -> bool:
    return ix < -win_w or ix >= w or iy < -win_h or iy >= h


@wp.kernel
def track_points_level(
    prev_img: wp.array2d(dtype=wp.uint8),
    next_img: wp.array2d(dtype=wp.uint8),
    prev_pts: wp.array(dtype=wp.float32),
    guess_pts: wp.array(dtype=wp.float32),
    params: TrackParams,
    patch: wp.array3d(dtype=wp.int16),
    tracked_pts: wp.array(dtype=wp.float32),
    status: wp.array(dtype=wp.uint8),
    err: wp.array(dtype=wp.float32),
):
    """Track point ``i`` on one level; lanes split the window. Points are flat (x0, y0, x1, ...).

    ``guess_pts`` is the previous (coarser) level's result, or the initial flow at the top
    level; ``tracked_pts`` receives this level's result. ``status`` and ``err`` are written
    at level 0 only. ``patch[0|1|2, i]`` holds the window of ``prev`` (value * 32, Ix, Iy)
    between the covariance pass and the iterations; each lane reads back only what it wrote.
    """
    i, lane = wp.tid()
    nlanes = wp.block_dim()
    win_w = params.win_w
    win_h = params.win_h
    area = win_w * win_h
    level = params.level
    h = prev_img.shape[0]
    w = prev_img.shape[1]

    scale = 1.0 / float(1 << level)
    px = prev_pts[2 * i] * scale
    py = prev_pts[2 * i + 1] * scale
    nx = float(0.0)
    ny = float(0.0)
    if level == params.max_level:
        if params.use_initial_flow != 0:
            nx = guess_pts[2 * i] * scale
            ny = guess_pts[2 * i + 1] * scale
        else:
            nx = px
            ny = py
    else:
        nx = guess_pts[2 * i] * 2.0
        ny = guess_pts[2 * i + 1] * 2.0
    res_x = nx
    res_y = ny

    half_x = float(win_w - 1) * 0.5
    half_y = float(win_h - 1) * 0.5
    x0 = px - half_x
    y0 = py - half_y

    # Every branch below depends only on block-uniform values, so all lanes take it together.
    ok = coords_usable(x0, y0)
    ix0 = int(0)
    iy0 = int(0)
    if ok:
        ix0 = int(wp.floor(x0))
        iy0 = int(wp.floor(y0))
        if window_outside(ix0, iy0, win_w, win_h, w, h):
            ok = False
    if not ok:
        if lane == 0:
            tracked_pts[2 * i] = res_x
            tracked_pts[2 * i + 1] = res_y
            if level == 0:
                status[i] = wp.uint8(0)
                err[i] = 0.0
        return

    # Window of prev and covariance matrix of its derivatives.
    wts = bilinear_weights(x0 - float(ix0), y0 - float(iy0))
    acc = wp.vec3(0.0, 0.0, 0.0)
    k = lane
    while k < area:
        wy = k // win_w
        wx = k - wy * win_w
        r = iy0 + wy
        c = ix0 + wx
        val = sample_fixed(prev_img, r, c, wts[0], wts[1], wts[2], wts[3])
        d = sample_scharr_fixed(prev_img, r, c, wts[0], wts[1], wts[2], wts[3])
        patch[0, i, k] = wp.int16(val)
        patch[1, i, k] = wp.int16(d[0])
        patch[2, i, k] = wp.int16(d[1])
        acc += wp.vec3(float(d[0] * d[0]), float(d[0] * d[1]), float(d[1] * d[1]))
        k += nlanes
    cov = wp.tile_extract(wp.tile_sum(wp.tile(acc, preserve_type=True)), 0)
    a11 = cov[0] * FLT_SCALE
    a12 = cov[1] * FLT_SCALE
    a22 = cov[2] * FLT_SCALE

    det = a11 * a22 - a12 * a12
    min_eig = (a22 + a11 - wp.sqrt((a11 - a22) * (a11 - a22) + 4.0 * a12 * a12)) / float(2 * area)
    alive = True
    if min_eig < params.min_eig_threshold or det < FLT_EPSILON:
        alive = False
    if not alive:
        if lane == 0:
            tracked_pts[2 * i] = res_x
            tracked_pts[2 * i + 1] = res_y
            if level == 0:
                status[i] = wp.uint8(0)
                err[i] = 0.0
        return
    inv_det = 1.0 / det

    # Gauss-Newton steps on the window of next.
    cx = nx - half_x
    cy = ny - half_y
    prev_dx = float(0.0)
    prev_dy = float(0.0)
    it = int(0)
    while it < params.max_iters:
        if not coords_usable(cx, cy):
            alive = False
            break
        jx = int(wp.floor(cx))
        jy = int(wp.floor(cy))
        if window_outside(jx, jy, win_w, win_h, w, h):
            alive = False
            break
        wj = bilinear_weights(cx - float(jx), cy - float(jy))
        bsum = wp.vec2(0.0, 0.0)
        k = lane
        while k < area:
            wy = k // win_w
            wx = k - wy * win_w
            diff = sample_fixed(next_img, jy + wy, jx + wx, wj[0], wj[1], wj[2], wj[3]) - int(patch[0, i, k])
            bsum += wp.vec2(float(diff * int(patch[1, i, k])), float(diff * int(patch[2, i, k])))
            k += nlanes
        b = wp.tile_extract(wp.tile_sum(wp.tile(bsum, preserve_type=True)), 0)
        b1 = b[0] * FLT_SCALE
        b2 = b[1] * FLT_SCALE
        dx = (a12 * b2 - a22 * b1) * inv_det
        dy = (a12 * b1 - a11 * b2) * inv_det
        cx += dx
        cy += dy
        res_x = cx + half_x
        res_y = cy + half_y
        if wp.float64(dx) * wp.float64(dx) + wp.float64(dy) * wp.float64(dy) <= params.eps2:
            break
        if (
            it > 0
            and wp.float64(wp.abs(dx + prev_dx)) < wp.float64(0.01)
            and wp.float64(wp.abs(dy + prev_dy)) < wp.float64(0.01)
        ):
            # Oscillating between two positions: settle in the middle.
            res_x -= dx * 0.5
            res_y -= dy * 0.5
            break
        prev_dx = dx
        prev_dy = dy
        it += 1

    # Final error at level 0 (mean absolute difference over the window).
    error = float(0.0)
    if alive and level == 0:
        ex = res_x - half_x
        ey = res_y - half_y
        if not coords_usable(ex, ey):
            alive = False
        else:
            ejx = int(wp.floor(ex))
            ejy = int(wp.floor(ey))
            if window_outside(ejx, ejy, win_w, win_h, w, h):
                alive = False
            else:
                we = bilinear_weights(ex - float(ejx), ey - float(ejy))
                esum = float(0.0)
                k = lane
                while k < area:
                    wy = k // win_w
                    wx = k - wy * win_w
                    diff = sample_fixed(next_img, ejy + wy, ejx + wx, we[0], we[1], we[2], we[3]) - int(
                        patch[0, i, k]
                    )
                    esum += float(wp.abs(diff))
                    k += nlanes
                total = wp.tile_extract(wp.tile_sum(wp.tile(esum)), 0)
                error = total / float(32 * area)

    if lane == 0:
        tracked_pts[2 * i] = res_x
        tracked_pts[2 * i + 1] = res_y
        if level == 0:
            if alive:
                status[i] = wp.uint8(1)
                err[i] = error
            else:
                status[i] = wp.uint8(0)
                err[i] = 0.0


def _build_pyramid(img, n_levels: int) -> list:
    """Gray pyramid of ``n_levels`` levels (level 0 = ``img``) on ``img``'s device."""
    from .gaussian_pyramid import gaussian_pyramid

    return list(gaussian_pyramid(img, n_levels))


def optical_flow_pyr_lk(
    prev,
    next,  # noqa: A002 - OpenCV's name
    prev_pts,
    next_pts,
    win_size,
    max_level,
    max_iters,
    eps,
    min_eig_threshold,
    *,
    out=None,
):
    """Pyramidal LK on Warp arrays; see :func:`warpvx.optical_flow_pyr_lk`.

    ``prev``/``next``: uint8 HxW ``wp.array``s or lists of levels (level 0 first);
    ``prev_pts`` float32 [N, 2]; ``next_pts`` float32 [N, 2] initial flow or None;
    ``win_size`` (w, h); ``max_level`` already limited to the pyramid (and the image size);
    ``max_iters`` in [0, 100], ``eps`` in [0, 10]. ``out``: optional (next_pts [N, 2] float32,
    status [N] uint8, err [N] float32) on the same device. Returns that triple. No host sync.
    """
    device = prev_pts.device
    n = prev_pts.shape[0]
    win_w, win_h = int(win_size[0]), int(win_size[1])
    area = win_w * win_h

    if out is None:
        res = wp.empty((n, 2), dtype=wp.float32, device=device)
        status = wp.empty(n, dtype=wp.uint8, device=device)
        err = wp.empty(n, dtype=wp.float32, device=device)
    else:
        res, status, err = out
    if n == 0:
        return res, status, err

    n_levels = max_level + 1
    prev_pyr = list(prev) if isinstance(prev, (list, tuple)) else _build_pyramid(prev, n_levels)
    next_pyr = list(next) if isinstance(next, (list, tuple)) else _build_pyramid(next, n_levels)
    flat_prev = prev_pts.reshape((2 * n,))
    use_initial = next_pts is not None
    # Coarser levels' results ping-pong between two rows (a level never reads what it writes).
    tmp = wp.empty((2, 2 * n), dtype=wp.float32, device=device)
    guess = tmp[max_level % 2]
    if use_initial:
        # A copy, so the initial flow may alias the output.
        wp.copy(guess, next_pts.reshape((2 * n,)))
    patch = wp.empty((3, n, area), dtype=wp.int16, device=device)
    res_flat = res.reshape((2 * n,))

    params = TrackParams()
    params.win_w = win_w
    params.win_h = win_h
    params.max_level = max_level
    params.max_iters = int(max_iters)
    params.eps2 = float(eps) * float(eps)
    params.min_eig_threshold = float(min_eig_threshold)
    params.use_initial_flow = 1 if use_initial else 0

    for level in range(max_level, -1, -1):
        params.level = level
        target = res_flat if level == 0 else tmp[(level + 1) % 2]
        wp.launch_tiled(
            track_points_level,
            dim=[n],
            inputs=[prev_pyr[level], next_pyr[level], flat_prev, guess, params, patch],
            outputs=[target, status, err],
            block_dim=BLOCK_DIM,
            device=device,
        )
        guess = target
    return res, status, err


__all__ = ["optical_flow_pyr_lk", "BLOCK_DIM"]
