"""The ORB extractor with the quadtree on the host: per-level launches, one host sync.

What a frame takes when it overflows its plan's capacities (:meth:`.plan.OrbPlan.run`), and the
"before" reference of ``benchmarks/perf/orb.py``; same result as the one-graph path.
"""

from __future__ import annotations

import functools

import numpy as np
import warp as wp

from ... import _orb_spec as spec
from ..._orb_quadtree import distribute_octtree
from ...keypoints import Keypoints
from ..fast_corners import fast_score
from ..gaussian_blur import gaussian_blur
from ..scale_pyramid import scale_pyramid
from .funcs import (KEY_LEVEL_SHIFT, KEY_X_SHIFT, KEY_Y_SHIFT, candidate_key, describe_byte,
                    ic_angle, neighbour_in_cell, round_coord)

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

# --------------------------------------------------------------------------------------------
# Kernels of the host-quadtree path (extract_host: fallback, and the reference for timings)
# --------------------------------------------------------------------------------------------


@wp.kernel
def score_cells(img: wp.array2d(dtype=wp.uint8), row_of_y: wp.array(dtype=wp.int32),
                col_of_x: wp.array(dtype=wp.int32), threshold: int,
                scores: wp.array2d(dtype=wp.int32)):
    """FAST score at ``threshold`` on the pixels a cell owns (>= 19 px inside), 0 elsewhere."""
    y, x = wp.tid()
    s = int(0)
    if row_of_y[y] >= 0 and col_of_x[x] >= 0:
        s = fast_score(img, y, x, threshold)
    scores[y, x] = s


