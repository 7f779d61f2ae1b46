"""ORB-SLAM2's ORB extractor on Warp, stage by stage (see :mod:`warpvx.kernels_cpu.orb`).

The image and its pyramid stay on the device. Per level:

``detect_and_select``  FAST-9/16 scores at the lower threshold on the pixels a
    30x30 cell owns (``score_cells``), non-max suppression inside each cell, as ORB-SLAM2's
    per-cell ``FAST`` sees it (``suppress_in_cells``: a neighbour in another cell counts as 0),
    a count per cell of the points >= iniThFAST, then every survivor >= the cell's threshold
    (iniThFAST when the cell has such a point, else minThFAST) is appended to one key buffer
    for all levels (``collect_cells``).
``distribute``  the quadtree is sequential (ORB-SLAM2's ``DistributeOctTree``, a node list
    whose order decides the result): the candidates are copied down to the host (the one
    sync: a count, then the keys), distributed there by the shared
    :func:`warpvx.kernels_cpu.orb.distribute_octtree`, and the chosen ones copied back up.
``compute_angles``  ``IC_Angle``, one thread per keypoint.
``blur_levels``  7x7 sigma 2 Gaussian, BORDER_REFLECT_101 (``kernels_warp.gaussian_blur``).
``describe_extracted``  rotated BRIEF, one thread per (keypoint, byte).
``scale_back_keypoints``  level coordinates times s_l, and the Keypoints fields.
"""

from __future__ import annotations

import functools

import numpy as np
import warp as wp

from ..kernels_cpu import orb as ref
from ..keypoints import Keypoints
from ._sampling import BORDER_REFLECT_101, border_index, round_coord
from .fast_corners import fast_score
from .gaussian_blur import gaussian_blur
from .scale_pyramid import scale_pyramid

vec16i = wp.types.vector(length=16, dtype=wp.int32)

UMAX = wp.constant(vec16i(*[int(v) for v in ref.umax()]))
HALF_PATCH = wp.constant(ref.HALF_PATCH_SIZE)
ATAN_P1 = wp.constant(wp.float32(ref.ATAN_P1))
ATAN_P3 = wp.constant(wp.float32(ref.ATAN_P3))
ATAN_P5 = wp.constant(wp.float32(ref.ATAN_P5))
ATAN_P7 = wp.constant(wp.float32(ref.ATAN_P7))
ATAN_EPS = wp.constant(wp.float32(ref.ATAN_EPS))
DEG_TO_RAD = wp.constant(wp.float32(np.float32(np.pi / 180.0)))

# Candidate keys, int64: level (5 bits) | cell (18) | y (16) | x (16) | score (8), so that
# sorting the keys sorts the candidates in ORB-SLAM2's order (level, cell row, cell column,
# y, x) and no key is negative. Images up to kernels_cpu.orb.MAX_SIDE px a side fit.
KEY_LEVEL_SHIFT = wp.constant(58)
KEY_CELL_SHIFT = wp.constant(40)
KEY_Y_SHIFT = wp.constant(24)
KEY_X_SHIFT = wp.constant(8)


@wp.func
def fast_atan2(y: float, x: float) -> float:
    """OpenCV's fastAtan2 (degrees in [0, 360)), the scalar polynomial of ``atan_f32``."""
    ax = wp.abs(x)
    ay = wp.abs(y)
    a = float(0.0)
    if ax >= ay:
        c = ay / (ax + ATAN_EPS)
        c2 = c * c
        a = (((ATAN_P7 * c2 + ATAN_P5) * c2 + ATAN_P3) * c2 + ATAN_P1) * c
    else:
        c = ax / (ay + ATAN_EPS)
        c2 = c * c
        a = 90.0 - (((ATAN_P7 * c2 + ATAN_P5) * c2 + ATAN_P3) * c2 + ATAN_P1) * c
    if x < 0.0:
        a = 180.0 - a
    if y < 0.0:
        a = 360.0 - a
    return a


@wp.func
def reflected(img: wp.array2d(dtype=wp.uint8), y: int, x: int) -> int:
    """img[y, x] with BORDER_REFLECT_101 outside: never reads out of bounds."""
    yy = border_index(y, img.shape[0], BORDER_REFLECT_101)
    xx = border_index(x, img.shape[1], BORDER_REFLECT_101)
    return int(img[yy, xx])


