"""ORB-SLAM2's ORB extractor on NumPy/OpenCV, stage by stage.

The stages follow ``ORBextractor::operator()`` of ORB-SLAM2 (``src/ORBextractor.cc``) and are
separate functions so a graph can run them as nodes (SPEC section 6):

``build_pyramid``        level l resized INTER_LINEAR from level l-1 to cvRound(w / s_l)
``detect_cells``         FAST-9/16 per 30x30 cell at the lower threshold, cell-local non-max
``select_cells``         per cell: the points >= iniThFAST if it has any, else those >= minThFAST
``distribute_octtree``   the quadtree (``DistributeOctTree``), sequential, host only
``compute_orientation``  intensity centroid over the radius-15 disc (``IC_Angle``)
``blur_level``           7x7 Gaussian, sigma 2, BORDER_REFLECT_101
``compute_descriptors``  rotated BRIEF with the 256 pairs of the 31x31 pattern
``scale_back``           level coordinates times s_l

The helpers that define the algorithm rather than an implementation (level scales, features
per level, the cell grid, the disc, the pattern, ``fastAtan2``, the quadtree) live here once
and the Warp implementation imports them; level sizes are
:func:`warpvx.pyramid.scale_pyramid_sizes`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources

import cv2
import numpy as np

from ..keypoints import Keypoints
from .scale_pyramid import scale_pyramid

PATCH_SIZE = 31
HALF_PATCH_SIZE = 15
EDGE_THRESHOLD = 19
# ComputeKeyPointsOctTree: cells are laid over [EDGE_THRESHOLD - 3, size - EDGE_THRESHOLD + 3).
MIN_BORDER = EDGE_THRESHOLD - 3
FAST_CELL = 30
# A level needs one whole cell inside its borders (nCols = width / 30 >= 1).
MIN_LEVEL_SIZE = 2 * MIN_BORDER + FAST_CELL
DESCRIPTOR_BYTES = 32
# Largest image side accepted (the Warp candidate keys hold 16-bit coordinates and 2^18 cells).
MAX_SIDE = 15000
# Rotated pattern points land within 18 px of the centre on each axis (|(13, 13)| < 18.4).
PATTERN_RADIUS = 19


# --------------------------------------------------------------------------------------------
# The algorithm's constants and helpers (shared with kernels_warp.orb)
# --------------------------------------------------------------------------------------------


def level_scales(scale_factor: float, n_levels: int) -> np.ndarray:
    """float32 [n_levels]: s_0 = 1, s_l = s_(l-1) * scale_factor in float (mvScaleFactor)."""
    scales = np.ones(n_levels, np.float32)
    f = np.float32(scale_factor)
    for level in range(1, n_levels):
        scales[level] = np.float32(scales[level - 1] * f)
    return scales


def c_round(v: float) -> int:
    """cvRound of a float: round half to even (what lrint does in the default mode)."""
    return int(np.rint(np.float32(v)))


def features_per_level(n_features: int, scale_factor: float, n_levels: int) -> list:
    """Features wanted per level, ORB-SLAM2's rule (float arithmetic, cvRound, remainder last).

    n0 = N (1 - f) / (1 - f^L) with f = 1 / scale_factor, level l gets cvRound(n0 f^l), the
    last level ``max(N - sum, 0)``. For N = 2000, 1.2, 8: 434 362 302 251 209 175 145 122.
    """
    factor = np.float32(1.0) / np.float32(scale_factor)
    per_scale = np.float32(
        np.float32(n_features) * (np.float32(1.0) - factor)
        / (np.float32(1.0) - np.float32(math.pow(float(factor), float(n_levels))))
    )
    counts = []
    total = 0
    for _ in range(n_levels - 1):
        c = c_round(per_scale)
        counts.append(c)
        total += c
        per_scale = np.float32(per_scale * factor)
    counts.append(max(n_features - total, 0))
    return counts


def keypoint_sizes(scale_factor: float, n_levels: int) -> np.ndarray:
    """float32 [n_levels]: ORB-SLAM2's ``int(PATCH_SIZE * s_l)`` (truncated to an integer)."""
    return np.array([int(np.float32(PATCH_SIZE) * s) for s in level_scales(scale_factor, n_levels)],
                    np.float32)


