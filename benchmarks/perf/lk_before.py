"""Pyramidal LK on Warp as of commit 26f41cc (a launch per level, the window patch in global
scratch), frozen for :mod:`benchmarks.perf.lk_harris`'s before/after timing: the level
kernel, its workspace and launches. Its helpers are the current module's (unchanged since).
"""

from __future__ import annotations

import warp as wp

from warpvx.kernels_warp._launch import Recorded
from warpvx.kernels_warp.optical_flow_pyr_lk import (
    FLT_EPSILON, FLT_SCALE, TrackParams, bilinear_weights, coords_usable, first_sample,
    next_sample, pack_sample, sample_fixed, sample_scharr_fixed, unpack_field,
    window_outside)

wp.set_module_options({"enable_backward": False})


@wp.func
def finish_level(i: int, lane: int, level: int, res_x: float, res_y: float, alive: bool,
                 error: float, tracked_pts: wp.array2d(dtype=wp.float32),
                 status: wp.array(dtype=wp.uint8), err: wp.array(dtype=wp.float32)):
    """Lane 0 writes the point's result (status and error at level 0 only)."""
    if lane == 0:
        tracked_pts[i, 0] = res_x
        tracked_pts[i, 1] = res_y
        if level == 0:
            if alive:
                status[i] = wp.uint8(1)
                err[i] = error
            else:
                status[i] = wp.uint8(0)
                err[i] = 0.0


@wp.kernel
def track_points_level(
    prev_img: wp.array2d(dtype=wp.uint8),
    next_img: wp.array2d(dtype=wp.uint8),
    prev_pts: wp.array2d(dtype=wp.float32),
    guess_pts: wp.array2d(dtype=wp.float32),
    params: TrackParams,
    patch: wp.array2d(dtype=wp.int64),
    tracked_pts: wp.array2d(dtype=wp.float32),
    status: wp.array(dtype=wp.uint8),
    err: wp.array(dtype=wp.float32),
):
    """Track point ``i`` on one level; lanes split the window. Points are [N, 2] (x, y).

    ``guess_pts`` is the previous (coarser) level's result, or the initial flow at the top
    level; ``tracked_pts`` receives this level's result. ``status`` and ``err`` are written
    at level 0 only. ``patch[i]`` holds the window of ``prev`` (value * 32, Ix, Iy packed by
    :func:`pack_sample`) between the covariance pass and the iterations; each lane reads
    back only what it wrote. Lane ``lane`` takes samples ``lane + j * lanes``.
    """
    i, lane = wp.tid()
    nlanes = wp.block_dim()
    win_w = params.win_w
    win_h = params.win_h
    area = win_w * win_h
    level = params.level
    h = prev_img.shape[0]
    w = prev_img.shape[1]
    start = first_sample(lane, win_w)
    step = first_sample(nlanes, win_w)

    scale = 1.0 / float(1 << level)
    px = prev_pts[i, 0] * scale
    py = prev_pts[i, 1] * scale
    nx = float(0.0)
    ny = float(0.0)
    if level == params.max_level:
        if params.use_initial_flow != 0:
            nx = guess_pts[i, 0] * scale
            ny = guess_pts[i, 1] * scale
        else:
            nx = px
            ny = py
    else:
        nx = guess_pts[i, 0] * 2.0
        ny = guess_pts[i, 1] * 2.0
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
        finish_level(i, lane, level, res_x, res_y, False, 0.0, tracked_pts, status, err)
        return

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
        finish_level(i, lane, level, res_x, res_y, False, 0.0, tracked_pts, status, err)
        return
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
    finish_level(i, lane, level, res_x, res_y, alive, error, tracked_pts, status, err)


class _TrackWorkspace:
    """Scratch of one problem size: pyramid levels for image inputs, coarse-level results,
    window patches, and one recorded launch per level."""

    def __init__(self, n, win_w, win_h, max_level, sizes, settings, device, block_dim):
        max_iters, eps, min_eig_threshold, use_initial = settings
        self.levels = {  # levels 1.. of image inputs (level 0 is the input itself)
            which: [wp.empty(hw, dtype=wp.uint8, device=device) for hw in sizes[1:]]
            for which in ("prev", "next")
        }
        # Coarser levels' results ping-pong between two buffers (a level never reads what
        # it writes); `guess` holds a copy of the initial flow (it may alias the output).
        self.tmp = [wp.empty((n, 2), dtype=wp.float32, device=device) for _ in range(2)]
        self.guess = wp.empty((n, 2), dtype=wp.float32, device=device)
        self.patch = wp.empty((n, win_w * win_h), dtype=wp.int64, device=device)
        self.cmds = []
        guess = self.guess
        for level in range(max_level, -1, -1):
            params = TrackParams()
            params.win_w = win_w
            params.win_h = win_h
            params.level = level
            params.max_level = max_level
            params.max_iters = int(max_iters)
            params.eps2 = float(eps) * float(eps)
            params.min_eig_threshold = float(min_eig_threshold)
            params.use_initial_flow = 1 if use_initial else 0
            # Placeholders for the per-call arrays (set before each launch).
            img = wp.empty(sizes[level], dtype=wp.uint8, device=device)
            pts = wp.empty((n, 2), dtype=wp.float32, device=device)
            target = pts if level == 0 else self.tmp[level % 2]
            self.cmds.append((level, Recorded(
                track_points_level, [n], device, block_dim=block_dim, prev_img=img,
                next_img=img, prev_pts=pts, guess_pts=guess, params=params, patch=self.patch,
                tracked_pts=target, status=wp.empty(n, dtype=wp.uint8, device=device),
                err=wp.empty(n, dtype=wp.float32, device=device))))
            guess = target


_WORKSPACES: dict = {}


def track(prev_pyr, next_pyr, prev_pts, out, settings, block_dim: int):
    """The old ``optical_flow_pyr_lk`` on lists of levels (no initial flow) into ``out``
    (next_pts, status, err); ``settings`` = (win_w, win_h, max_level, max_iters, eps,
    min_eig_threshold). Recorded once per problem, as the old module did."""
    win_w, win_h, max_level, max_iters, eps, min_eig = settings
    n = prev_pts.shape[0]
    device = prev_pts.device
    sizes = [tuple(a.shape) for a in prev_pyr[:max_level + 1]]
    key = (n, tuple(sizes), tuple(settings), block_dim, str(device))
    ws = _WORKSPACES.get(key)
    if ws is None:
        ws = _WORKSPACES[key] = _TrackWorkspace(n, win_w, win_h, max_level, sizes,
                                          (max_iters, eps, min_eig, False), device, block_dim)
    res, status, err = out
    for level, cmd in ws.cmds:
        if level == 0:
            cmd.launch(prev_img=prev_pyr[0], next_img=next_pyr[0], prev_pts=prev_pts,
                       tracked_pts=res, status=status, err=err)
        else:
            cmd.launch(prev_img=prev_pyr[level], next_img=next_pyr[level], prev_pts=prev_pts)