@wp.func
def neighbour_in_cell(scores: wp.array2d(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
                      col_of_x: wp.array(dtype=wp.int32), y: int, x: int, cr: int, cc: int) -> int:
    """scores[y, x] when (y, x) lies in cell (cr, cc), else 0 (what the cell's FAST sees)."""
    if y < 0 or x < 0 or y >= scores.shape[0] or x >= scores.shape[1]:
        return 0
    if row_of_y[y] != cr or col_of_x[x] != cc:
        return 0
    return scores[y, x]


@wp.func
def rotated_sample(img: wp.array2d(dtype=wp.uint8), cy: int, cx: int, px: float, py: float,
                   a: float, b: float) -> int:
    """The blurred value at pattern point (px, py) rotated by (a = cos, b = sin), rounded."""
    dx = round_coord(px * a - py * b)
    dy = round_coord(px * b + py * a)
    return reflected(img, cy + dy, cx + dx)


@wp.func
def describe_byte(img: wp.array2d(dtype=wp.uint8), cy: int, cx: int, angle_deg: float,
                  pattern: wp.array2d(dtype=wp.int32), byte: int) -> int:
    """Byte ``byte`` of the rotated-BRIEF descriptor: bit k is I(p1) < I(p2) of pair 8 byte + k."""
    rad = angle_deg * DEG_TO_RAD
    a = wp.cos(rad)
    b = wp.sin(rad)
    val = int(0)
    for k in range(8):
        i = byte * 8 + k
        t0 = rotated_sample(img, cy, cx, float(pattern[i, 0]), float(pattern[i, 1]), a, b)
        t1 = rotated_sample(img, cy, cx, float(pattern[i, 2]), float(pattern[i, 3]), a, b)
        if t0 < t1:
            val = val | (1 << k)
    return val


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
                keys[slot] = ((wp.int64(level) << wp.int64(KEY_LEVEL_SHIFT))
                              | (wp.int64(cell) << wp.int64(KEY_CELL_SHIFT))
                              | (wp.int64(y) << wp.int64(KEY_Y_SHIFT))
                              | (wp.int64(x) << wp.int64(KEY_X_SHIFT)) | wp.int64(s))


@wp.kernel
def compute_angles(img: wp.array2d(dtype=wp.uint8), kps: wp.array2d(dtype=wp.int32), first: int,
                   angle: wp.array(dtype=wp.float32)):
    """IC_Angle of keypoint ``first + i`` (level coordinates in kps[:, 0:2])."""
    i = wp.tid() + first
    cx = kps[i, 0]
    cy = kps[i, 1]
    m10 = int(0)
    m01 = int(0)
    for v in range(-HALF_PATCH, HALF_PATCH + 1):
        d = UMAX[wp.abs(v)]
        for u in range(-d, d + 1):
            val = reflected(img, cy + v, cx + u)
            m10 += u * val
            m01 += v * val
    angle[i] = fast_atan2(float(m01), float(m10))


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
# Host side: per-device constants and the stages
# --------------------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _pattern_on(device: str):
    return wp.array(np.ascontiguousarray(ref.pattern()), dtype=wp.int32, device=device)


@functools.lru_cache(maxsize=64)
def _grid_on(width: int, height: int, device: str):
    grid = ref.cell_grid(width, height)
    return (grid, wp.array(np.ascontiguousarray(grid.row_of_y), dtype=wp.int32, device=device),
            wp.array(np.ascontiguousarray(grid.col_of_x), dtype=wp.int32, device=device))


@functools.lru_cache(maxsize=16)
def _level_tables_on(scale_factor: float, n_levels: int, device: str):
    """(s_l, ORB-SLAM2's keypoint size) per level as float32 device arrays."""
    return (wp.array(ref.level_scales(scale_factor, n_levels), dtype=wp.float32, device=device),
            wp.array(ref.keypoint_sizes(scale_factor, n_levels), dtype=wp.float32, device=device))


def _capacity(grid) -> int:
    """Most survivors a level can have: strict 3x3 maxima inside one cell cannot touch."""
    rows = sum((b - a - 6 + 1) // 2 for a, b in grid.row_spans if b - a > 6)
    cols = sum((b - a - 6 + 1) // 2 for a, b in grid.col_spans if b - a > 6)
    return rows * cols


def build_pyramid(src, scale_factor: float, n_levels: int) -> list:
    """ORB-SLAM2's scale pyramid on the device (``kernels_warp.scale_pyramid``)."""
    return scale_pyramid(src, n_levels, scale_factor)


def detect_and_select(pyramid: list, ini_th: int, min_th: int):
    """FAST per cell and the per-cell threshold on every level, launched back to back.

    Returns ``(count, keys)``: a device counter and an int64 key buffer (KEY_* layout) holding
    every level's candidates in no particular order.
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
    level = k >> KEY_LEVEL_SHIFT
    bounds = np.searchsorted(level, np.arange(len(pyramid) + 1))
    y = ((k >> KEY_Y_SHIFT) & 0xFFFF).astype(np.int32)
    x = ((k >> KEY_X_SHIFT) & 0xFFFF).astype(np.int32)
    score = (k & 0xFF).astype(np.int32)
    out = []
    for lv, img in enumerate(pyramid):
        grid = ref.cell_grid(int(img.shape[1]), int(img.shape[0]))
        a, b = bounds[lv], bounds[lv + 1]
        chosen = a + ref.distribute_octtree(x[a:b], y[a:b], score[a:b], grid, wanted[lv])
        out.append(np.stack([x[chosen], y[chosen], score[chosen],
                             np.full(chosen.size, lv, np.int32)], axis=1))
    return np.ascontiguousarray(np.concatenate(out, axis=0), dtype=np.int32)


def compute_orientation(pyramid: list, kps, first: list, counts: list, angle) -> None:
    """IC_Angle of every keypoint (one launch per level, on the unblurred level)."""
    for img, f, n in zip(pyramid, first, counts):
        if n:
            wp.launch(compute_angles, dim=n, inputs=[img, kps, f], outputs=[angle],
                      device=img.device)


def blur_levels(pyramid: list) -> list:
    """The 7x7, sigma 2, BORDER_REFLECT_101 Gaussian of each level
    (``kernels_warp.gaussian_blur``)."""
    return [gaussian_blur(img, (7, 7), 2.0, "reflect101") for img in pyramid]


def compute_descriptors(blurred: list, kps, angle, first: list, counts: list, desc) -> None:
    """Rotated BRIEF of every keypoint, one thread per (keypoint, byte)."""
    for img, f, n in zip(blurred, first, counts):
        if n:
            pat = _pattern_on(str(img.device))
            wp.launch(describe_extracted, dim=(n, ref.DESCRIPTOR_BYTES),
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


def extract(pyramid: list, n_features: int, scale_factor: float, ini_th: int, min_th: int):
    """FAST, per-cell threshold, quadtree, orientation, blur, descriptors, scale back."""
    n_levels = len(pyramid)
    device = pyramid[0].device
    wanted = ref.features_per_level(n_features, scale_factor, n_levels)
    count, keys = detect_and_select(pyramid, ini_th, min_th)
    chosen = distribute(count, keys, pyramid, wanted)
    counts = np.bincount(chosen[:, 3], minlength=n_levels).tolist() if chosen.size else \
        [0] * n_levels
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(int).tolist()
    n = chosen.shape[0]
    kps = wp.array(chosen.reshape(n, 4), dtype=wp.int32, device=device)
    angle = wp.empty(n, dtype=wp.float32, device=device)
    desc = wp.empty((n, ref.DESCRIPTOR_BYTES), dtype=wp.uint8, device=device)
    if n:
        compute_orientation(pyramid, kps, first, counts, angle)
        compute_descriptors(blur_levels(pyramid), kps, angle, first, counts, desc)
    return scale_back(kps, angle, scale_factor, n_levels), desc


def orb(src, n_features: int, scale_factor: float, n_levels: int, ini_th_fast: int,
        min_th_fast: int, *, out=None) -> tuple:
    """ORB-SLAM2's extractor on ``src.device``: (Keypoints of device arrays, uint8 [N, 32]).

    Everything but the quadtree runs on the device; the quadtree's host step syncs once to
    read the candidates (a count, then the keys) and uploads the chosen keypoints. ``out`` is
    not supported (the count is data-dependent) and ignored.
    """
    pyramid = build_pyramid(src, scale_factor, n_levels)
    return extract(pyramid, n_features, scale_factor, ini_th_fast, min_th_fast)


def orb_compute(src, keypoints: Keypoints, scale_factor: float, n_levels: int, *, out=None):
    """uint8 [N, 32] descriptors of given keypoints (level-0 coordinates, octave, angle).

    The octaves are read on the host (to group the launches per level), one sync.
    """
    device = src.device
    kp = keypoints.to(str(device))
    n = len(kp)
    desc = out if out is not None else wp.zeros((n, ref.DESCRIPTOR_BYTES), dtype=wp.uint8,
                                                device=device)
    if n == 0:
        return desc
    octave = kp.octave.numpy()
    pyramid = build_pyramid(src, scale_factor, n_levels)
    blurred = blur_levels(pyramid)
    inv = np.float32(1.0) / ref.level_scales(scale_factor, n_levels)
    pat = _pattern_on(str(device))
    for level in np.unique(octave):
        idx = np.flatnonzero(octave == level).astype(np.int32)
        index = wp.array(idx, dtype=wp.int32, device=device)
        wp.launch(describe_keypoints, dim=(idx.size, ref.DESCRIPTOR_BYTES),
                  inputs=[blurred[level], kp.x, kp.y, kp.angle, index, float(inv[level]), pat],
                  outputs=[desc], device=device)
    return desc


__all__ = ["orb", "orb_compute"]