@wp.kernel
def suppress_in_cells(scores: wp.array2d(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
                      col_of_x: wp.array(dtype=wp.int32), n_cols: int, ini_th: int,
                      kept: wp.array2d(dtype=wp.int32), strong_count: wp.array(dtype=wp.int32)):
    """OpenCV's strict 3x3 maximum within the cell; count the survivors >= ``ini_th`` per cell."""
    y, x = wp.tid()
    s = scores[y, x]
    keep = int(0)
    if s > 0:
        cr = row_of_y[y]
        cc = col_of_x[x]
        keep = s
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if dy != 0 or dx != 0:
                    if neighbour_in_cell(scores, row_of_y, col_of_x, y + dy, x + dx, cr, cc) >= s:
                        keep = 0
        if keep >= ini_th:
            wp.atomic_add(strong_count, cr * n_cols + cc, 1)
    kept[y, x] = keep


@wp.kernel
def collect_cells(kept: wp.array2d(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
                  col_of_x: wp.array(dtype=wp.int32), n_cols: int,
                  strong_count: wp.array(dtype=wp.int32), ini_th: int, min_th: int, level: int,
                  count: wp.array(dtype=wp.int32), keys: wp.array(dtype=wp.int64)):
    """Append each survivor at or above its cell's threshold as a key (see KEY_*)."""
    y, x = wp.tid()
    s = kept[y, x]
    if s > 0:
        cell = row_of_y[y] * n_cols + col_of_x[x]
        th = min_th
        if strong_count[cell] > 0:
            th = ini_th
        if s >= th:
            slot = wp.atomic_add(count, 0, 1)
            # The capacity is a proven bound; the guard only keeps a bug from writing out of bounds.
            if slot < keys.shape[0]:
                keys[slot] = candidate_key(level, cell, y, x, s)


@wp.kernel
def compute_angles(img: wp.array2d(dtype=wp.uint8), kps: wp.array2d(dtype=wp.int32), first: int,
                   angle: wp.array(dtype=wp.float32)):
    """IC_Angle of keypoint ``first + i`` (level coordinates in kps[:, 0:2])."""
    i = wp.tid() + first
    angle[i] = ic_angle(img, kps[i, 1], kps[i, 0])


@wp.kernel
def describe_extracted(img: wp.array2d(dtype=wp.uint8), kps: wp.array2d(dtype=wp.int32),
                       angle: wp.array(dtype=wp.float32), first: int,
                       pattern: wp.array2d(dtype=wp.int32), desc: wp.array2d(dtype=wp.uint8)):
    """Descriptor byte ``j`` of keypoint ``first + i`` (integer level coordinates)."""
    i, j = wp.tid()
    k = i + first
    desc[k, j] = wp.uint8(describe_byte(img, kps[k, 1], kps[k, 0], angle[k], pattern, j))


@wp.kernel
def describe_keypoints(img: wp.array2d(dtype=wp.uint8), x: wp.array(dtype=wp.float32),
                       y: wp.array(dtype=wp.float32), angle: wp.array(dtype=wp.float32),
                       index: wp.array(dtype=wp.int32), inv_scale: float,
                       pattern: wp.array2d(dtype=wp.int32), desc: wp.array2d(dtype=wp.uint8)):
    """Descriptor byte ``j`` of keypoint ``index[i]`` given at level 0: centre cvRound(p / s)."""
    i, j = wp.tid()
    k = index[i]
    cx = round_coord(x[k] * inv_scale)
    cy = round_coord(y[k] * inv_scale)
    # Centres clamped into the level: reads stay inside whatever the input was.
    cx = wp.clamp(cx, 0, img.shape[1] - 1)
    cy = wp.clamp(cy, 0, img.shape[0] - 1)
    desc[k, j] = wp.uint8(describe_byte(img, cy, cx, angle[k], pattern, j))


@wp.kernel
def scale_back_keypoints(kps: wp.array2d(dtype=wp.int32), scales: wp.array(dtype=wp.float32),
                         sizes: wp.array(dtype=wp.float32), kp_x: wp.array(dtype=wp.float32),
                         kp_y: wp.array(dtype=wp.float32), kp_response: wp.array(dtype=wp.float32),
                         kp_size: wp.array(dtype=wp.float32), kp_octave: wp.array(dtype=wp.int32)):
    """Keypoint fields at level 0: (x, y) s_l, response, ORB-SLAM2's size, octave."""
    i = wp.tid()
    level = kps[i, 3]
    s = scales[level]
    kp_x[i] = float(kps[i, 0]) * s
    kp_y[i] = float(kps[i, 1]) * s
    kp_response[i] = float(kps[i, 2])
    kp_size[i] = sizes[level]
    kp_octave[i] = level


# --------------------------------------------------------------------------------------------
# Host side: per-device constants
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _pattern_on(device: str):
    return wp.array(np.ascontiguousarray(spec.pattern()), dtype=wp.int32, device=device)


@functools.lru_cache(maxsize=64)
def _grid_on(width: int, height: int, device: str):
    grid = spec.cell_grid(width, height)
    return (grid, wp.array(np.ascontiguousarray(grid.row_of_y), dtype=wp.int32, device=device),
            wp.array(np.ascontiguousarray(grid.col_of_x), dtype=wp.int32, device=device))


@functools.lru_cache(maxsize=16)
def _level_tables_on(scale_factor: float, n_levels: int, device: str):
    """(s_l, ORB-SLAM2's keypoint size) per level as float32 device arrays."""
    return (wp.array(spec.level_scales(scale_factor, n_levels), dtype=wp.float32, device=device),
            wp.array(spec.keypoint_sizes(scale_factor, n_levels), dtype=wp.float32, device=device))


def _capacity(grid) -> int:
    """Most survivors a level can have: strict 3x3 maxima inside one cell cannot touch."""
    rows = sum((b - a - 6 + 1) // 2 for a, b in grid.row_spans if b - a > 6)
    cols = sum((b - a - 6 + 1) // 2 for a, b in grid.col_spans if b - a > 6)
    return rows * cols


# --------------------------------------------------------------------------------------------
# The host-quadtree stages (extract_host)
# --------------------------------------------------------------------------------------------


def build_pyramid(src, scale_factor: float, n_levels: int) -> list:
    """ORB-SLAM2's scale pyramid on the device (``kernels_warp.scale_pyramid``)."""
    return scale_pyramid(src, n_levels, scale_factor)


def detect_and_select(pyramid: list, ini_th: int, min_th: int):
    """FAST per cell and the per-cell threshold on every level, launched back to back.

    Returns ``(count, keys)``: a device counter and an int64 key buffer (KEY_* layout) holding
    every level's candidates in no particular order (capacity: a proven bound).
    """
    device = pyramid[0].device
    grids = [_grid_on(int(img.shape[1]), int(img.shape[0]), str(device)) for img in pyramid]
    capacity = max(1, sum(_capacity(g[0]) for g in grids))
    count = wp.zeros(1, dtype=wp.int32, device=device)
    keys = wp.empty(capacity, dtype=wp.int64, device=device)
    low = min(ini_th, min_th)
    for level, (img, (grid, row_of_y, col_of_x)) in enumerate(zip(pyramid, grids)):
        h, w = int(img.shape[0]), int(img.shape[1])
        scores = wp.empty((h, w), dtype=wp.int32, device=device)
        kept = wp.empty((h, w), dtype=wp.int32, device=device)
        strong = wp.zeros(max(1, grid.n_rows * grid.n_cols), dtype=wp.int32, device=device)
        wp.launch(score_cells, dim=(h, w), inputs=[img, row_of_y, col_of_x, low],
                  outputs=[scores], device=device)
        wp.launch(suppress_in_cells, dim=(h, w),
                  inputs=[scores, row_of_y, col_of_x, grid.n_cols, ini_th],
                  outputs=[kept, strong], device=device)
        wp.launch(collect_cells, dim=(h, w),
                  inputs=[kept, row_of_y, col_of_x, grid.n_cols, strong, ini_th, min_th, level],
                  outputs=[count, keys], device=device)
    return count, keys


def distribute(count, keys, pyramid: list, wanted: list) -> np.ndarray:
    """The quadtree on the host: int32 [N, 4] (x, y, score, level) kept, level by level.

    Host sync: reads the candidate count, then the keys; sorting the keys puts the candidates
    in ORB-SLAM2's order.
    """
    n = min(int(count.numpy()[0]), keys.shape[0])
    k = np.sort(keys[:n].numpy()) if n else np.zeros(0, np.int64)
    level = k >> int(KEY_LEVEL_SHIFT)
    bounds = np.searchsorted(level, np.arange(len(pyramid) + 1))
    y = ((k >> int(KEY_Y_SHIFT)) & 0xFFFF).astype(np.int32)
    x = ((k >> int(KEY_X_SHIFT)) & 0xFFFF).astype(np.int32)
    score = (k & 0xFF).astype(np.int32)
    out = []
    for lv, img in enumerate(pyramid):
        grid = spec.cell_grid(int(img.shape[1]), int(img.shape[0]))
        a, b = bounds[lv], bounds[lv + 1]
        chosen = a + distribute_octtree(x[a:b], y[a:b], score[a:b], grid, wanted[lv])
        out.append(np.stack([x[chosen], y[chosen], score[chosen],
                             np.full(chosen.size, lv, np.int32)], axis=1))
    return np.ascontiguousarray(np.concatenate(out, axis=0), dtype=np.int32)


def compute_orientation(pyramid: list, kps, first: list, counts: list, angle) -> None:
    """IC_Angle of every keypoint (one launch per level, on the unblurred level)."""
    for img, f, n in zip(pyramid, first, counts):
        if n:
            wp.launch(compute_angles, dim=n, inputs=[img, kps, f], outputs=[angle],
                      device=img.device)


def blur_levels(pyramid: list, out: list | None = None) -> list:
    """The 7x7, sigma 2, BORDER_REFLECT_101 Gaussian of each level
    (``kernels_warp.gaussian_blur``), into ``out`` when given."""
    outs = out if out is not None else [None] * len(pyramid)
    return [gaussian_blur(img, (7, 7), 2.0, "reflect101", out=o) for img, o in zip(pyramid, outs)]


def compute_descriptors(blurred: list, kps, angle, first: list, counts: list, desc) -> None:
    """Rotated BRIEF of every keypoint, one thread per (keypoint, byte)."""
    for img, f, n in zip(blurred, first, counts):
        if n:
            pat = _pattern_on(str(img.device))
            wp.launch(describe_extracted, dim=(n, spec.DESCRIPTOR_BYTES),
                      inputs=[img, kps, angle, f, pat], outputs=[desc], device=img.device)


def scale_back(kps, angle, scale_factor: float, n_levels: int) -> Keypoints:
    """Keypoints at level 0 (device arrays)."""
    device = kps.device
    n = kps.shape[0]
    fields = {f: wp.empty(n, dtype=wp.float32, device=device)
              for f in ("x", "y", "response", "size")}
    octave = wp.empty(n, dtype=wp.int32, device=device)
    if n:
        scales, sizes = _level_tables_on(float(scale_factor), n_levels, str(device))
        wp.launch(scale_back_keypoints, dim=n, inputs=[kps, scales, sizes],
                  outputs=[fields["x"], fields["y"], fields["response"], fields["size"], octave],
                  device=device)
    return Keypoints(x=fields["x"], y=fields["y"], response=fields["response"],
                     size=fields["size"], angle=angle, octave=octave)


def extract_host(pyramid: list, n_features: int, scale_factor: float, ini_th: int, min_th: int,
                 blurred: list | None = None):
    """FAST, per-cell threshold, quadtree on the host, orientation, blur, descriptors, scale
    back: one launch per level and stage, a host sync for the candidates.

    What :func:`orb` does when a frame overflows its plan's capacities (the same result).
    """
    n_levels = len(pyramid)
    device = pyramid[0].device
    wanted = spec.features_per_level(n_features, scale_factor, n_levels)
    count, keys = detect_and_select(pyramid, ini_th, min_th)
    chosen = distribute(count, keys, pyramid, wanted)
    counts = np.bincount(chosen[:, 3], minlength=n_levels).tolist() if chosen.size else \
        [0] * n_levels
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
    n = chosen.shape[0]
    kps = wp.array(chosen.reshape(n, 4), dtype=wp.int32, device=device)
    angle = wp.empty(n, dtype=wp.float32, device=device)
    desc = wp.empty((n, spec.DESCRIPTOR_BYTES), dtype=wp.uint8, device=device)
    if n:
        compute_orientation(pyramid, kps, first, counts, angle)
        compute_descriptors(blurred if blurred is not None else blur_levels(pyramid), kps, angle,
                            first, counts, desc)
    return scale_back(kps, angle, scale_factor, n_levels), desc


def orb_host_quadtree(src, n_features: int, scale_factor: float, n_levels: int, ini_th_fast: int,
                      min_th_fast: int):
    """The extractor with the quadtree on the host (per-level launches, no graph)."""
    pyramid = build_pyramid(src, scale_factor, n_levels)
    return extract_host(pyramid, n_features, scale_factor, ini_th_fast, min_th_fast)