@dataclass(frozen=True)
class CellGrid:
    """ComputeKeyPointsOctTree's cells for one level of ``width`` x ``height``.

    FAST runs on cell (i, j) over rows ``row_spans[i]`` and columns ``col_spans[j]`` (each
    ``[start, stop)``, cells overlapping by 6 px); FAST reports corners 3 px inside its input,
    so each cell *owns* the pixels of ``[start + 3, stop - 3)``; those inner areas tile the
    level without overlap. ``row_of_y[y]`` / ``col_of_x[x]`` give the owning cell row / column
    of a pixel, -1 where no cell owns it.
    """

    width: int
    height: int
    row_spans: tuple
    col_spans: tuple
    row_of_y: np.ndarray
    col_of_x: np.ndarray

    @property
    def n_rows(self) -> int:
        return len(self.row_spans)

    @property
    def n_cols(self) -> int:
        return len(self.col_spans)

    @property
    def max_border_x(self) -> int:
        return self.width - EDGE_THRESHOLD + 3

    @property
    def max_border_y(self) -> int:
        return self.height - EDGE_THRESHOLD + 3


def _spans(size: int, skip_margin: int) -> tuple:
    """Cell spans along one axis (ComputeKeyPointsOctTree, float arithmetic as there)."""
    max_border = size - EDGE_THRESHOLD + 3
    extent = np.float32(max_border - MIN_BORDER)
    n = int(extent / np.float32(FAST_CELL))
    if n < 1:
        return ()
    step = int(math.ceil(np.float32(extent / np.float32(n))))
    spans = []
    for i in range(n):
        start = MIN_BORDER + i * step
        if start >= max_border - skip_margin:
            continue
        spans.append((start, min(start + step + 6, max_border)))
    return tuple(spans)


@functools.lru_cache(maxsize=64)
def cell_grid(width: int, height: int) -> CellGrid:
    """The cell grid of a ``width`` x ``height`` level (cached per size)."""
    # ORB-SLAM2 skips a row of cells starting within 3 px of the bottom border, a column
    # within 6 px of the right one.
    rows = _spans(height, 3)
    cols = _spans(width, 6)
    row_of_y = np.full(height, -1, np.int32)
    col_of_x = np.full(width, -1, np.int32)
    for i, (a, b) in enumerate(rows):
        row_of_y[a + 3:max(b - 3, a + 3)] = i
    for j, (a, b) in enumerate(cols):
        col_of_x[a + 3:max(b - 3, a + 3)] = j
    row_of_y.setflags(write=False)
    col_of_x.setflags(write=False)
    return CellGrid(width, height, rows, cols, row_of_y, col_of_x)


@functools.lru_cache(maxsize=1)
def umax() -> np.ndarray:
    """int32 [16]: half-width of each row of the radius-15 disc (ORB-SLAM2's umax)."""
    hp = HALF_PATCH_SIZE
    u = np.zeros(hp + 1, np.int32)
    vmax = int(math.floor(hp * math.sqrt(2.0) / 2 + 1))
    vmin = int(math.ceil(hp * math.sqrt(2.0) / 2))
    for v in range(vmax + 1):
        u[v] = c_round(math.sqrt(hp * hp - v * v))
    v0 = 0
    for v in range(hp, vmin - 1, -1):  # make the disc symmetric in u and v
        while u[v0] == u[v0 + 1]:
            v0 += 1
        u[v] = v0
        v0 += 1
    u.setflags(write=False)
    return u


