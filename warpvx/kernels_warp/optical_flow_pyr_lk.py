"""Pyramidal Lucas-Kanade sparse optical flow on Warp (OpenCV's ``calcOpticalFlowPyrLK``).

One thread block per point (:data:`BLOCK_DIM` lanes; one lane on Warp's CPU device), one
launch for all pyramid levels (up to :data:`LEVELS_PER_LAUNCH`): each block walks its point
coarse to fine, a level's result being the next level's guess, so a call costs the slowest
point's total rather than the sum of each level's slowest point. The lanes of a block split
the integration window between them and combine their partial sums with block reductions
(``wp.tile_sum``); every lane then holds the same sums, so the iteration and its exit tests
run in lock step.

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

Speed: each lane steps through its share of the window without integer divisions; the window
patch (value, Ix, Iy) is one int64 per sample, read with one load per iteration; windows that
lie with their derivative margins inside the level read pixels directly (the reflecting reads
serve the edges only). Scratch (pyramid levels of image inputs, window patches) and the
launch are made and recorded once per problem size and replayed (:func:`._launch.workspace`);
no host sync.
"""

from __future__ import annotations

import warp as wp

from .._counted import Counted, is_counted
from ._sampling import read_reflect101
from ._launch import Recorded, array_key, as_view, workspace

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

BLOCK_DIM = 256
"""Lanes per point on CUDA (Warp's CPU device runs one lane per block). The kernel is bound by
the latency of each point's iterations: more lanes, fewer samples each. With all levels in one
launch, on an H100 at 1280x720 (21x21, 4 levels; benchmarks/results/graph/h100-2026-11-25-s10/
lk_levels.md) 500 points took 217-230 / 137-139 / 97-111 us and 1000 points 275-304 / 204-226 /
188-198 us with 64 / 128 / 256 lanes (one launch per level and 128 lanes before: 169-183 and
250-252 us). The block sums' order follows the lane count, so their last bits do too."""

FLT_SCALE = wp.constant(1.0 / float(1 << 20))
FLT_EPSILON = wp.constant(1.1920928955078125e-07)
COORD_LIMIT = wp.constant(1.0e7)  # beyond this a coordinate is lost before any int conversion


LEVELS_PER_LAUNCH = 8
"""Pyramid levels tracked by one launch (at most the 8 :class:`Pyramid` slots); deeper
pyramids take a launch per 8 levels, the coarser launch's result being the next one's guess.
At 1280x720 OpenCV's level limit (:func:`warpvx.flow._level_limit`) allows 6 levels to a
21x21 window, 8 to a 3x3 one."""

_PYRAMIDS_MAX = 16  # Pyramid structs a workspace keeps (a graph alternates a few level sets)


@wp.struct
class Pyramid:
    """Up to :data:`LEVELS_PER_LAUNCH` consecutive levels of one frame, finest first (slot k
    holds level ``bottom + k`` of the launch); slots past the launch's levels are unused."""

    level0: wp.array2d(dtype=wp.uint8)
    level1: wp.array2d(dtype=wp.uint8)
    level2: wp.array2d(dtype=wp.uint8)
    level3: wp.array2d(dtype=wp.uint8)
    level4: wp.array2d(dtype=wp.uint8)
    level5: wp.array2d(dtype=wp.uint8)
    level6: wp.array2d(dtype=wp.uint8)
    level7: wp.array2d(dtype=wp.uint8)


@wp.struct
class TrackParams:
    """Parameters of a :func:`track_points` launch (levels ``top`` .. ``bottom``)."""

    win_w: int
    win_h: int
    top: int
    bottom: int
    max_level: int
    max_iters: int
    eps2: wp.float64  # squared step threshold, compared in double as OpenCV's ddot
    min_eig_threshold: float
    use_initial_flow: int


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
            read_reflect101(img, r, c) * iw00
            + read_reflect101(img, r, c + 1) * iw01
            + read_reflect101(img, r + 1, c) * iw10
            + read_reflect101(img, r + 1, c + 1) * iw11
        )
    return (s + 256) >> 9


