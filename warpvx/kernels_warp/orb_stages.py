"""Warp implementations of the per-level ORB stage nodes of :func:`warpvx.orb_graph` (SPEC §6).

Each function is one stage on one pyramid level, on ``wp.array`` inputs on the level's
device, and returns what the stage's CPU implementation (:mod:`warpvx.kernels_cpu.orb`)
returns, bit for bit, so a graph may place each node on either side:

``fast``        FAST-9/16 per 30x30 cell at the lower threshold, cell-local non-max:
                ``(x, y, score)`` int32 [N] in ORB-SLAM2's order (cell row, cell column, y, x)
``grid``        the per-cell threshold: the same three arrays, the kept points, order kept
``quadtree``    ORB-SLAM2's ``DistributeOctTree`` computed in parallel: the fused
                extractor's device quadtree (:class:`~warpvx.kernels_warp.orb.OrbPlan`) run
                on one level (a one-level plan per level size, from the extractor's pool)
``angle``       intensity-centroid orientation, float32 degrees [N]
``describe``    rotated BRIEF on the blurred level, uint8 [N, 32]
``scale_back``  level-0 keypoint fields (x, y, response, size, angle, octave)
``handoff``     the levels joined into one set of fields and descriptors

Point lists have exact lengths (the CPU stages' form), so a stage that selects points reads
its count on the host once (one sync); the fused ``warpvx.orb`` avoids those syncs by running
every level and stage in one captured graph.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from .. import _orb_spec as spec
from .._orb_quadtree import distribute_octtree
from .orb.funcs import (C_CAND, C_FINAL, KEY_LEVEL_SHIFT, KEY_X_SHIFT, KEY_Y_SHIFT, PATH_DEPTH,
                        PATH_ROOT_SHIFT, LevelInfo, candidate_key, ic_angle, key_field,
                        quadtree_path)
from .orb.brief import describe_points
from .orb.host import _grid_on, _pattern_on, collect_cells, score_cells, suppress_in_cells
from .orb.kernels import gather_paths
from .orb.plan import OrbPlan, acquire, release

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})


# --------------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------------


@wp.func
def cell_of(row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32), n_cols: int,
            x: int, y: int) -> int:
    """The index of the cell owning pixel (x, y) (row-major over the level's cell grid)."""
    return row_of_y[y] * n_cols + col_of_x[x]


@wp.kernel
def unpack_keys(keys: wp.array(dtype=wp.int64), x: wp.array(dtype=wp.int32),
                y: wp.array(dtype=wp.int32), score: wp.array(dtype=wp.int32)):
    i = wp.tid()
    k = keys[i]
    x[i] = key_field(k, KEY_X_SHIFT, 0xFFFF)
    y[i] = key_field(k, KEY_Y_SHIFT, 0xFFFF)
    score[i] = key_field(k, 0, 0xFF)


@wp.kernel
def count_strong(x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                 score: wp.array(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
                 col_of_x: wp.array(dtype=wp.int32), n_cols: int, ini_th: int,
                 strong: wp.array(dtype=wp.int32)):
    """Points >= ``ini_th`` per cell."""
    i = wp.tid()
    if score[i] >= ini_th:
        wp.atomic_add(strong, cell_of(row_of_y, col_of_x, n_cols, x[i], y[i]), 1)


@wp.kernel
def flag_kept(x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
              score: wp.array(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
              col_of_x: wp.array(dtype=wp.int32), n_cols: int, strong: wp.array(dtype=wp.int32),
              ini_th: int, min_th: int, flags: wp.array(dtype=wp.int32)):
    """1 where a point reaches its cell's threshold (``ini_th`` if the cell has such a point)."""
    i = wp.tid()
    th = min_th
    if strong[cell_of(row_of_y, col_of_x, n_cols, x[i], y[i])] > 0:
        th = ini_th
    flags[i] = wp.where(score[i] >= th, 1, 0)


@wp.kernel
def compact_points(flags: wp.array(dtype=wp.int32), at: wp.array(dtype=wp.int32),
                   x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                   score: wp.array(dtype=wp.int32), out_x: wp.array(dtype=wp.int32),
                   out_y: wp.array(dtype=wp.int32), out_score: wp.array(dtype=wp.int32)):
    """Flagged points to their slot, ``at`` the inclusive scan of the flags (order kept)."""
    i = wp.tid()
    if flags[i] != 0:
        j = at[i] - 1
        out_x[j] = x[i]
        out_y[j] = y[i]
        out_score[j] = score[i]


@wp.kernel
def seed_quadtree(x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                  score: wp.array(dtype=wp.int32), levels: wp.array(dtype=LevelInfo),
                  row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                  roots: wp.array(dtype=wp.int32), digits: int, n: int,
                  counters: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                  paths: wp.array(dtype=wp.int64), sort_keys: wp.array(dtype=wp.int64),
                  order: wp.array(dtype=wp.int32)):
    """A one-level plan's candidate buffers from a point list: point i's candidate key, its
    quadtree path, the path's sort key (root | first ``digits`` quadrants) and slot i (what
    the fused extractor's ``select_candidates`` writes for level 0)."""
    i = wp.tid()
    if i == 0:
        counters[C_CAND] = n
    cell = cell_of(row_of_y, col_of_x, levels[0].n_cols, x[i], y[i])
    cand[i] = candidate_key(0, cell, y[i], x[i], score[i])
    path = quadtree_path(0, x[i], y[i], levels, roots)
    paths[i] = path
    root = (path >> wp.int64(PATH_ROOT_SHIFT)) & wp.int64(511)
    kept = (path & wp.int64(0xFFFFFFFF)) >> wp.int64(2 * (PATH_DEPTH - digits))
    sort_keys[i] = (root << wp.int64(2 * digits)) | kept
    order[i] = i


@wp.kernel
def gather_finals(counters: wp.array(dtype=wp.int32), index: wp.array(dtype=wp.int32),
                  x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                  score: wp.array(dtype=wp.int32), out_x: wp.array(dtype=wp.int32),
                  out_y: wp.array(dtype=wp.int32), out_score: wp.array(dtype=wp.int32)):
    """The quadtree's kept points (``index``: the final nodes' points, counters[C_FINAL] of
    them), in its order."""
    i = wp.tid()
    if i >= wp.min(counters[C_FINAL], out_x.shape[0]):
        return
    k = index[i]
    out_x[i] = x[k]
    out_y[i] = y[k]
    out_score[i] = score[k]


@wp.kernel
def orient_points(img: wp.array2d(dtype=wp.uint8), x: wp.array(dtype=wp.int32),
                  y: wp.array(dtype=wp.int32), angle: wp.array(dtype=wp.float32)):
    i = wp.tid()
    angle[i] = ic_angle(img, y[i], x[i])


@wp.kernel
def level_fields(x: wp.array(dtype=wp.int32), y: wp.array(dtype=wp.int32),
                 score: wp.array(dtype=wp.int32), scale: float, size: float, level: int,
                 out_x: wp.array(dtype=wp.float32), out_y: wp.array(dtype=wp.float32),
                 response: wp.array(dtype=wp.float32), out_size: wp.array(dtype=wp.float32),
                 octave: wp.array(dtype=wp.int32)):
    """Level-0 fields: (x s_l, y s_l) in float32, the score, ORB-SLAM2's size, the level."""
    i = wp.tid()
    out_x[i] = float(x[i]) * scale
    out_y[i] = float(y[i]) * scale
    response[i] = float(score[i])
    out_size[i] = size
    octave[i] = level


# --------------------------------------------------------------------------------------------
# Stages
# --------------------------------------------------------------------------------------------


def _points(n: int, device) -> tuple:
    return tuple(wp.empty(n, dtype=wp.int32, device=device) for _ in range(3))


def _count(counter) -> int:
    """A device counter read on the host (the stage's one sync)."""
    return int(counter.numpy()[0])


def fast(level, threshold: int) -> tuple:
    """FAST-9/16 per cell at ``threshold`` with the cell's own non-max suppression.

    ``level``: uint8 [H, W]. Returns ``(x, y, score)`` int32 [N] (level coordinates), sorted
    as ORB-SLAM2 hands them on (``kernels_cpu.orb.detect_cells``).
    """
    device = level.device
    h, w = int(level.shape[0]), int(level.shape[1])
    grid, row_of_y, col_of_x = _grid_on(w, h, str(device))
    scores = wp.empty((h, w), dtype=wp.int32, device=device)
    kept = wp.empty((h, w), dtype=wp.int32, device=device)
    # suppress_in_cells and collect_cells apply the fused path's grid rule; the Grid stage
    # applies it on its own, so here no cell has a strong point (no score reaches 256) and
    # every survivor passes the threshold of 1.
    no_strong = wp.zeros(max(1, grid.n_rows * grid.n_cols), dtype=wp.int32, device=device)
    wp.launch(score_cells, dim=(h, w), inputs=[level, row_of_y, col_of_x, int(threshold)],
              outputs=[scores], device=device)
    wp.launch(suppress_in_cells, dim=(h, w), inputs=[scores, row_of_y, col_of_x, grid.n_cols, 256],
              outputs=[kept, no_strong], device=device)
    # Strict 3x3 maxima cannot touch: at most one pixel in each 2x2 block survives. Twice
    # that for the radix sort's scratch half.
    cap = max(1, ((h + 1) // 2) * ((w + 1) // 2))
    count = wp.zeros(1, dtype=wp.int32, device=device)
    keys = wp.empty(2 * cap, dtype=wp.int64, device=device)
    wp.launch(collect_cells, dim=(h, w),
              inputs=[kept, row_of_y, col_of_x, grid.n_cols, no_strong, 256, 1, 0],
              outputs=[count, keys], device=device)
    n = _count(count)
    out = _points(n, device)
    if n:
        slots = wp.empty(2 * n, dtype=wp.int32, device=device)  # the sort's values: unused
        wp.utils.radix_sort_pairs(keys, slots, n, 0, int(KEY_LEVEL_SHIFT))
        wp.launch(unpack_keys, dim=n, inputs=[keys], outputs=list(out), device=device)
    return out


def grid(level, x, y, score, ini_th: int, min_th: int) -> tuple:
    """The per-cell threshold: the points >= ``ini_th`` of a cell that has one, else those
    >= ``min_th`` (``kernels_cpu.orb.select_cells``); ``(x, y, score)`` kept, order kept."""
    device = x.device
    n = int(x.shape[0])
    if n == 0:
        return _points(0, device)
    g, row_of_y, col_of_x = _grid_on(int(level.shape[1]), int(level.shape[0]), str(device))
    strong = wp.zeros(max(1, g.n_rows * g.n_cols), dtype=wp.int32, device=device)
    wp.launch(count_strong, dim=n, inputs=[x, y, score, row_of_y, col_of_x, g.n_cols, int(ini_th)],
              outputs=[strong], device=device)
    flags = wp.empty(n, dtype=wp.int32, device=device)
    wp.launch(flag_kept, dim=n, inputs=[x, y, score, row_of_y, col_of_x, g.n_cols, strong,
                                        int(ini_th), int(min_th)],
              outputs=[flags], device=device)
    at = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(flags, at, inclusive=True)
    kept = _count(at[n - 1:])
    out = _points(kept, device)
    if kept:
        wp.launch(compact_points, dim=n, inputs=[flags, at, x, y, score], outputs=list(out),
                  device=device)
    return out


def quadtree(level, x, y, score, n_wanted: int, scale_factor: float) -> tuple:
    """ORB-SLAM2's ``DistributeOctTree`` on the device: the points it keeps, in its order.

    The fused extractor's parallel quadtree (sort by quadtree path, node counts per depth,
    the division plan, the ordered rounds, the strongest point of each final node) on a
    one-level plan of this level's size; a list past the plan's capacities takes the host
    quadtree (``_orb_quadtree.distribute_octtree``), as the fused extractor does: the result
    never depends on capacity. Returns ``(x, y, score)`` int32 [n_kept].
    """
    device = x.device
    n = int(x.shape[0])
    if n == 0:
        return _points(0, device)
    h, w = int(level.shape[0]), int(level.shape[1])
    key = ("stage-quadtree", str(device), h, w, int(n_wanted))
    plan = acquire(key, lambda: OrbPlan(device, h, w, int(n_wanted), float(scale_factor), 1,
                                        0, 0, graph=False))
    try:
        kept = None
        if n <= plan.cand_cap:
            plan.counters.zero_()
            wp.launch(seed_quadtree, dim=n,
                      inputs=[x, y, score, plan.level_info, plan.row_of_y, plan.col_of_x,
                              plan.roots, plan.digits, n],
                      outputs=[plan.counters[0], plan.cand[0], plan.paths[0], plan.sort_keys,
                               plan.order],
                      device=device)
            wp.utils.radix_sort_pairs(plan.sort_keys, plan.order, n, 0, plan.sort_bits)
            wp.launch(gather_paths, dim=n,
                      inputs=[1, plan.order, plan.flat["counters"], plan.flat["paths"]],
                      outputs=[plan.flat["sorted_paths"]], device=device)
            plan.stage_nodes()
            plan.stage_finals()
            # Gathered into fresh buffers before the one sync: once it returns, nothing queued
            # reads the plan, so it can go back to the pool (another stream may take it).
            finals = _points(plan.final_cap, device)
            wp.launch(gather_finals, dim=plan.final_cap,
                      inputs=[plan.counters[0], plan.final_values, x, y, score],
                      outputs=list(finals), device=device)
            plan.stage_heads()
            head = plan.read_head()[0]
            if not plan.overflowed(head):
                m = int(head[C_FINAL])
                kept = tuple(a[:m] for a in finals)
    finally:
        release(key, plan)
    if kept is None:
        hx, hy, hs = x.numpy(), y.numpy(), score.numpy()
        chosen = distribute_octtree(hx, hy, hs, spec.cell_grid(w, h), int(n_wanted))
        kept = tuple(wp.array(a[chosen], dtype=wp.int32, device=device) for a in (hx, hy, hs))
    return kept


def angle(level, x, y):
    """float32 [N] degrees: ORB-SLAM2's ``IC_Angle`` on the unblurred ``level`` (uint8 [H, W])."""
    out = wp.empty(int(x.shape[0]), dtype=wp.float32, device=x.device)
    if out.shape[0]:
        wp.launch(orient_points, dim=out.shape[0], inputs=[level, x, y], outputs=[out],
                  device=x.device)
    return out


def describe(blurred, x, y, angle_deg):
    """uint8 [N, 32]: rotated BRIEF of the points on the blurred level (uint8 [H, W])."""
    n = int(x.shape[0])
    out = wp.empty((n, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=x.device)
    if n:
        wp.launch(describe_points, dim=(n, spec.DESCRIPTOR_BYTES),
                  inputs=[blurred, x, y, angle_deg, _pattern_on(str(x.device))], outputs=[out],
                  device=x.device)
    return out


def scale_back(x, y, score, angle_deg, level: int, scale_factor: float, n_levels: int) -> tuple:
    """Level ``level``'s points as level-0 keypoint fields: x, y, response, size, angle
    (float32 [N]) and octave (int32 [N]); ``angle_deg`` is passed through."""
    device = x.device
    n = int(x.shape[0])
    fx, fy, resp, size = (wp.empty(n, dtype=wp.float32, device=device) for _ in range(4))
    octave = wp.empty(n, dtype=wp.int32, device=device)
    if n:
        s = spec.level_scales(scale_factor, n_levels)[level]
        kp_size = spec.keypoint_sizes(scale_factor, n_levels)[level]
        wp.launch(level_fields, dim=n, inputs=[x, y, score, float(s), float(kp_size), int(level)],
                  outputs=[fx, fy, resp, size, octave], device=device)
    return fx, fy, resp, size, angle_deg, octave


def concatenate(arrays: list):
    """The arrays (one dtype, equal trailing shape, contiguous) joined along axis 0."""
    first = arrays[0]
    rest = tuple(first.shape[1:])
    row = int(np.prod(rest, dtype=np.int64))
    total = sum(int(a.shape[0]) for a in arrays)
    flat = wp.empty(total * row, dtype=first.dtype, device=first.device)
    at = 0
    for a in arrays:
        count = int(a.shape[0]) * row
        if count:
            wp.copy(flat, a.flatten(), at, 0, count)
        at += count
    return flat.reshape((total, *rest)) if rest else flat


def handoff(*parts, n_fields: int) -> tuple:
    """The levels' outputs joined: ``parts`` are ``n_fields`` arrays per level, levels in
    order (the CPU hand-off, ``np.concatenate`` per field); one array per field."""
    return tuple(concatenate(list(parts[i::n_fields])) for i in range(n_fields))