@functools.lru_cache(maxsize=1)
def disc_offsets() -> tuple:
    """(du, dv) int32 arrays of every pixel of the radius-15 disc, |du| <= umax[|dv|]."""
    um = umax()
    du, dv = [], []
    for v in range(-HALF_PATCH_SIZE, HALF_PATCH_SIZE + 1):
        d = int(um[abs(v)])
        du.extend(range(-d, d + 1))
        dv.extend([v] * (2 * d + 1))
    return np.array(du, np.int32), np.array(dv, np.int32)


@functools.lru_cache(maxsize=1)
def _disc_mask() -> np.ndarray:
    """uint8 [31, 31]: 1 on the radius-15 disc (|u| <= umax[|v|]), 0 outside."""
    du, dv = disc_offsets()
    mask = np.zeros((PATCH_SIZE, PATCH_SIZE), np.uint8)
    mask[dv + HALF_PATCH_SIZE, du + HALF_PATCH_SIZE] = 1
    mask.setflags(write=False)
    return mask


@functools.lru_cache(maxsize=1)
def pattern() -> np.ndarray:
    """int32 [256, 4]: the (x1, y1, x2, y2) point pairs of ORB's 31x31 pattern (package data)."""
    text = resources.files("warpvx").joinpath("data/orb_pattern_31.txt").read_text()
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    table = np.array(rows, np.int32)
    if table.shape != (256, 4):
        raise RuntimeError(f"orb_pattern_31.txt: expected 256 rows of 4 integers, got "
                           f"{table.shape}")
    table.setflags(write=False)
    return table


# OpenCV's fastAtan2 (atan_f32 in core/src/mathfuncs_core.simd.hpp): a 7th-order polynomial in
# degrees, float arithmetic; each coefficient is a float product as there.
_DEG = np.float32(180.0 / math.pi)
ATAN_P1 = float(np.float32(np.float32(0.9997878412794807) * _DEG))
ATAN_P3 = float(np.float32(np.float32(-0.3258083974640975) * _DEG))
ATAN_P5 = float(np.float32(np.float32(0.1555786518463281) * _DEG))
ATAN_P7 = float(np.float32(np.float32(-0.04432655554792128) * _DEG))
ATAN_EPS = float(np.float32(np.finfo(np.float64).eps))


def fast_atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """float32 degrees in [0, 360): OpenCV's ``cv::fastAtan2(y, x)``, elementwise."""
    y = np.asarray(y, np.float32)
    x = np.asarray(x, np.float32)
    ax, ay = np.abs(x), np.abs(y)
    wide = ax >= ay
    eps = np.float32(ATAN_EPS)
    c = np.where(wide, ay, ax) / (np.where(wide, ax, ay) + eps)
    c2 = c * c
    p = (((np.float32(ATAN_P7) * c2 + np.float32(ATAN_P5)) * c2 + np.float32(ATAN_P3)) * c2
         + np.float32(ATAN_P1)) * c
    a = np.where(wide, p, np.float32(90.0) - p)
    a = np.where(x < 0, np.float32(180.0) - a, a)
    a = np.where(y < 0, np.float32(360.0) - a, a)
    return a.astype(np.float32)


def padded_centres(img: np.ndarray, x, y, radius: int) -> tuple:
    """(padded image, cx, cy): ``img`` with ``radius`` px of BORDER_REFLECT_101 around it and
    the rounded centres (cvRound(x), cvRound(y)), clamped into the image, in padded
    coordinates."""
    h, w = img.shape
    r = int(radius)
    if r >= min(h, w):  # cv2's reflection needs the image larger than the pad
        padded = np.pad(img, r, mode="reflect") if min(h, w) > 1 else np.pad(img, r, mode="edge")
    else:
        padded = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_REFLECT_101)
    cx = np.clip(np.rint(np.asarray(x, np.float32)).astype(np.intp), 0, w - 1) + r
    cy = np.clip(np.rint(np.asarray(y, np.float32)).astype(np.intp), 0, h - 1) + r
    return padded, cx, cy