@wp.func
def scharr_column(img: wp.array2d(dtype=wp.uint8), r: int, c: int, interior: bool) -> wp.vec4i:
    """Vertical Scharr pass of column ``c`` for rows ``r`` and ``r + 1``.

    Returns (smooth(r), diff(r), smooth(r + 1), diff(r + 1)) with smooth = 3 [1 0 1] + 10 and
    diff = I(row + 1) - I(row - 1), rows and column reflected (BORDER_REFLECT_101) unless
    ``interior`` (rows r - 1 .. r + 2 and column c inside the image: direct reads).
    """
    p0 = int(0)
    p1 = int(0)
    p2 = int(0)
    p3 = int(0)
    if interior:
        p0 = int(img[r - 1, c])
        p1 = int(img[r, c])
        p2 = int(img[r + 1, c])
        p3 = int(img[r + 2, c])
    else:
        p0 = read_reflect101(img, r - 1, c)
        p1 = read_reflect101(img, r, c)
        p2 = read_reflect101(img, r + 1, c)
        p3 = read_reflect101(img, r + 2, c)
    return wp.vec4i((p0 + p2) * 3 + p1 * 10, p2 - p0, (p1 + p3) * 3 + p2 * 10, p3 - p1)


@wp.func
def inside(img: wp.array2d(dtype=wp.uint8), r: int, c: int) -> int:
    if r >= 0 and r < img.shape[0] and c >= 0 and c < img.shape[1]:
        return 1
    return 0


@wp.func
def sample_scharr_fixed(
    img: wp.array2d(dtype=wp.uint8), r: int, c: int, iw00: int, iw01: int, iw10: int, iw11: int,
    interior: bool,
) -> wp.vec2i:
    """Fixed-point bilinear sample of the Scharr derivatives (Ix, Iy) at ``(r + b, c + a)``.

    The derivative image is OpenCV's ``calcScharrDeriv`` of the level (int16 values) padded
    with zeros outside the level, so each of the four taps is masked by :func:`inside`.
    ``interior``: rows r - 1 .. r + 2 and columns c - 1 .. c + 2 lie inside the level.
    """
    cm = scharr_column(img, r, c - 1, interior)
    c0 = scharr_column(img, r, c, interior)
    c1 = scharr_column(img, r, c + 1, interior)
    c2 = scharr_column(img, r, c + 2, interior)
    m00 = int(1)
    m01 = int(1)
    m10 = int(1)
    m11 = int(1)
    if not interior:
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


@wp.func
def first_sample(lane: int, win_w: int) -> wp.vec2i:
    """(row, column) of window sample ``lane`` (row-major), a lane's first sample."""
    wy = lane // win_w
    return wp.vec2i(wy, lane - wy * win_w)


@wp.func
def next_sample(rc: wp.vec2i, step: wp.vec2i, win_w: int) -> wp.vec2i:
    """(row, column) ``lanes`` samples further, ``step`` = (lanes // win_w, lanes % win_w)."""
    wy = rc[0] + step[0]
    wx = rc[1] + step[1]
    if wx >= win_w:
        wx -= win_w
        wy += 1
    return wp.vec2i(wy, wx)


@wp.func
def pack_sample(val: int, ix: int, iy: int) -> wp.int64:
    """(value * 32, Ix, Iy), each an int16, in one int64."""
    return (wp.int64(val & 0xFFFF) | (wp.int64(ix & 0xFFFF) << wp.int64(16))
            | (wp.int64(iy & 0xFFFF) << wp.int64(32)))


@wp.func
def unpack_field(p: wp.int64, shift: int) -> int:
    """The sign-extended int16 at bit ``shift`` of ``p``."""
    return int(wp.int16(int((p >> wp.int64(shift)) & wp.int64(0xFFFF))))


@wp.func
def pyramid_level(pyr: Pyramid, k: int) -> wp.array2d(dtype=wp.uint8):
    """Level ``k`` of the launch's levels (``pyr.level0`` is its finest)."""
    if k == 0:
        return pyr.level0
    if k == 1:
        return pyr.level1
    if k == 2:
        return pyr.level2
    if k == 3:
        return pyr.level3
    if k == 4:
        return pyr.level4
    if k == 5:
        return pyr.level5
    if k == 6:
        return pyr.level6
    return pyr.level7


@wp.func
def track_level(
    prev_img: wp.array2d(dtype=wp.uint8),
    next_img: wp.array2d(dtype=wp.uint8),
    patch: wp.array2d(dtype=wp.int64),
    i: int,
    lane: int,
    level: int,
    px: float,
    py: float,
    nx: float,
    ny: float,
    params: TrackParams,
) -> tuple[float, float, bool, float]:
    """Track point ``i`` on one level; lanes split the window.

    ``(px, py)``: the point in ``prev`` and ``(nx, ny)`` the guess in ``next``, both in this
    level's pixels. Returns ``(x, y, alive, err)``: the level's result (the guess itself, or
    the last estimate, where the point is lost), whether it was tracked, and at level 0 the
    mean absolute difference of the windows (0 elsewhere and for lost points). ``patch[i]``
    holds the window of ``prev`` (value * 32, Ix, Iy packed by :func:`pack_sample`) between
    the covariance pass and the iterations; each lane reads back only what it wrote. Lane
    ``lane`` takes samples ``lane + j * lanes``. Every branch depends only on block-uniform
    values (the lanes' sums are block reductions), so all lanes take it together and reach
    the same reductions.
    """
    nlanes = wp.block_dim()
    win_w = params.win_w
    win_h = params.win_h
    area = win_w * win_h
    h = prev_img.shape[0]
    w = prev_img.shape[1]
    start = first_sample(lane, win_w)
    step = first_sample(nlanes, win_w)
    res_x = nx
    res_y = ny

    half_x = float(win_w - 1) * 0.5
    half_y = float(win_h - 1) * 0.5
    x0 = px - half_x
    y0 = py - half_y

    ok = coords_usable(x0, y0)
    ix0 = int(0)
    iy0 = int(0)
    if ok:
        ix0 = int(wp.floor(x0))
        iy0 = int(wp.floor(y0))
        if window_outside(ix0, iy0, win_w, win_h, w, h):
            ok = False
    if not ok:
        return res_x, res_y, False, 0.0

    # Window of prev and covariance matrix of its derivatives. Interior: the samples' taps
    # and their Scharr neighbours (rows iy0 - 1 .. iy0 + win_h + 1, same for columns) all
    # lie inside the level.
    inner = iy0 >= 1 and ix0 >= 1 and iy0 + win_h + 1 < h and ix0 + win_w + 1 < w
    wts = bilinear_weights(x0 - float(ix0), y0 - float(iy0))
    acc = wp.vec3(0.0, 0.0, 0.0)
    k = lane
    rc = start
    while k < area:
        r = iy0 + rc[0]
        c = ix0 + rc[1]
        val = sample_fixed(prev_img, r, c, wts[0], wts[1], wts[2], wts[3])
        d = sample_scharr_fixed(prev_img, r, c, wts[0], wts[1], wts[2], wts[3], inner)
        patch[i, k] = pack_sample(val, d[0], d[1])
        acc += wp.vec3(float(d[0] * d[0]), float(d[0] * d[1]), float(d[1] * d[1]))
        k += nlanes
        rc = next_sample(rc, step, win_w)
    cov = wp.tile_extract(wp.tile_sum(wp.tile(acc, preserve_type=True)), 0)
    a11 = cov[0] * FLT_SCALE
    a12 = cov[1] * FLT_SCALE
    a22 = cov[2] * FLT_SCALE

    det = a11 * a22 - a12 * a12
    min_eig = (a22 + a11 - wp.sqrt((a11 - a22) * (a11 - a22) + 4.0 * a12 * a12)) / float(2 * area)
    if min_eig < params.min_eig_threshold or det < FLT_EPSILON:
        return res_x, res_y, False, 0.0
    inv_det = 1.0 / det

    # Gauss-Newton steps on the window of next.
    alive = bool(True)
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
        rc = start
        while k < area:
            p = patch[i, k]
            val = sample_fixed(next_img, jy + rc[0], jx + rc[1], wj[0], wj[1], wj[2], wj[3])
            diff = val - unpack_field(p, 0)
            bsum += wp.vec2(float(diff * unpack_field(p, 16)), float(diff * unpack_field(p, 32)))
            k += nlanes
            rc = next_sample(rc, step, win_w)
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
                rc = start
                while k < area:
                    val = sample_fixed(next_img, ejy + rc[0], ejx + rc[1], we[0], we[1], we[2], we[3])
                    diff = val - unpack_field(patch[i, k], 0)
                    esum += float(wp.abs(diff))
                    k += nlanes
                    rc = next_sample(rc, step, win_w)
                total = wp.tile_extract(wp.tile_sum(wp.tile(esum)), 0)
                error = total / float(32 * area)
    return res_x, res_y, alive, error