def patches(img: np.ndarray, x, y, radius: int) -> np.ndarray:
    """uint8 [N, 2r+1, 2r+1]: the square patches around the rounded centres (cvRound(x),
    cvRound(y)), BORDER_REFLECT_101 beyond the image; centres are clamped into the image."""
    r = int(radius)
    padded, cx, cy = padded_centres(img, x, y, r)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (2 * r + 1, 2 * r + 1))
    return windows[cy - r, cx - r]


# --------------------------------------------------------------------------------------------
# The quadtree (DistributeOctTree), sequential: CPU in both implementations
# --------------------------------------------------------------------------------------------


def order_candidates(x: np.ndarray, y: np.ndarray, grid: CellGrid) -> np.ndarray:
    """Permutation putting candidates in ORB-SLAM2's order: cell row, cell column, y, x.

    That is the order in which ComputeKeyPointsOctTree hands them to DistributeOctTree; it
    decides which point of a node wins a tie of responses.
    """
    cell = grid.row_of_y[y].astype(np.int64) * grid.n_cols + grid.col_of_x[x]
    return np.argsort((cell * grid.height + y) * grid.width + x)


# Columns of the quadtree's node table.
_X0, _Y0, _X1, _Y1, _COUNT, _ID = range(6)


def _divide(nodes, point_node, px, py, parents, next_id, stop_at=None):
    """Divide ``parents`` (list positions, in processing order) as ``DivideNode`` does.

    ``nodes`` is the node list as an int64 table (columns _X0.._ID), ``point_node`` each
    point's list position. Children go to the front of the list (the last processed parent's
    first, each as n4 n3 n2 n1); the other nodes keep their order. With ``stop_at``,
    processing stops after the division that brings the list to ``stop_at`` nodes. Returns
    the new table, the points' new positions, the ids of the new children holding more than
    one point (in creation order) and the next free id.
    """
    n_nodes = nodes.shape[0]
    rank = np.full(n_nodes, -1, np.int64)
    rank[parents] = np.arange(parents.size)
    pts = np.flatnonzero(rank[point_node] >= 0)
    r = rank[point_node[pts]]
    bounds = nodes[parents][:, :4]
    # Quadrant split at (x0 + ceil((x1 - x0) / 2), y0 + ceil((y1 - y0) / 2)).
    mid_x = bounds[:, _X0] - ((bounds[:, _X0] - bounds[:, _X1]) // 2)
    mid_y = bounds[:, _Y0] - ((bounds[:, _Y0] - bounds[:, _Y1]) // 2)
    keys = r * 4 + (px[pts] >= mid_x[r]) + 2 * (py[pts] >= mid_y[r])
    # Group the points by child (keys are small: a bincount); children in key order.
    bins = np.bincount(keys, minlength=4 * parents.size)
    child_keys = np.flatnonzero(bins)
    child_counts = bins[child_keys]
    lookup = np.empty(bins.size, np.int64)
    lookup[child_keys] = np.arange(child_keys.size)
    child_of_point = lookup[keys]
    child_rank = child_keys // 4
    if stop_at is not None:
        # List size after each parent's division: + its children - itself.
        sizes = n_nodes + np.cumsum(np.bincount(child_rank, minlength=parents.size) - 1)
        reached = np.flatnonzero(sizes >= stop_at)
        if reached.size:
            last = int(reached[0])
            parents = parents[:last + 1]
            # The divided parents' children are a prefix in key order; the points of the
            # undivided parents stay where they are.
            n_keep = int(np.searchsorted(child_rank, last, side="right"))
            child_keys, child_counts = child_keys[:n_keep], child_counts[:n_keep]
            child_rank = child_rank[:n_keep]
            done = r <= last
            pts, child_of_point = pts[done], child_of_point[done]
    n_children = child_keys.size
    q = child_keys % 4
    right, bottom = (q % 2) == 1, q >= 2
    b = bounds[child_rank]
    mx, my = mid_x[child_rank], mid_y[child_rank]
    child = np.empty((n_children, 6), np.int64)
    child[:, _X0] = np.where(right, mx, b[:, _X0])
    child[:, _X1] = np.where(right, b[:, _X1], mx)
    child[:, _Y0] = np.where(bottom, my, b[:, _Y0])
    child[:, _Y1] = np.where(bottom, b[:, _Y1], my)
    child[:, _COUNT] = child_counts
    child[:, _ID] = next_id + np.arange(n_children)  # creation order
    # New list: children by descending key (front), then the untouched nodes in order.
    divided = np.zeros(n_nodes, bool)
    divided[parents] = True
    kept = np.flatnonzero(~divided)
    new_nodes = np.concatenate([child[::-1], nodes[kept]])
    pos = np.full(n_nodes, -1, np.int64)
    pos[kept] = n_children + np.arange(kept.size)
    new_point_node = pos[point_node]
    new_point_node[pts] = (n_children - 1) - child_of_point
    expandable_ids = child[child[:, _COUNT] > 1, _ID]
    return new_nodes, new_point_node, expandable_ids, next_id + n_children


def distribute_octtree(x: np.ndarray, y: np.ndarray, response: np.ndarray,
                       grid: CellGrid, n: int) -> np.ndarray:
    """ORB-SLAM2's ``DistributeOctTree``: indices of the kept points, in its output order.

    The points (level coordinates, in ORB-SLAM2's candidate order) are split by a quadtree over
    ``[MIN_BORDER, maxBorder)``: the root row holds ``round(w / h)`` nodes; while fewer than
    ``n`` nodes exist, every node holding more than one point is divided into quadrants
    (children pushed to the front of the node list, empty ones dropped); once dividing all of
    them would overshoot ``n``, nodes are divided largest first and the division stops as soon
    as there are ``n`` nodes (so up to ``n + 2``). Each node keeps its strongest point (the
    first in order on a tie). The node list order, and so the output order, is ORB-SLAM2's.

    Deviations (documented): ORB-SLAM2 sorts equal-sized nodes by their heap address, which is
    not reproducible; here the later-created node goes first (what increasing addresses give).
    A level more than twice as tall as wide gets one root node (ORB-SLAM2 divides by zero).

    Each pass is vectorized over the points; the pass structure is ORB-SLAM2's.
    """
    count = int(x.shape[0])
    if count == 0:
        return np.zeros(0, np.int64)
    min_x = min_y = MIN_BORDER
    max_x, max_y = grid.max_border_x, grid.max_border_y
    px = (x.astype(np.float32) - np.float32(min_x))
    py = (y.astype(np.float32) - np.float32(min_y))
    resp = np.asarray(response, np.float32)
    width, height = max_x - min_x, max_y - min_y

    n_ini = max(1, int(math.floor(float(np.float32(width) / np.float32(height)) + 0.5)))
    h_x = np.float32(np.float32(width) / np.float32(n_ini))
    point_node = np.minimum((px / h_x).astype(np.int64), n_ini - 1)
    counts = np.bincount(point_node, minlength=n_ini)
    alive = np.flatnonzero(counts > 0)  # empty root nodes are erased
    # The node list, in list order: bounds, point count, creation id (heap-address proxy).
    nodes = np.zeros((alive.size, 6), np.int64)
    nodes[:, _X0] = [int(np.float32(h_x * np.float32(i))) for i in alive]
    nodes[:, _X1] = [int(np.float32(h_x * np.float32(i + 1))) for i in alive]
    nodes[:, _Y1] = height
    nodes[:, _COUNT] = counts[alive]
    nodes[:, _ID] = np.arange(alive.size)
    remap = np.full(n_ini, -1, np.int64)
    remap[alive] = np.arange(alive.size)
    point_node = remap[point_node]
    next_id = alive.size

    finish = False
    while not finish:
        prev_size = nodes.shape[0]
        parents = np.flatnonzero(nodes[:, _COUNT] > 1)
        to_expand = np.zeros(0, np.int64)
        if parents.size:
            nodes, point_node, to_expand, next_id = _divide(nodes, point_node, px, py, parents,
                                                            next_id)
        size = nodes.shape[0]
        if size >= n or size == prev_size:
            finish = True
        elif size + to_expand.size * 3 > n:
            # Divide the largest nodes first until n nodes exist.
            while not finish:
                prev_size = nodes.shape[0]
                if to_expand.size:
                    # List positions of the expandable nodes (ids are unique).
                    by_id = np.argsort(nodes[:, _ID])
                    cand = by_id[np.searchsorted(nodes[:, _ID], to_expand, sorter=by_id)]
                    # sort(pairs(size, pointer)), walked from the back: largest first.
                    order = np.lexsort((nodes[cand, _ID], nodes[cand, _COUNT]))[::-1]
                    nodes, point_node, to_expand, next_id = _divide(
                        nodes, point_node, px, py, cand[order], next_id, stop_at=n)
                size = nodes.shape[0]
                if size >= n or size == prev_size:
                    finish = True

    # The strongest point of each node, the first in candidate order on a tie, in list order.
    best = np.full(nodes.shape[0], -np.inf, np.float32)
    np.maximum.at(best, point_node, resp)
    strongest = np.flatnonzero(resp == best[point_node])
    _, first = np.unique(point_node[strongest], return_index=True)
    return strongest[first]


# --------------------------------------------------------------------------------------------
# Stages
# --------------------------------------------------------------------------------------------


def build_pyramid(src: np.ndarray, scale_factor: float, n_levels: int) -> list:
    """ORB-SLAM2's scale pyramid: level l resized INTER_LINEAR from level l-1 to
    cvRound(w / s_l) (``kernels_cpu.scale_pyramid``)."""
    return scale_pyramid(src, n_levels, scale_factor)


@functools.lru_cache(maxsize=16)
def _fast_detector(threshold: int):
    return cv2.FastFeatureDetector_create(int(threshold), True,
                                          cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)


def detect_cells(level: np.ndarray, threshold: int) -> tuple:
    """FAST-9/16 with non-max suppression on each cell, as ComputeKeyPointsOctTree runs it.

    Returns ``(x, y, score)`` int32 arrays in level coordinates and ORB-SLAM2's order. Run at
    the lower of the two thresholds: a point survives non-max suppression at a threshold t
    exactly when it survives at a lower one and scores >= t, so :func:`select_cells` can apply
    the per-cell rule afterwards (the data-flow form of thesis section 3.3.1).
    """
    h, w = level.shape
    grid = cell_grid(w, h)
    detect = _fast_detector(threshold).detect
    # One cv2 call per cell (its own non-max suppression); the keypoints of all cells are
    # converted at once, each shifted by its cell's origin.
    found, x_off, y_off, counts = [], [], [], []
    for y0, y1 in grid.row_spans:
        for x0, x1 in grid.col_spans:
            kps = detect(level[y0:y1, x0:x1])
            if kps:
                found.extend(kps)
                x_off.append(x0)
                y_off.append(y0)
                counts.append(len(kps))
    if not found:
        z = np.zeros(0, np.int32)
        return z, z.copy(), z.copy()
    pts = cv2.KeyPoint_convert(found)
    x = pts[:, 0].astype(np.int32) + np.repeat(np.array(x_off, np.int32), counts)
    y = pts[:, 1].astype(np.int32) + np.repeat(np.array(y_off, np.int32), counts)
    s = np.fromiter((k.response for k in found), np.float32, len(found)).astype(np.int32)
    order = order_candidates(x, y, grid)
    return x[order], y[order], s[order]


def select_cells(x, y, score, grid: CellGrid, ini_th: int, min_th: int) -> np.ndarray:
    """Boolean mask: per cell, the points >= ``ini_th`` when it has one, else >= ``min_th``."""
    if x.size == 0:
        return np.zeros(0, bool)
    cell = grid.row_of_y[y].astype(np.int64) * grid.n_cols + grid.col_of_x[x]
    strong = score >= ini_th
    has_strong = np.bincount(cell, weights=strong, minlength=grid.n_rows * grid.n_cols) > 0
    return np.where(has_strong[cell], strong, score >= min_th)


def compute_orientation(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """float32 degrees: ORB-SLAM2's IC_Angle, fastAtan2(m01, m10) over the radius-15 disc.

    m10 = sum u I(x+u, y+v), m01 = sum v I(x+u, y+v) on the unblurred level, centred at the
    rounded keypoint. Reads beyond the level reflect (BORDER_REFLECT_101); extracted
    keypoints never need it.
    """
    if np.asarray(x).size == 0:
        return np.zeros(0, np.float32)
    # Row v of the disc spans |u| <= umax[|v|], column u spans |v| <= umax[|u|] (the disc is
    # symmetric): each row and column sum is four reads of the integral image.
    hp = HALF_PATCH_SIZE
    padded, cx, cy = padded_centres(level, x, y, hp)
    exact_int32 = padded.size * 255 < 2 ** 31
    integral = cv2.integral(padded, sdepth=cv2.CV_32S if exact_int32 else cv2.CV_64F)
    off = np.arange(-hp, hp + 1)
    half = umax()[np.abs(off)].astype(np.intp)
    yy = cy[:, None] + off
    left = cx[:, None] - half
    right = cx[:, None] + half + 1
    row_sums = (integral[yy + 1, right] - integral[yy, right]
                - integral[yy + 1, left] + integral[yy, left])
    xx = cx[:, None] + off
    top = cy[:, None] - half
    bottom = cy[:, None] + half + 1
    col_sums = (integral[bottom, xx + 1] - integral[bottom, xx]
                - integral[top, xx + 1] + integral[top, xx])
    m01 = row_sums.astype(np.int64) @ off  # sum over v of v * (row sum)
    m10 = col_sums.astype(np.int64) @ off  # sum over u of u * (column sum)
    return fast_atan2(m01.astype(np.float32), m10.astype(np.float32))


def blur_level(level: np.ndarray) -> np.ndarray:
    """The 7x7, sigma 2 Gaussian (BORDER_REFLECT_101) ORB-SLAM2 describes on."""
    return cv2.GaussianBlur(level, (7, 7), 2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)


def compute_descriptors(blurred: np.ndarray, x, y, angle, *, out=None) -> np.ndarray:
    """uint8 [N, 32] rotated BRIEF (ORB-SLAM2's computeOrbDescriptor).

    With a = cos(angle), b = sin(angle) (radians, float), pattern point (px, py) is sampled
    at (cvRound(px a - py b), cvRound(px b + py a)) from the rounded centre; bit i (bit i % 8
    of byte i // 8) is I(p1) < I(p2) of pair i. Reads beyond the level reflect.
    """
    n = int(np.asarray(x).shape[0])
    desc = out if out is not None else np.empty((n, DESCRIPTOR_BYTES), np.uint8)
    if n == 0:
        return desc
    pat = pattern().astype(np.float32)
    px = pat[:, [0, 2]].reshape(-1)  # p1, p2 of each pair, interleaved: 512 points
    py = pat[:, [1, 3]].reshape(-1)
    rad = np.asarray(angle, np.float32) * np.float32(math.pi / 180.0)
    a = np.cos(rad).astype(np.float32)[:, None]
    b = np.sin(rad).astype(np.float32)[:, None]
    padded, cx, cy = padded_centres(blurred, x, y, PATTERN_RADIUS)
    width = np.float32(padded.shape[1])
    # Flat index of (cvRound(px a - py b), cvRound(px b + py a)) from the centre in the padded
    # level; products and differences in float32, as ORB-SLAM2 (integers stay exact).
    dx = px * a
    dx -= py * b
    np.rint(dx, out=dx)
    dy = px * b
    dy += py * a
    np.rint(dy, out=dy)
    dy *= width
    dy += dx
    index = dy.astype(np.int64)
    index += (cy * padded.shape[1] + cx)[:, None]
    vals = np.take(padded.reshape(-1), index)
    bits = vals[:, 0::2] < vals[:, 1::2]
    desc[...] = np.packbits(bits, axis=1, bitorder="little")
    return desc


def scale_back(x, y, octave, scale_factor: float, n_levels: int) -> tuple:
    """Level coordinates to level 0: (x s_l, y s_l) in float32 (level 0 untouched)."""
    s = level_scales(scale_factor, n_levels)[octave]
    return (np.asarray(x, np.float32) * s).astype(np.float32), \
        (np.asarray(y, np.float32) * s).astype(np.float32)


# --------------------------------------------------------------------------------------------
# The extractor
# --------------------------------------------------------------------------------------------


def extract_level(level: np.ndarray, n_wanted: int, ini_th: int, min_th: int) -> tuple:
    """FAST per cell, per-cell threshold and quadtree on one level: (x, y, score) kept."""
    h, w = level.shape
    grid = cell_grid(w, h)
    x, y, s = detect_cells(level, min(ini_th, min_th))
    keep = select_cells(x, y, s, grid, ini_th, min_th)
    x, y, s = x[keep], y[keep], s[keep]
    chosen = distribute_octtree(x, y, s, grid, n_wanted)
    return x[chosen], y[chosen], s[chosen]


def orb(src: np.ndarray, n_features: int, scale_factor: float, n_levels: int,
        ini_th_fast: int, min_th_fast: int, *, out=None) -> tuple:
    """ORB-SLAM2's extractor: (Keypoints at level 0, uint8 [N, 32] descriptors).

    Keypoints are listed level by level, each level in the quadtree's node order; ``out`` is
    not supported (the count is data-dependent) and ignored.
    """
    pyramid = build_pyramid(src, scale_factor, n_levels)
    wanted = features_per_level(n_features, scale_factor, n_levels)
    sizes = keypoint_sizes(scale_factor, n_levels)
    fields = {k: [] for k in ("x", "y", "response", "size", "angle", "octave")}
    descs = []
    for level, img in enumerate(pyramid):
        x, y, s = extract_level(img, wanted[level], ini_th_fast, min_th_fast)
        angle = compute_orientation(img, x, y)
        descs.append(compute_descriptors(blur_level(img), x, y, angle))
        octave = np.full(x.size, level, np.int32)
        sx, sy = scale_back(x, y, octave, scale_factor, n_levels)
        fields["x"].append(sx)
        fields["y"].append(sy)
        fields["response"].append(s.astype(np.float32))
        fields["size"].append(np.full(x.size, sizes[level], np.float32))
        fields["angle"].append(angle)
        fields["octave"].append(octave)
    kps = Keypoints(**{k: np.concatenate(v) for k, v in fields.items()})
    return kps, np.concatenate(descs, axis=0) if descs else np.zeros((0, 32), np.uint8)


def orb_compute(src: np.ndarray, keypoints: Keypoints, scale_factor: float, n_levels: int,
                *, out=None) -> np.ndarray:
    """uint8 [N, 32] descriptors of given keypoints (level-0 coordinates, octave, angle).

    Each keypoint is described on its octave's blurred level of the ORB-SLAM2 pyramid at
    (x, y) / s_octave, in the input order.
    """
    kp = keypoints.to("host")
    n = len(kp)
    desc = out if out is not None else np.zeros((n, DESCRIPTOR_BYTES), np.uint8)
    if n == 0:
        return desc
    pyramid = build_pyramid(src, scale_factor, n_levels)
    inv = (np.float32(1.0) / level_scales(scale_factor, n_levels)).astype(np.float32)
    for level in np.unique(kp.octave):
        idx = np.flatnonzero(kp.octave == level)
        lx = kp.x[idx] * inv[level]
        ly = kp.y[idx] * inv[level]
        desc[idx] = compute_descriptors(blur_level(pyramid[level]), lx, ly, kp.angle[idx])
    return desc


__all__ = ["orb", "orb_compute"]