# No grid-stride loop (a thread per lane of a point, never more threads than the launch's):
# 128 registers a lane on sm_90 instead of 154 (at 128 lanes, 4 points fit an SM, not 3; at
# BLOCK_DIM's 256, 2), and measured faster (benchmarks/perf/lk_levels.py, "grid-stride").
@wp.kernel(grid_stride=False)
def track_points(
    prev_pyr: Pyramid,
    next_pyr: Pyramid,
    prev_pts: wp.array2d(dtype=wp.float32),
    guess_pts: wp.array2d(dtype=wp.float32),
    params: TrackParams,
    patch: wp.array2d(dtype=wp.int64),
    tracked_pts: wp.array2d(dtype=wp.float32),
    status: wp.array(dtype=wp.uint8),
    err: wp.array(dtype=wp.float32),
):
    """Track point ``i`` through levels ``params.top`` .. ``params.bottom``, coarse to fine
    (:func:`track_level` on each); lanes split the window. Points are [N, 2] (x, y).

    ``guess_pts`` is the initial flow (``top`` = ``max_level``) or the result of the launch
    of the coarser levels; a level's result, lost point or not, is the next level's guess
    (times 2), as in OpenCV. Lane 0 writes the result of level ``bottom`` to ``tracked_pts``,
    and when that is level 0, ``status`` and ``err`` (status is only cleared at level 0).
    """
    i, lane = wp.tid()
    x = prev_pts[i, 0]
    y = prev_pts[i, 1]
    level = params.top
    nx = float(0.0)
    ny = float(0.0)
    if level == params.max_level:
        scale = 1.0 / float(1 << level)
        if params.use_initial_flow != 0:
            nx = guess_pts[i, 0] * scale
            ny = guess_pts[i, 1] * scale
        else:
            nx = x * scale
            ny = y * scale
    else:
        nx = guess_pts[i, 0] * 2.0
        ny = guess_pts[i, 1] * 2.0
    alive = bool(False)
    error = float(0.0)
    while True:
        scale = 1.0 / float(1 << level)
        k = level - params.bottom
        nx, ny, alive, error = track_level(
            pyramid_level(prev_pyr, k), pyramid_level(next_pyr, k), patch, i, lane, level,
            x * scale, y * scale, nx, ny, params)
        if level == params.bottom:
            break
        nx *= 2.0
        ny *= 2.0
        level -= 1
    if lane == 0:
        tracked_pts[i, 0] = nx
        tracked_pts[i, 1] = ny
        if level == 0:
            if alive:
                status[i] = wp.uint8(1)
                err[i] = error
            else:
                status[i] = wp.uint8(0)
                err[i] = 0.0


class _TrackWorkspace:
    """Scratch of one problem size: pyramid levels for image inputs, the results of coarser
    launches, window patches, and one recorded launch per :data:`LEVELS_PER_LAUNCH` levels."""

    def __init__(self, n, win_w, win_h, max_level, sizes, settings, device, block_dim):
        max_iters, eps, min_eig_threshold, use_initial = settings
        self.levels = {  # levels 1.. of image inputs (level 0 is the input itself)
            which: [wp.empty(hw, dtype=wp.uint8, device=device) for hw in sizes[1:]]
            for which in ("prev", "next")
        }
        # Coarser launches' results ping-pong between two buffers (a launch never reads what
        # it writes); `guess` holds a copy of the initial flow (it may alias the output).
        self.tmp = [wp.empty((n, 2), dtype=wp.float32, device=device) for _ in range(2)]
        self.guess = wp.empty((n, 2), dtype=wp.float32, device=device)
        self.patch = wp.empty((n, win_w * win_h), dtype=wp.int64, device=device)
        self.pyramids = {}  # level arrays' keys -> their Pyramid struct (see pyramid())
        self.cmds = []
        guess = self.guess
        top = max_level
        while top >= 0:
            bottom = max(top - LEVELS_PER_LAUNCH + 1, 0)
            params = TrackParams()
            params.win_w = win_w
            params.win_h = win_h
            params.top = top
            params.bottom = bottom
            params.max_level = max_level
            params.max_iters = int(max_iters)
            params.eps2 = float(eps) * float(eps)
            params.min_eig_threshold = float(min_eig_threshold)
            params.use_initial_flow = 1 if use_initial else 0
            # Placeholders for the per-call arrays (set before each launch).
            imgs = self.pyramid([wp.empty(hw, dtype=wp.uint8, device=device)
                                 for hw in sizes[bottom:top + 1]])
            pts = wp.empty((n, 2), dtype=wp.float32, device=device)
            target = pts if bottom == 0 else self.tmp[len(self.cmds) % 2]
            self.cmds.append((bottom, top, Recorded(
                track_points, [n], device, block_dim=block_dim, prev_pyr=imgs, next_pyr=imgs,
                prev_pts=pts, guess_pts=guess, params=params, patch=self.patch,
                tracked_pts=target, status=wp.empty(n, dtype=wp.uint8, device=device),
                err=wp.empty(n, dtype=wp.float32, device=device))))
            guess = target
            top = bottom - 1

    def pyramid(self, levels) -> Pyramid:
        """A :class:`Pyramid` of ``levels`` (finest first, at most :data:`LEVELS_PER_LAUNCH`),
        made once per set of arrays (pointer, shape, strides) and reused: passing the same
        struct again re-packs nothing. It holds non-owning views, so it keeps no image alive."""
        key = tuple(array_key(a) for a in levels)
        pyr = self.pyramids.get(key)
        if pyr is None:
            if len(self.pyramids) >= _PYRAMIDS_MAX:
                self.pyramids.clear()
            pyr = Pyramid()
            for k, slot in enumerate(Pyramid.vars):
                # Slots past the launch's levels are never read; any valid level fills them.
                setattr(pyr, slot, as_view(levels[min(k, len(levels) - 1)]))
            self.pyramids[key] = pyr
        return pyr


def _build_pyramid(img, n_levels: int, out=None) -> list:
    """Gray pyramid of ``n_levels`` levels (level 0 = ``img``) on ``img``'s device; into
    ``out`` (levels 1..) when given."""
    from .gaussian_pyramid import gaussian_pyramid

    return list(gaussian_pyramid(img, n_levels, out=None if out is None else [img, *out]))


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

    Counted points (:class:`~warpvx._counted.Counted`, a graph's corners): every row is
    tracked (rows are independent; those past the count are simply not part of the value)
    and the results are Counteds of the points' count: ``out``'s own counts (a device copy)
    when ``out`` holds Counteds, else the points' count buffer itself. Plain points into
    Counted ``out``: their counts are set to N.
    """
    counted_in = is_counted(prev_pts)
    count = prev_pts.count if counted_in else None
    if counted_in:
        prev_pts = prev_pts.rows
    device = prev_pts.device
    n = prev_pts.shape[0]
    win_w, win_h = int(win_size[0]), int(win_size[1])

    if out is None:
        res = wp.empty((n, 2), dtype=wp.float32, device=device)
        status = wp.empty(n, dtype=wp.uint8, device=device)
        err = wp.empty(n, dtype=wp.float32, device=device)
        result = (res, status, err) if count is None else \
            tuple(Counted(a, count) for a in (res, status, err))
    else:
        result = tuple(out)
        if is_counted(result[0]):
            _set_counts(result, count, n)
        res, status, err = (o.rows if is_counted(o) else o for o in result)
    if n == 0:
        return result

    n_levels = max_level + 1
    level0 = prev[0] if isinstance(prev, (list, tuple)) else prev
    sizes = [tuple(level0.shape)]
    for _ in range(max_level):
        h, w = sizes[-1]
        sizes.append(((h + 1) // 2, (w + 1) // 2))
    use_initial = next_pts is not None
    settings = (int(max_iters), float(eps), float(min_eig_threshold), use_initial)
    block_dim = BLOCK_DIM
    ws = workspace("optical_flow_pyr_lk", (n, win_w, win_h, max_level, tuple(sizes), settings,
                                           block_dim, LEVELS_PER_LAUNCH, track_points), device,
                   lambda: _TrackWorkspace(n, win_w, win_h, max_level, sizes, settings, device,
                                           block_dim))

    prev_pyr = list(prev) if isinstance(prev, (list, tuple)) else _build_pyramid(
        prev, n_levels, ws.levels["prev"])
    next_pyr = list(next) if isinstance(next, (list, tuple)) else _build_pyramid(
        next, n_levels, ws.levels["next"])
    if use_initial:
        wp.copy(ws.guess, next_pts)
    for bottom, top, cmd in ws.cmds:
        prev_imgs = ws.pyramid(prev_pyr[bottom:top + 1])
        next_imgs = ws.pyramid(next_pyr[bottom:top + 1])
        if bottom == 0:
            cmd.launch(prev_pyr=prev_imgs, next_pyr=next_imgs, prev_pts=prev_pts,
                       tracked_pts=res, status=status, err=err)
        else:
            cmd.launch(prev_pyr=prev_imgs, next_pyr=next_imgs, prev_pts=prev_pts)
    return result


def _set_counts(outs, count, n: int) -> None:
    """Each distinct count buffer of the Counted ``outs``: a copy of ``count`` (device), or
    ``n`` when the points came without one."""
    seen = set()
    for o in outs:
        if o.count.ptr in seen:
            continue
        seen.add(o.count.ptr)
        if count is None:
            o.count.fill_(n)
        elif o.count.ptr != count.ptr:
            wp.copy(o.count, count)


__all__ = ["optical_flow_pyr_lk", "BLOCK_DIM"]
