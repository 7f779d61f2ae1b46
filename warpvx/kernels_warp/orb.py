"""ORB-SLAM2's ORB extractor on Warp, the quadtree included (see :mod:`warpvx.kernels_cpu.orb`).

:func:`orb` runs every stage on the device with fixed shapes, so on CUDA the whole extractor is
one captured graph per image size and parameter set (a *plan*: buffers and graph cached, a pool
of them so concurrent calls never share one). The one host sync reads the keypoint count.
All levels go through each kernel together: the pyramid and its blurred copy live in two flat
buffers, a per-level table gives each level's offset, size and cell grid.

Stages (one launch each unless said):

``build_pyramid``, ``blur_levels``  ``kernels_warp.scale_pyramid`` and ``gaussian_blur`` (7x7,
    sigma 2, BORDER_REFLECT_101) into the flat buffers, one launch per level; on CUDA the blur
    runs on a side stream, beside detection and the quadtree.
``score_pixels``  FAST-9/16 scores at the lower threshold on the pixels a 30x30 cell owns
    (``fast_corners.fast_score``).
``suppress_pixels``  OpenCV's strict 3x3 maximum *within the cell* (ORB-SLAM2 runs FAST per
    cell: a neighbour in another cell counts as 0); survivors appended to 32 striped lists,
    and a count per cell of those >= iniThFAST.
``select_candidates``  the per-cell rule (iniThFAST when the cell has such a point, else
    minThFAST); each kept point gets its quadtree path (the root column, then the quadrant of
    every division as ``DivideNode`` splits, 16 levels deep: distinct pixels always part).
``pad_paths``, radix sort, ``gather_paths``  points sorted by path (a key of as few bits as
    the image size needs): every quadtree node at depth d is then a run of points sharing d
    digits.
``count_depths``, ``sum_depth_counts``  per point, the depth it shares with each neighbour
    (``lcp``); per level and depth, the nodes holding one point and more than one.
``plan_divisions``  ``DistributeOctTree`` decided from those counts alone (one thread a level):
    the pass K where its first loop stops, and, when it goes on dividing largest nodes first,
    the depth g* of its last round and whether that round stops part way.
``alloc_nodes``, ``link_nodes``, ``rank_nodes``  the nodes of the rounds that divide largest
    first, ordered as ORB-SLAM2 walks them (size, then creation order; each node compared with
    its (level, depth) group by 32 threads), and the nodes added before each one's turn, which
    decide where the last round stops.
``emit_finals``  each node left in the final list, its strongest point (the first in ORB-SLAM2's
    candidate order on a tie) and a key giving the node's place in the list; radix sort.
``accumulate_moments``, ``describe_levels``  ``IC_Angle`` (a thread per disc row, integer
    atomics), then rotated BRIEF and the level-0 fields.

Why the node list order has a closed form: a pass of the first loop puts the children of the
nodes it divides in front, in reverse; so after pass k the nodes created at depth k come first,
ordered by their path with alternating directions (``flipped_prefix``), then the single-point
nodes of earlier passes, newest pass first. A round of the second loop divides the nodes of one
depth, ordered by (size, creation order) descending; its children again go in front in
reverse. Every division is known from the node counts per depth, so each final node's place
is a sort key, and the result equals the sequential algorithm (checked against
:func:`warpvx.kernels_cpu.orb.distribute_octtree` on real and random point sets).

Capacities (candidates, nodes, final nodes) are sized for real images; when a frame exceeds
one (e.g. pure noise), that frame takes :func:`extract_host`, the same stages with the quadtree
on the host (``kernels_cpu.orb.distribute_octtree``), so results never depend on capacity.
"""

from __future__ import annotations

import functools
import math
import threading
from collections import OrderedDict

import numpy as np
import warp as wp

from ..kernels_cpu import orb as ref
from ..keypoints import Keypoints
from ..pyramid import scale_pyramid_sizes
from ._sampling import read_reflect101, round_coord
from .fast_corners import fast_score
from .gaussian_blur import gaussian_blur
from .scale_pyramid import scale_pyramid

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

vec16i = wp.types.vector(length=16, dtype=wp.int32)

UMAX = wp.constant(vec16i(*[int(v) for v in ref.umax()]))
HALF_PATCH = wp.constant(ref.HALF_PATCH_SIZE)
ATAN_P1 = wp.constant(wp.float32(ref.ATAN_P1))
ATAN_P3 = wp.constant(wp.float32(ref.ATAN_P3))
ATAN_P5 = wp.constant(wp.float32(ref.ATAN_P5))
ATAN_P7 = wp.constant(wp.float32(ref.ATAN_P7))
ATAN_EPS = wp.constant(wp.float32(ref.ATAN_EPS))
DEG_TO_RAD = wp.constant(wp.float32(np.float32(np.pi / 180.0)))
MIN_BORDER = wp.constant(ref.MIN_BORDER)

# Candidate keys, int64: level (5 bits) | cell (18) | y (16) | x (16) | score (8), so that
# sorting the keys sorts the candidates in ORB-SLAM2's order (level, cell row, cell column,
# y, x) and no key is negative. Images up to kernels_cpu.orb.MAX_SIDE px a side fit.
KEY_LEVEL_SHIFT = wp.constant(58)
KEY_CELL_SHIFT = wp.constant(40)
KEY_Y_SHIFT = wp.constant(24)
KEY_X_SHIFT = wp.constant(8)

# Quadtree path keys, int64: level (5 bits) | root column (9) | 16 quadrant digits (2 bits
# each, the first division in the top bits). 16 divisions separate any two pixels of a root
# node up to 2^14 px a side; a root column index is < 512 (width / height <= 15000 / 30).
PATH_DEPTH = wp.constant(16)
PATH_ROOT_SHIFT = wp.constant(32)
PATH_LEVEL_SHIFT = wp.constant(41)
# Sort keys (int64, per plan, as few bits as the size needs so the radix sorts take few
# passes): the path key kept to its first ``digits`` quadrants (enough to separate any two
# pixels of a root node), and the final-node key: level | segment (5 bits: 31 - depth, newest
# nodes first) | place in the segment (a flipped path prefix, or parent rank and quadrant).
# Node counts are kept per (level, stripe, depth): striping spreads the atomics.
DEPTHS = 18
STRIPES = 32
N_DEPTHS = wp.constant(DEPTHS)
N_STRIPES = wp.constant(STRIPES)
# rank_nodes splits each node's comparisons over this many threads.
RANK_CHUNKS = 32
N_RANK_CHUNKS = wp.constant(RANK_CHUNKS)

# Per-level table (int32 [L, LT_FIELDS]) columns.
LT_PIX = wp.constant(0)  # offset of the level in the flat pyramid
LT_W = wp.constant(1)
LT_H = wp.constant(2)
LT_ROW = wp.constant(3)  # offset of its row_of_y in the flat table
LT_COL = wp.constant(4)  # offset of its col_of_x
LT_NCOLS = wp.constant(5)
LT_CELL = wp.constant(6)  # offset of its cells in the per-cell counts
LT_WANT = wp.constant(7)  # features wanted
LT_NINI = wp.constant(8)  # root nodes
LT_ROOT = wp.constant(9)  # offset of its root boundaries
LT_QTH = wp.constant(10)  # quadtree height (maxBorderY - minBorderY)
LT_NODE = wp.constant(11)  # offset of its node pool
LT_NODE_CAP = wp.constant(12)
LT_FIELDS = 13
# Per-level float table (float32 [L, 3]): root width hX, scale s_l, keypoint size.
FT_HX = wp.constant(0)
FT_SCALE = wp.constant(1)
FT_SIZE = wp.constant(2)
# Per-level plan (int32 [L, 4]) written by plan_divisions.
CT_K = wp.constant(0)  # pass at which the first loop stops
CT_GSTAR = wp.constant(1)  # depth of the last division round (K when there is none)
CT_MODE = wp.constant(2)
CT_SIZE = wp.constant(3)  # list size before the last round
MODE_EMPTY = wp.constant(0)  # no candidates
MODE_PASSES = wp.constant(1)  # the first loop finished: nothing divided at depth K
MODE_FULL = wp.constant(2)  # the last round divided all its nodes
MODE_PARTIAL = wp.constant(3)  # the last round stopped once n nodes existed
# Counters (int32, zeroed per frame): candidates, final nodes, an overflow flag, survivors and
# candidates per stripe (appends go to N_STRIPES regions: no single hot counter), node counts
# per level, then per (level, stripe, depth) single- and multi-point node counts and per-cell
# counts (offsets in the plan).
C_CAND = wp.constant(0)
C_FINAL = wp.constant(1)
C_OVER = wp.constant(2)
C_SURV_R = wp.constant(3)
C_CAND_R = wp.constant(3 + STRIPES)
C_NODES = wp.constant(3 + 2 * STRIPES)


# --------------------------------------------------------------------------------------------
# Device functions
# --------------------------------------------------------------------------------------------


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
def neighbour_in_cell(scores: wp.array2d(dtype=wp.int32), row_of_y: wp.array(dtype=wp.int32),
                      col_of_x: wp.array(dtype=wp.int32), y: int, x: int, cr: int, cc: int) -> int:
    """scores[y, x] when (y, x) lies in cell (cr, cc), else 0 (what the cell's FAST sees)."""
    if y < 0 or x < 0 or y >= scores.shape[0] or x >= scores.shape[1]:
        return 0
    if row_of_y[y] != cr or col_of_x[x] != cc:
        return 0
    return scores[y, x]


@wp.func
def ic_angle(img: wp.array2d(dtype=wp.uint8), cy: int, cx: int) -> float:
    """ORB-SLAM2's IC_Angle: fastAtan2(m01, m10) over the radius-15 disc around (cx, cy)."""
    m10 = int(0)
    m01 = int(0)
    for v in range(-HALF_PATCH, HALF_PATCH + 1):
        d = UMAX[wp.abs(v)]
        for u in range(-d, d + 1):
            val = read_reflect101(img, cy + v, cx + u)
            m10 += u * val
            m01 += v * val
    return fast_atan2(float(m01), float(m10))


@wp.func
def rotated_sample(img: wp.array2d(dtype=wp.uint8), cy: int, cx: int, px: float, py: float,
                   a: float, b: float) -> int:
    """The blurred value at pattern point (px, py) rotated by (a = cos, b = sin), rounded."""
    dx = round_coord(px * a - py * b)
    dy = round_coord(px * b + py * a)
    return read_reflect101(img, cy + dy, cx + dx)


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


@wp.func
def level_image(base: wp.uint64, lt: wp.array2d(dtype=wp.int32), level: int):
    """Level ``level`` of a flat pyramid buffer as a 2-D array (a view, no copy)."""
    return wp.array(ptr=base + wp.uint64(lt[level, LT_PIX]),
                    shape=(lt[level, LT_H], lt[level, LT_W]), dtype=wp.uint8)


@wp.func
def level_holding(i: int, lt: wp.array2d(dtype=wp.int32), column: int, n_levels: int) -> int:
    """The level whose range starts at or before ``i`` in level-table column ``column``
    (``LT_PIX``: a flat pixel index; ``LT_NODE``: a quadtree node index)."""
    level = int(0)
    while level + 1 < n_levels and i >= lt[level + 1, column]:
        level += 1
    return level


@wp.func
def candidate_key(level: int, cell: int, y: int, x: int, score: int) -> wp.int64:
    return ((wp.int64(level) << wp.int64(KEY_LEVEL_SHIFT))
            | (wp.int64(cell) << wp.int64(KEY_CELL_SHIFT))
            | (wp.int64(y) << wp.int64(KEY_Y_SHIFT))
            | (wp.int64(x) << wp.int64(KEY_X_SHIFT)) | wp.int64(score))


@wp.func
def key_field(key: wp.int64, shift: int, mask: int) -> int:
    return int((key >> wp.int64(shift)) & wp.int64(mask))


@wp.func
def quadtree_path(level: int, x: int, y: int, lt: wp.array2d(dtype=wp.int32),
                  ft: wp.array2d(dtype=wp.float32), roots: wp.array(dtype=wp.int32)) -> wp.int64:
    """Path key of a candidate: its root column (``vpIniNodes[x / hX]``) and the quadrant it
    falls in at each of 16 successive ``DivideNode`` splits (float coordinates relative to the
    border, integer node bounds, split at ceil(half) as there)."""
    px = float(x - MIN_BORDER)
    py = float(y - MIN_BORDER)
    n_ini = lt[level, LT_NINI]
    root = wp.min(int(px / ft[level, FT_HX]), n_ini - 1)
    x0 = roots[lt[level, LT_ROOT] + root]
    x1 = roots[lt[level, LT_ROOT] + root + 1]
    y0 = int(0)
    y1 = lt[level, LT_QTH]
    digits = wp.int64(0)
    for _d in range(16):
        mx = x0 + ((x1 - x0 + 1) >> 1)
        my = y0 + ((y1 - y0 + 1) >> 1)
        q = int(0)
        if px >= float(mx):
            q += 1
            x0 = mx
        else:
            x1 = mx
        if py >= float(my):
            q += 2
            y0 = my
        else:
            y1 = my
        digits = (digits << wp.int64(2)) | wp.int64(q)
    return ((wp.int64(level) << wp.int64(PATH_LEVEL_SHIFT))
            | (wp.int64(root) << wp.int64(PATH_ROOT_SHIFT)) | digits)


@wp.func
def shared_depth(a: wp.int64, b: wp.int64) -> int:
    """How many leading quadrant digits two path keys share; -1 in different root nodes."""
    if (a >> wp.int64(PATH_ROOT_SHIFT)) != (b >> wp.int64(PATH_ROOT_SHIFT)):
        return -1
    diff = (a ^ b) & wp.int64(0xFFFFFFFF)
    d = int(0)
    while d < PATH_DEPTH:
        if ((diff >> wp.int64(30 - 2 * d)) & wp.int64(3)) != wp.int64(0):
            return d
        d += 1
    return PATH_DEPTH


@wp.func
def quadrant(path: wp.int64, depth: int) -> int:
    """The quadrant (0 top-left, 1 top-right, 2 bottom-left, 3 bottom-right) entered at
    division ``depth`` (>= 1)."""
    return int((path >> wp.int64(2 * (PATH_DEPTH - depth))) & wp.int64(3))


@wp.func
def flipped_prefix(path: wp.int64, depth: int, n_ini: int) -> wp.int64:
    """Rank key of a depth-``depth`` node in the node list after pass ``depth``: its root and
    quadrants, each reversed where that pass order runs backwards (the last division, and
    every second one before it; the root as the first division)."""
    root = int((path >> wp.int64(PATH_ROOT_SHIFT)) & wp.int64(511))
    if depth == 0:
        return wp.int64(root)
    if (depth - 1) % 2 == 0:
        root = n_ini - 1 - root
    digits = (path & wp.int64(0xFFFFFFFF)) >> wp.int64(2 * (PATH_DEPTH - depth))
    mask = wp.int64(0x33333333) & ((wp.int64(1) << wp.int64(2 * depth)) - wp.int64(1))
    return (wp.int64(root) << wp.int64(2 * depth)) | (digits ^ mask)


@wp.func
def run_start(lcp: wp.array(dtype=wp.int32), s: int, depth: int) -> int:
    """First point of the depth-``depth`` node holding sorted point ``s``."""
    k = s
    while lcp[k] >= depth:
        k -= 1
    return k


@wp.func
def node_index(node_base: wp.array(dtype=wp.int32), lcp: wp.array(dtype=wp.int32), start: int,
               depth: int, first_depth: int) -> int:
    """Node of depth ``depth`` starting at sorted point ``start`` (see ``alloc_nodes``); -1
    when its level ran out of node capacity (that frame is redone on the host)."""
    base = node_base[start]
    if base < 0:
        return -1
    return base + depth - wp.max(lcp[start] + 1, first_depth)


@wp.func
def node_before(u: int, v: int, first_depth: int, n_ini: int, node_start: wp.array(dtype=wp.int32),
                node_depth: wp.array(dtype=wp.int32), node_count: wp.array(dtype=wp.int32),
                node_parent: wp.array(dtype=wp.int32), paths: wp.array(dtype=wp.int64)) -> bool:
    """Whether ORB-SLAM2 divides node u before node v (same level and depth): larger first,
    then the later created. Creation order: at the first round's depth, the reverse of the
    list order (``flipped_prefix``); deeper, by parent division order then quadrant."""
    a = u
    b = v
    while True:
        ca = node_count[a]
        cb = node_count[b]
        if ca != cb:
            return ca > cb
        if node_depth[a] == first_depth:
            return (flipped_prefix(paths[node_start[a]], first_depth, n_ini)
                    < flipped_prefix(paths[node_start[b]], first_depth, n_ini))
        pa = node_parent[a]
        pb = node_parent[b]
        if pa == pb:
            return (quadrant(paths[node_start[a]], node_depth[a])
                    > quadrant(paths[node_start[b]], node_depth[b]))
        # Later-created children come from earlier-divided parents: compare parents reversed.
        a = pb
        b = pa
    return False


vec_depths = wp.types.vector(length=DEPTHS, dtype=wp.int32)


@wp.func
def depth_counts(totals: wp.array3d(dtype=wp.int32), level: int, which: int) -> vec_depths:
    """A level's per-depth node counts (``sum_depth_counts``) as a local vector."""
    v = vec_depths()
    for g in range(DEPTHS):
        v[g] = totals[level, which, g]
    return v


# --------------------------------------------------------------------------------------------
# Kernels of the one-graph extractor (all levels per launch)
# --------------------------------------------------------------------------------------------


@wp.kernel
def score_pixels(pyr: wp.uint64, lt: wp.array2d(dtype=wp.int32), n_levels: int,
                 row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                 threshold: int, scores: wp.array(dtype=wp.uint8)):
    """FAST score at ``threshold`` of each pixel a cell owns (>= 19 px inside), 0 elsewhere."""
    i = wp.tid()
    level = level_holding(i, lt, LT_PIX, n_levels)
    w = lt[level, LT_W]
    r = i - lt[level, LT_PIX]
    y = r // w
    x = r - y * w
    s = int(0)
    if row_of_y[lt[level, LT_ROW] + y] >= 0 and col_of_x[lt[level, LT_COL] + x] >= 0:
        s = fast_score(level_image(pyr, lt, level), y, x, threshold)
    scores[i] = wp.uint8(s)


@wp.kernel
def suppress_pixels(lt: wp.array2d(dtype=wp.int32), n_levels: int,
                    row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                    scores: wp.array(dtype=wp.uint8), ini_th: int, cells_at: int, region: int,
                    counters: wp.array(dtype=wp.int32), survivors: wp.array(dtype=wp.int64)):
    """OpenCV's strict 3x3 maximum within the cell: append the survivors (candidate keys) to
    the region of stripe i % N_STRIPES, and count those >= ``ini_th`` per cell."""
    i = wp.tid()
    s = int(scores[i])
    if s == 0:
        return
    level = level_holding(i, lt, LT_PIX, n_levels)
    w = lt[level, LT_W]
    r = i - lt[level, LT_PIX]
    y = r // w
    x = r - y * w
    ro = lt[level, LT_ROW]
    co = lt[level, LT_COL]
    cr = row_of_y[ro + y]
    cc = col_of_x[co + x]
    # Owned pixels lie >= 19 px inside the level: the neighbours exist.
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if dy != 0 or dx != 0:
                if row_of_y[ro + y + dy] == cr and col_of_x[co + x + dx] == cc:
                    if int(scores[i + dy * w + dx]) >= s:
                        return
    cell = cr * lt[level, LT_NCOLS] + cc
    if s >= ini_th:
        wp.atomic_add(counters, cells_at + lt[level, LT_CELL] + cell, 1)
    stripe = i % N_STRIPES
    slot = wp.atomic_add(counters, C_SURV_R + stripe, 1)
    # Past the capacity the count still grows: pad_paths flags it, the frame takes extract_host.
    if slot < region:
        survivors[stripe * region + slot] = candidate_key(level, cell, y, x, s)


@wp.kernel
def select_candidates(survivors: wp.array(dtype=wp.int64), surv_region: int,
                      lt: wp.array2d(dtype=wp.int32), ft: wp.array2d(dtype=wp.float32),
                      roots: wp.array(dtype=wp.int32), ini_th: int, min_th: int, cells_at: int,
                      cand_region: int, digits: int, root_bits: int,
                      counters: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                      paths: wp.array(dtype=wp.int64), sort_keys: wp.array(dtype=wp.int64),
                      order: wp.array(dtype=wp.int32)):
    """Keep a survivor when its score reaches its cell's threshold; write its candidate key,
    its quadtree path, the path's sort key (level | root | first ``digits`` quadrants) and its
    slot (the sort's value) into the region of stripe j % N_STRIPES."""
    j = wp.tid()
    r = j // surv_region
    if j - r * surv_region >= wp.min(counters[C_SURV_R + r], surv_region):
        return
    key = survivors[j]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    cell = key_field(key, KEY_CELL_SHIFT, 0x3FFFF)
    s = key_field(key, 0, 0xFF)
    th = min_th
    if counters[cells_at + lt[level, LT_CELL] + cell] > 0:
        th = ini_th
    if s < th:
        return
    stripe = j % N_STRIPES
    slot = wp.atomic_add(counters, C_CAND_R + stripe, 1)
    if slot < cand_region:
        at = stripe * cand_region + slot
        cand[at] = key
        path = quadtree_path(level, key_field(key, KEY_X_SHIFT, 0xFFFF),
                             key_field(key, KEY_Y_SHIFT, 0xFFFF), lt, ft, roots)
        paths[at] = path
        root = (path >> wp.int64(PATH_ROOT_SHIFT)) & wp.int64(511)
        kept = (path & wp.int64(0xFFFFFFFF)) >> wp.int64(2 * (PATH_DEPTH - digits))
        sort_keys[at] = ((((wp.int64(level) << wp.int64(root_bits)) | root)
                          << wp.int64(2 * digits)) | kept)
        order[at] = at


@wp.kernel
def pad_paths(counters: wp.array(dtype=wp.int32), surv_region: int, cand_region: int,
              pad: wp.int64, sort_keys: wp.array(dtype=wp.int64)):
    """Pad the candidate regions' unused slots (a fixed-size sort puts them last); thread 0
    writes the candidate total and whether a region overflowed."""
    i = wp.tid()
    r = i // cand_region
    if i - r * cand_region >= counters[C_CAND_R + r]:
        sort_keys[i] = pad
    if i == 0:
        total = int(0)
        over = int(0)
        for k in range(STRIPES):
            c = counters[C_CAND_R + k]
            total += wp.min(c, cand_region)
            if c > cand_region or counters[C_SURV_R + k] > surv_region:
                over = 1
        counters[C_CAND] = total
        counters[C_OVER] = over


@wp.kernel
def pad_keys(counters: wp.array(dtype=wp.int32), which: int, pad: wp.int64,
             keys: wp.array(dtype=wp.int64)):
    """keys[i] = pad past the count (so a fixed-size sort puts them last)."""
    i = wp.tid()
    if i >= counters[which]:
        keys[i] = pad


@wp.kernel
def gather_paths(order: wp.array(dtype=wp.int32), counters: wp.array(dtype=wp.int32),
                 paths: wp.array(dtype=wp.int64), sorted_paths: wp.array(dtype=wp.int64)):
    """The full paths in sorted order."""
    i = wp.tid()
    if i < counters[C_CAND]:
        sorted_paths[i] = paths[order[i]]


@wp.kernel
def count_depths(paths: wp.array(dtype=wp.int64), counters: wp.array(dtype=wp.int32), n_cap: int,
                 digits: int, singles_at: int, multis_at: int, lcp: wp.array(dtype=wp.int32)):
    """lcp[i]: the digits sorted point i shares with point i - 1 (-1: another root). Point i
    is alone from depth max(lcp[i], lcp[i+1]) + 1 on (one single-point node there); it starts
    a node of several points at each depth in (lcp[i], lcp[i+1]]. Two points sharing all the
    sorted ``digits`` (the plan's bound says they cannot) flag the frame for the host path."""
    i = wp.tid()
    n = wp.min(counters[C_CAND], n_cap)
    if i >= n:
        return
    a = paths[i]
    lo = int(-1)
    if i > 0:
        lo = shared_depth(paths[i - 1], a)
    hi = int(-1)
    if i + 1 < n:
        hi = shared_depth(a, paths[i + 1])
    if hi >= digits:
        counters[C_OVER] = 1
    lcp[i] = lo
    level = int(a >> wp.int64(PATH_LEVEL_SHIFT))
    row = (level * N_STRIPES + (i % N_STRIPES)) * N_DEPTHS
    wp.atomic_add(counters, singles_at + row + wp.max(lo, hi) + 1, 1)
    for g in range(lo + 1, hi + 1):
        wp.atomic_add(counters, multis_at + row + g, 1)


@wp.kernel
def sum_depth_counts(counters: wp.array(dtype=wp.int32), singles_at: int, multis_at: int,
                     totals: wp.array3d(dtype=wp.int32)):
    """totals[level, 0 | 1, depth]: single- | multi-point nodes, summed over the stripes."""
    level, which, g = wp.tid()
    base = singles_at
    if which == 1:
        base = multis_at
    total = int(0)
    for s in range(STRIPES):
        total += counters[base + (level * N_STRIPES + s) * N_DEPTHS + g]
    totals[level, which, g] = total


@wp.kernel
def plan_divisions(lt: wp.array2d(dtype=wp.int32), totals: wp.array3d(dtype=wp.int32),
                   ctl: wp.array2d(dtype=wp.int32)):
    """DistributeOctTree's control flow from node counts (one thread per level).

    With S_g, M_g the single- and multi-point nodes created at depth g (a node is created when
    its parent has several points), A_g = S_g + M_g, pass k of the first loop leaves
    N_k = A_k + sum_{g<k} S_g nodes; it stops at the first k with N_k >= n or no growth
    (MODE_PASSES), or goes on to divide largest first when N_k + 3 M_k > n. Each round of that
    second loop divides the multi-point nodes of one depth g, adding A_{g+1} - M_g nodes; the
    last round is the one reaching n (MODE_PARTIAL) or adding nothing (MODE_FULL).
    """
    level = wp.tid()
    n = lt[level, LT_WANT]
    singles = depth_counts(totals, level, 0)
    multis = depth_counts(totals, level, 1)
    if singles[0] + multis[0] == 0:
        ctl[level, CT_MODE] = MODE_EMPTY
        ctl[level, CT_K] = 0
        ctl[level, CT_GSTAR] = 0
        ctl[level, CT_SIZE] = 0
        return
    n_prev = singles[0] + multis[0]
    sum_singles = singles[0]
    k = int(1)
    second_loop = bool(False)
    while k < N_DEPTHS - 1:
        nk = singles[k] + multis[k] + sum_singles
        if nk >= n or nk == n_prev:
            break
        if nk + 3 * multis[k] > n:
            second_loop = True
            break
        sum_singles += singles[k]
        n_prev = nk
        k += 1
    size = singles[k] + multis[k] + sum_singles
    g = k
    mode = MODE_PASSES
    if second_loop:
        mode = MODE_FULL
        while g < N_DEPTHS - 2:
            growth = singles[g + 1] + multis[g + 1] - multis[g]
            if size + growth >= n:
                mode = MODE_PARTIAL
                break
            if growth == 0:
                break
            size += growth
            g += 1
    ctl[level, CT_K] = k
    ctl[level, CT_GSTAR] = g
    ctl[level, CT_MODE] = mode
    ctl[level, CT_SIZE] = size


@wp.kernel
def alloc_nodes(paths: wp.array(dtype=wp.int64), lcp: wp.array(dtype=wp.int32),
                counters: wp.array(dtype=wp.int32), n_cap: int, lt: wp.array2d(dtype=wp.int32),
                ctl: wp.array2d(dtype=wp.int32), groups_at: int,
                node_base: wp.array(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
                node_depth: wp.array(dtype=wp.int32), node_count: wp.array(dtype=wp.int32),
                node_growth: wp.array(dtype=wp.int32), groups: wp.array3d(dtype=wp.int32)):
    """The multi-point nodes the second loop orders (depths K..g*), from the point starting
    them: consecutive entries of the level's pool, one per depth; their size and the nodes a
    division adds (children - 1, the points inside sharing exactly ``depth`` digits). Each is
    also listed in groups[level, depth] (the nodes rank_nodes compares)."""
    s = wp.tid()
    n = wp.min(counters[C_CAND], n_cap)
    if s >= n:
        return
    level = int(paths[s] >> wp.int64(PATH_LEVEL_SHIFT))
    mode = ctl[level, CT_MODE]
    node_base[s] = -1
    if mode != MODE_FULL and mode != MODE_PARTIAL:
        return
    k = ctl[level, CT_K]
    hi = int(-1)
    if s + 1 < n:
        hi = lcp[s + 1]
    g0 = wp.max(lcp[s] + 1, k)
    g1 = wp.min(hi, ctl[level, CT_GSTAR])
    if g0 > g1:
        return
    base = wp.atomic_add(counters, C_NODES + level, g1 - g0 + 1)
    if base + g1 - g0 + 1 > lt[level, LT_NODE_CAP]:
        return  # the host sees the count past the capacity
    first = lt[level, LT_NODE] + base
    node_base[s] = first
    for g in range(g0, g1 + 1):
        e = s + 1
        children = int(0)
        while e < n and lcp[e] >= g:
            if lcp[e] == g:
                children += 1
            e += 1
        v = first + g - g0
        node_start[v] = s
        node_depth[v] = g
        node_count[v] = e - s
        node_growth[v] = children
        # A group holds at most the level's nodes: within its capacity.
        slot = wp.atomic_add(counters, groups_at + level * N_DEPTHS + g, 1)
        groups[level, g, slot] = v


@wp.func
def live_node_level(v: int, lt: wp.array2d(dtype=wp.int32), n_levels: int,
                    counters: wp.array(dtype=wp.int32)) -> int:
    """The level of node slot ``v``, or -1 when the slot holds no node: past the level's used
    nodes, or the level overflowed its capacity (its frame is then redone on the host)."""
    level = level_holding(v, lt, LT_NODE, n_levels)
    used = counters[C_NODES + level]
    if v - lt[level, LT_NODE] >= used or used > lt[level, LT_NODE_CAP]:
        return -1
    return level


@wp.kernel
def link_nodes(lt: wp.array2d(dtype=wp.int32), n_levels: int, counters: wp.array(dtype=wp.int32),
               ctl: wp.array2d(dtype=wp.int32), lcp: wp.array(dtype=wp.int32),
               node_base: wp.array(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
               node_depth: wp.array(dtype=wp.int32), node_parent: wp.array(dtype=wp.int32)):
    """Each ordered node's parent (a node of the previous round), -1 at depth K."""
    v = wp.tid()
    level = live_node_level(v, lt, n_levels, counters)
    if level < 0:
        return
    g = node_depth[v]
    k = ctl[level, CT_K]
    if g == k:
        node_parent[v] = -1
        return
    ps = run_start(lcp, node_start[v], g - 1)
    node_parent[v] = node_index(node_base, lcp, ps, g - 1, k)


@wp.kernel
def rank_nodes(lt: wp.array2d(dtype=wp.int32), n_levels: int, counters: wp.array(dtype=wp.int32),
               ctl: wp.array2d(dtype=wp.int32), paths: wp.array(dtype=wp.int64), groups_at: int,
               groups: wp.array3d(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
               node_depth: wp.array(dtype=wp.int32), node_count: wp.array(dtype=wp.int32),
               node_growth: wp.array(dtype=wp.int32), node_parent: wp.array(dtype=wp.int32),
               node_rank: wp.array(dtype=wp.int32), node_grown: wp.array(dtype=wp.int32)):
    """A node's place in its round's division order (the nodes of its group divided before
    it), and the nodes those divisions add; thread c of a node compares every
    N_RANK_CHUNKS-th member of its group (both arrays zeroed first, sums by atomics)."""
    v, c = wp.tid()
    level = live_node_level(v, lt, n_levels, counters)
    if level < 0:
        return
    g = node_depth[v]
    k = ctl[level, CT_K]
    n_ini = lt[level, LT_NINI]
    members = counters[groups_at + level * N_DEPTHS + g]
    rank = int(0)
    grown = int(0)
    for j in range(c, members, N_RANK_CHUNKS):
        u = groups[level, g, j]
        if u != v:
            if node_before(u, v, k, n_ini, node_start, node_depth, node_count, node_parent,
                           paths):
                rank += 1
                grown += node_growth[u]
    if rank > 0:
        wp.atomic_add(node_rank, v, rank)
        wp.atomic_add(node_grown, v, grown)


@wp.kernel
def emit_finals(paths: wp.array(dtype=wp.int64), order: wp.array(dtype=wp.int32),
                lcp: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                counters: wp.array(dtype=wp.int32), n_cap: int, lt: wp.array2d(dtype=wp.int32),
                ctl: wp.array2d(dtype=wp.int32), node_base: wp.array(dtype=wp.int32),
                node_rank: wp.array(dtype=wp.int32), node_grown: wp.array(dtype=wp.int32),
                place_bits: int, final_keys: wp.array(dtype=wp.int64),
                final_values: wp.array(dtype=wp.int32)):
    """For each node of the final list (from the point starting it): its strongest point and
    its list position key.

    A point alone from depth sd on ends in that single-point node when sd <= g*; otherwise it
    lies in a multi-point node of depth g*, final unless the last round divided it (then its
    child is). Segments, newest first: the children of the last round, then each round's and
    pass's nodes back to the roots; inside a segment, a node created by the second loop goes
    by its parent's division order (reversed) and quadrant (reversed), a node of the first
    loop by ``flipped_prefix``.
    """
    s = wp.tid()
    n = wp.min(counters[C_CAND], n_cap)
    if s >= n:
        return
    path = paths[s]
    level = int(path >> wp.int64(PATH_LEVEL_SHIFT))
    mode = ctl[level, CT_MODE]
    k = ctl[level, CT_K]
    gstar = ctl[level, CT_GSTAR]
    lo = lcp[s]
    hi = int(-1)
    if s + 1 < n:
        hi = lcp[s + 1]
    depth = wp.max(lo, hi) + 1
    if depth > gstar:
        p = run_start(lcp, s, gstar)
        divided = int(0)
        if mode == MODE_FULL:
            divided = 1
        if mode == MODE_PARTIAL:
            node = node_index(node_base, lcp, p, gstar, k)
            if node < 0:
                return
            # Divided when the list had fewer than n nodes before its turn.
            if ctl[level, CT_SIZE] + node_grown[node] < lt[level, LT_WANT]:
                divided = 1
        if divided != 0:
            depth = gstar + 1
            if lo > gstar:
                return
        else:
            depth = gstar
            if p != s:
                return
    # The node's points: s and the following ones sharing ``depth`` digits.
    best = order[s]
    best_key = cand[best]
    e = s + 1
    while e < n and lcp[e] >= depth:
        c = order[e]
        ck = cand[c]
        sc = key_field(ck, 0, 0xFF)
        sb = key_field(best_key, 0, 0xFF)
        if sc > sb or (sc == sb and (ck >> wp.int64(8)) < (best_key >> wp.int64(8))):
            best = c
            best_key = ck
        e += 1
    place = wp.int64(0)
    if depth <= k:
        place = flipped_prefix(path, depth, lt[level, LT_NINI])
    else:
        parent = node_index(node_base, lcp, run_start(lcp, s, depth - 1), depth - 1, k)
        if parent < 0:
            return
        rank_max = (wp.int64(1) << wp.int64(place_bits - 2)) - wp.int64(1)
        place = (((rank_max - wp.int64(node_rank[parent])) << wp.int64(2))
                 | wp.int64(3 - quadrant(path, depth)))
    slot = wp.atomic_add(counters, C_FINAL, 1)
    if slot < final_keys.shape[0]:
        final_keys[slot] = ((((wp.int64(level) << wp.int64(5)) | wp.int64(31 - depth))
                             << wp.int64(place_bits)) | place)
        final_values[slot] = best


@wp.kernel
def accumulate_moments(pyr: wp.uint64, lt: wp.array2d(dtype=wp.int32),
                       counters: wp.array(dtype=wp.int32), final_values: wp.array(dtype=wp.int32),
                       cand: wp.array(dtype=wp.int64), moments: wp.array2d(dtype=wp.int32)):
    """IC_Angle's moments of keypoint i, one disc row v per thread: m10 += sum u I,
    m01 += v sum I (integer sums: the order of the atomics does not matter)."""
    i, r = wp.tid()
    if i >= wp.min(counters[C_FINAL], moments.shape[0]):
        return
    key = cand[final_values[i]]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    cx = key_field(key, KEY_X_SHIFT, 0xFFFF)
    cy = key_field(key, KEY_Y_SHIFT, 0xFFFF)
    img = level_image(pyr, lt, level)
    v = r - HALF_PATCH
    d = UMAX[wp.abs(v)]
    row = int(0)
    weighted = int(0)
    for u in range(-d, d + 1):
        val = read_reflect101(img, cy + v, cx + u)
        row += val
        weighted += u * val
    wp.atomic_add(moments, i, 0, weighted)
    wp.atomic_add(moments, i, 1, v * row)


@wp.kernel
def describe_levels(blurred: wp.uint64, lt: wp.array2d(dtype=wp.int32),
                    ft: wp.array2d(dtype=wp.float32), counters: wp.array(dtype=wp.int32),
                    final_values: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                    moments: wp.array2d(dtype=wp.int32), pattern: wp.array2d(dtype=wp.int32),
                    kp_fields: wp.array(dtype=wp.float32), kp_octave: wp.array(dtype=wp.int32),
                    desc: wp.array2d(dtype=wp.uint8)):
    """Descriptor byte j of keypoint i on its blurred level; thread j = 0 also writes the
    keypoint's level-0 fields. ``kp_fields`` holds x, y, response, size, angle as a (5, n)
    block, n the keypoint count, so one contiguous copy takes them out."""
    i, j = wp.tid()
    n = wp.min(counters[C_FINAL], desc.shape[0])
    if i >= n:
        return
    key = cand[final_values[i]]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    x = key_field(key, KEY_X_SHIFT, 0xFFFF)
    y = key_field(key, KEY_Y_SHIFT, 0xFFFF)
    angle = fast_atan2(float(moments[i, 1]), float(moments[i, 0]))
    desc[i, j] = wp.uint8(describe_byte(level_image(blurred, lt, level), y, x, angle, pattern, j))
    if j == 0:
        s = ft[level, FT_SCALE]
        kp_fields[i] = float(x) * s
        kp_fields[n + i] = float(y) * s
        kp_fields[2 * n + i] = float(key_field(key, 0, 0xFF))
        kp_fields[3 * n + i] = ft[level, FT_SIZE]
        kp_fields[4 * n + i] = angle
        kp_octave[i] = level


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


def _root_geometry(grid) -> tuple:
    """DistributeOctTree's root nodes of a level: (count, hX, column boundaries, height)."""
    width = grid.max_border_x - ref.MIN_BORDER
    height = grid.max_border_y - ref.MIN_BORDER
    n_ini = max(1, int(math.floor(float(np.float32(width) / np.float32(height)) + 0.5)))
    hx = np.float32(np.float32(width) / np.float32(n_ini))
    bounds = [int(np.float32(hx * np.float32(i))) for i in range(n_ini + 1)]
    return n_ini, hx, bounds, height


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


def extract_host(pyramid: list, n_features: int, scale_factor: float, ini_th: int, min_th: int,
                 blurred: list | None = None):
    """FAST, per-cell threshold, quadtree on the host, orientation, blur, descriptors, scale
    back: one launch per level and stage, a host sync for the candidates.

    What :func:`orb` does when a frame overflows its plan's capacities (the same result).
    """
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
        compute_descriptors(blurred if blurred is not None else blur_levels(pyramid), kps, angle,
                            first, counts, desc)
    return scale_back(kps, angle, scale_factor, n_levels), desc


def orb_host_quadtree(src, n_features: int, scale_factor: float, n_levels: int, ini_th_fast: int,
                      min_th_fast: int):
    """The extractor with the quadtree on the host (per-level launches, no graph)."""
    pyramid = build_pyramid(src, scale_factor, n_levels)
    return extract_host(pyramid, n_features, scale_factor, ini_th_fast, min_th_fast)


# --------------------------------------------------------------------------------------------
# The one-graph extractor: plans
# --------------------------------------------------------------------------------------------


def _round_up(n: int, m: int) -> int:
    return max(m, -(-int(n) // m) * m)


def _view(buf, offset: int, shape: tuple, dtype):
    """A typed view of part of a flat device buffer (kept alive by the plan)."""
    itemsize = wp.types.type_size_in_bytes(dtype)
    return wp.array(ptr=buf.ptr + offset * itemsize, shape=shape, dtype=dtype,
                    device=buf.device)


class Plan:
    """Buffers, tables and (on CUDA) the captured graph of one (device, size, parameters).

    Capacities: non-maximum-suppression survivors, the pyramid's pixel count over
    ``survivor_divisor``, and candidates (what the quadtree sorts), over
    ``candidate_divisor`` (real photos keep about 1 pixel in 50, grass 1 in 17, noise 1 in
    12); ``run`` takes :func:`extract_host` for a frame that exceeds one, or the node
    capacities.
    """

    def __init__(self, device, height: int, width: int, n_features: int, scale_factor: float,
                 n_levels: int, ini_th: int, min_th: int, *, survivor_divisor: int = 8,
                 candidate_divisor: int = 20, graph: bool = True):
        self.device = wp.get_device(device)
        self.shape = (height, width)
        self.params = (n_features, scale_factor, n_levels, ini_th, min_th)
        self.n_levels = n_levels
        sizes = scale_pyramid_sizes(width, height, n_levels, scale_factor)
        wanted = ref.features_per_level(n_features, scale_factor, n_levels)
        grids = [ref.cell_grid(lw, lh) for lw, lh in sizes]
        scales = ref.level_scales(scale_factor, n_levels)
        kp_sizes = ref.keypoint_sizes(scale_factor, n_levels)

        lt = np.zeros((n_levels, LT_FIELDS), np.int32)
        ft = np.zeros((n_levels, 3), np.float32)
        rows, cols, roots = [], [], []
        pix = row = col = cell = root = node = final = 0
        for level, ((lw, lh), grid) in enumerate(zip(sizes, grids)):
            n_ini, hx, bounds, qt_height = _root_geometry(grid)
            # Final list: <= n + 2 (a division adds <= 3 past n - 1), or 4 per root after the
            # first pass; ordered nodes: a few rounds of at most n nodes.
            final_cap = max(wanted[level] + 2, 4 * n_ini)
            node_cap = 4 * final_cap + 64
            lt[level] = (pix, lw, lh, row, col, grid.n_cols, cell, wanted[level], n_ini, root,
                         qt_height, node, node_cap)
            ft[level] = (hx, scales[level], kp_sizes[level])
            rows.append(grid.row_of_y)
            cols.append(grid.col_of_x)
            roots.append(np.array(bounds, np.int32))
            pix += lw * lh
            row += lh
            col += lw
            cell += grid.n_rows * grid.n_cols
            root += n_ini + 1
            node += node_cap
            final += final_cap
        # Sort keys: the quadrant digits that separate any two pixels of a root node (a node's
        # pixel columns, its width + 1, halve, rounded up, per division), plus one.
        spans = [max(max(b1 - b0 for b0, b1 in zip(r[:-1], r[1:])) + 1, int(lt[i, LT_QTH]))
                 for i, r in enumerate(roots)]
        self.digits = min(16, max(max(1, math.ceil(math.log2(v))) for v in spans) + 1)
        self.root_bits = max(1, int(lt[:, LT_NINI].max() - 1).bit_length())
        level_bits = max(1, (n_levels - 1).bit_length())
        self.sort_bits = level_bits + self.root_bits + 2 * self.digits + 1  # top bit: padding
        self.place_bits = max(self.root_bits + 2 * self.digits,
                              int(lt[:, LT_NODE_CAP].max()).bit_length() + 2)
        self.final_bits = level_bits + 5 + self.place_bits + 1
        self.level_sizes = sizes
        self.wanted = wanted
        self.n_pixels = pix
        # Per-stripe regions, a quarter over the even share: the stripes are interleaved pixels.
        proven = sum(_capacity(g) for g in grids)
        self.surv_region = _round_up(min(pix // survivor_divisor, proven) * 5 // 4 // STRIPES, 64)
        self.cand_region = _round_up(min(pix // candidate_divisor, proven) * 5 // 4 // STRIPES,
                                     64)
        self.surv_cap = STRIPES * self.surv_region
        self.cand_cap = STRIPES * self.cand_region
        self.final_cap = final
        self.node_cap = node
        self.node_caps = lt[:, LT_NODE_CAP].copy()
        self.nodes_at = int(C_NODES)
        self.singles_at = int(C_NODES) + n_levels
        self.multis_at = self.singles_at + n_levels * STRIPES * DEPTHS
        self.cells_at = self.multis_at + n_levels * STRIPES * DEPTHS
        self.groups_at = self.cells_at + cell
        n_counters = self.groups_at + n_levels * DEPTHS

        dev = self.device
        self.lt = wp.array(lt, dtype=wp.int32, device=dev)
        self.ft = wp.array(ft, dtype=wp.float32, device=dev)
        self.row_of_y = wp.array(np.concatenate(rows).astype(np.int32), dtype=wp.int32, device=dev)
        self.col_of_x = wp.array(np.concatenate(cols).astype(np.int32), dtype=wp.int32, device=dev)
        self.roots = wp.array(np.concatenate(roots), dtype=wp.int32, device=dev)
        self.pattern = _pattern_on(str(dev))
        # Flat pyramids: level l at lt[l, LT_PIX]; per-level views for the resize and blur.
        self.pyr = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.blurred = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.levels = [_view(self.pyr, int(lt[i, LT_PIX]), (lh, lw), wp.uint8)
                       for i, (lw, lh) in enumerate(sizes)]
        self.blurred_levels = [_view(self.blurred, int(lt[i, LT_PIX]), (lh, lw), wp.uint8)
                               for i, (lw, lh) in enumerate(sizes)]
        self.scores = wp.empty(pix, dtype=wp.uint8, device=dev)
        self.counters = wp.zeros(n_counters, dtype=wp.int32, device=dev)
        cap = self.cand_cap
        self.survivors = wp.empty(self.surv_cap, dtype=wp.int64, device=dev)
        self.cand = wp.empty(cap, dtype=wp.int64, device=dev)
        self.paths = wp.empty(cap, dtype=wp.int64, device=dev)
        self.sort_keys = wp.empty(2 * cap, dtype=wp.int64, device=dev)  # radix sort: 2x
        self.order = wp.empty(2 * cap, dtype=wp.int32, device=dev)
        self.sorted_paths = wp.empty(cap, dtype=wp.int64, device=dev)
        self.totals = wp.empty((n_levels, 2, DEPTHS), dtype=wp.int32, device=dev)
        self.lcp = wp.empty(cap, dtype=wp.int32, device=dev)
        self.ctl = wp.zeros((n_levels, 4), dtype=wp.int32, device=dev)
        self.node_base = wp.empty(cap, dtype=wp.int32, device=dev)
        nc = self.node_cap
        self.node_start = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_depth = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_count = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_growth = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_parent = wp.empty(nc, dtype=wp.int32, device=dev)
        self.node_rank = wp.zeros(nc, dtype=wp.int32, device=dev)
        self.node_grown = wp.zeros(nc, dtype=wp.int32, device=dev)
        self.groups = wp.empty((n_levels, DEPTHS, int(lt[:, LT_NODE_CAP].max())), dtype=wp.int32,
                               device=dev)
        fc = self.final_cap
        self.final_keys = wp.empty(2 * fc, dtype=wp.int64, device=dev)
        self.final_values = wp.empty(2 * fc, dtype=wp.int32, device=dev)
        self.moments = wp.empty((fc, 2), dtype=wp.int32, device=dev)
        self.kp_fields = wp.empty(5 * fc, dtype=wp.float32, device=dev)
        self.kp_octave = wp.empty(fc, dtype=wp.int32, device=dev)
        self.desc = wp.empty((fc, ref.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        self.head = (wp.empty(C_NODES + n_levels, dtype=wp.int32, device="cpu",
                              pinned=dev.is_cuda))
        self.use_graph = bool(graph) and dev.is_cuda
        self.side = wp.Stream(dev) if dev.is_cuda else None
        self.graph = None
        self.runs = 0
        self.last_stream = None  # where the last frame's output copies were enqueued (CUDA)

    # -- the device program ---------------------------------------------------------------

    def stage_pyramid(self):
        scale_pyramid(self.levels[0], self.n_levels, self.params[1], out=self.levels)

    def stage_blur(self):
        blur_levels(self.levels, out=self.blurred_levels)

    def stage_detect(self):
        dev = self.device
        _, _, n_levels, ini_th, min_th = self.params
        self.counters.zero_()
        wp.launch(score_pixels, dim=self.n_pixels,
                  inputs=[wp.uint64(self.pyr.ptr), self.lt, n_levels, self.row_of_y,
                          self.col_of_x, min(ini_th, min_th)],
                  outputs=[self.scores], device=dev)
        wp.launch(suppress_pixels, dim=self.n_pixels,
                  inputs=[self.lt, n_levels, self.row_of_y, self.col_of_x, self.scores, ini_th,
                          self.cells_at, self.surv_region],
                  outputs=[self.counters, self.survivors], device=dev)
        wp.launch(select_candidates, dim=self.surv_cap,
                  inputs=[self.survivors, self.surv_region, self.lt, self.ft, self.roots, ini_th,
                          min_th, self.cells_at, self.cand_region, self.digits, self.root_bits],
                  outputs=[self.counters, self.cand, self.paths, self.sort_keys, self.order],
                  device=dev)

    def stage_quadtree(self):
        self.stage_sort()
        self.stage_nodes()
        self.stage_finals()

    def stage_sort(self):
        """Candidates sorted by quadtree path (fixed size: the padding goes last)."""
        dev = self.device
        wp.launch(pad_paths, dim=self.cand_cap,
                  inputs=[self.counters, self.surv_region, self.cand_region,
                          wp.int64((1 << self.sort_bits) - 1)],
                  outputs=[self.sort_keys], device=dev)
        wp.utils.radix_sort_pairs(self.sort_keys, self.order, self.cand_cap, 0, self.sort_bits)
        wp.launch(gather_paths, dim=self.cand_cap, inputs=[self.order, self.counters, self.paths],
                  outputs=[self.sorted_paths], device=dev)

    def stage_nodes(self):
        """Node counts per depth, DistributeOctTree's decisions, the second loop's order."""
        dev = self.device
        n_levels = self.n_levels
        cap = self.cand_cap
        wp.launch(count_depths, dim=cap,
                  inputs=[self.sorted_paths, self.counters, cap, self.digits, self.singles_at,
                          self.multis_at],
                  outputs=[self.lcp], device=dev)
        wp.launch(sum_depth_counts, dim=(n_levels, 2, DEPTHS),
                  inputs=[self.counters, self.singles_at, self.multis_at], outputs=[self.totals],
                  device=dev)
        wp.launch(plan_divisions, dim=n_levels, inputs=[self.lt, self.totals],
                  outputs=[self.ctl], device=dev)
        wp.launch(alloc_nodes, dim=cap,
                  inputs=[self.sorted_paths, self.lcp, self.counters, cap, self.lt, self.ctl,
                          self.groups_at],
                  outputs=[self.node_base, self.node_start, self.node_depth, self.node_count,
                           self.node_growth, self.groups], device=dev)
        wp.launch(link_nodes, dim=self.node_cap,
                  inputs=[self.lt, n_levels, self.counters, self.ctl, self.lcp, self.node_base,
                          self.node_start, self.node_depth],
                  outputs=[self.node_parent], device=dev)
        self.node_rank.zero_()
        self.node_grown.zero_()
        wp.launch(rank_nodes, dim=(self.node_cap, RANK_CHUNKS),
                  inputs=[self.lt, n_levels, self.counters, self.ctl, self.sorted_paths,
                          self.groups_at, self.groups, self.node_start, self.node_depth,
                          self.node_count, self.node_growth, self.node_parent],
                  outputs=[self.node_rank, self.node_grown], device=dev)

    def stage_finals(self):
        """The final list's nodes, their strongest points, sorted into the list order."""
        dev = self.device
        cap = self.cand_cap
        wp.launch(emit_finals, dim=cap,
                  inputs=[self.sorted_paths, self.order, self.lcp, self.cand, self.counters, cap,
                          self.lt, self.ctl, self.node_base, self.node_rank, self.node_grown,
                          self.place_bits],
                  outputs=[self.final_keys, self.final_values], device=dev)
        wp.launch(pad_keys, dim=self.final_cap,
                  inputs=[self.counters, int(C_FINAL), wp.int64((1 << self.final_bits) - 1)],
                  outputs=[self.final_keys], device=dev)
        wp.utils.radix_sort_pairs(self.final_keys, self.final_values, self.final_cap, 0,
                                  self.final_bits)

    def stage_describe(self):
        dev = self.device
        self.moments.zero_()
        wp.launch(accumulate_moments, dim=(self.final_cap, ref.PATCH_SIZE),
                  inputs=[wp.uint64(self.pyr.ptr), self.lt, self.counters, self.final_values,
                          self.cand],
                  outputs=[self.moments], device=dev)
        wp.launch(describe_levels, dim=(self.final_cap, ref.DESCRIPTOR_BYTES),
                  inputs=[wp.uint64(self.blurred.ptr), self.lt, self.ft, self.counters,
                          self.final_values, self.cand, self.moments, self.pattern],
                  outputs=[self.kp_fields, self.kp_octave, self.desc], device=dev)

    def program(self):
        """Every device stage, fixed shapes: what the graph holds. On CUDA the blur runs on a
        side stream, beside detection and the quadtree (the graph keeps the concurrency)."""
        self.stage_pyramid()
        if self.side is None:
            self.stage_blur()
            self.stage_detect()
            self.stage_quadtree()
        else:
            main = wp.get_stream(self.device)
            with wp.ScopedStream(self.side):  # waits for the pyramid on entry
                self.stage_blur()
            self.stage_detect()
            self.stage_quadtree()
            main.wait_stream(self.side)
        self.stage_describe()

    def launch(self):
        """Run the program: eagerly the first time (loads the modules), then from a graph."""
        if self.graph is not None:
            wp.capture_launch(self.graph)
            return
        if self.use_graph and self.runs > 0:
            try:
                with wp.ScopedCapture(device=self.device) as capture:
                    self.program()
                self.graph = capture.graph
            except Exception:  # noqa: BLE001 - e.g. inside a caller's capture: run eagerly
                self.use_graph = False
                self.program()
            else:
                wp.capture_launch(self.graph)
            return
        self.program()

    # -- one frame ------------------------------------------------------------------------

    def read_head(self) -> np.ndarray:
        """The counters the host needs (one sync): candidates, finals, overflow, nodes."""
        wp.copy(self.head, self.counters, count=self.head.shape[0])
        if self.device.is_cuda:
            wp.synchronize_stream(wp.get_stream(self.device))
        return self.head.numpy().copy()

    def overflowed(self, head: np.ndarray) -> bool:
        return bool(head[C_OVER] != 0 or head[C_FINAL] > self.final_cap
                    or np.any(head[C_NODES:C_NODES + self.n_levels] > self.node_caps))

    def run(self, src):
        """Extract from ``src`` (uint8 HxW on the plan's device): (Keypoints, descriptors)."""
        if self.device.is_cuda:
            # On another stream than the last frame, wait for that frame's output copies.
            stream = wp.get_stream(self.device)
            if self.last_stream is not None and self.last_stream is not stream:
                stream.wait_stream(self.last_stream)
            self.last_stream = stream
        wp.copy(self.levels[0], src)
        self.launch()
        self.runs += 1
        head = self.read_head()
        if self.overflowed(head):
            n_features, scale_factor, _, ini_th, min_th = self.params
            return extract_host(self.levels, n_features, scale_factor, ini_th, min_th,
                                blurred=self.blurred_levels)
        return self.take_outputs(int(head[C_FINAL]))

    def take_outputs(self, n: int):
        """Fresh arrays holding the frame's n keypoints (the plan's buffers are reused)."""
        dev = self.device
        octave = wp.empty(n, dtype=wp.int32, device=dev)
        desc = wp.empty((n, ref.DESCRIPTOR_BYTES), dtype=wp.uint8, device=dev)
        if n == 0:
            rows = [wp.empty(0, dtype=wp.float32, device=dev) for _ in range(5)]
            return Keypoints(*rows, octave), desc
        fields = wp.empty((5, n), dtype=wp.float32, device=dev)
        wp.copy(fields, self.kp_fields, count=5 * n)
        wp.copy(octave, self.kp_octave, count=n)
        wp.copy(desc, self.desc, count=n * ref.DESCRIPTOR_BYTES)
        return Keypoints(x=fields[0], y=fields[1], response=fields[2], size=fields[3],
                         angle=fields[4], octave=octave), desc


_plans: OrderedDict = OrderedDict()  # key -> idle plans, least recently used first
_plans_lock = threading.Lock()
_PLANS_PER_KEY = 8
_PLAN_KEYS = 16


def _acquire(key, make):
    with _plans_lock:
        free = _plans.get(key)
        if free:
            _plans.move_to_end(key)
            return free.pop()
    return make()


def _release(key, plan):
    with _plans_lock:
        free = _plans.setdefault(key, [])
        _plans.move_to_end(key)
        if len(free) < _PLANS_PER_KEY:
            free.append(plan)
        while len(_plans) > _PLAN_KEYS:
            _plans.popitem(last=False)


def orb(src, n_features: int, scale_factor: float, n_levels: int, ini_th_fast: int,
        min_th_fast: int, *, out=None) -> tuple:
    """ORB-SLAM2's extractor on ``src.device``: (Keypoints of device arrays, uint8 [N, 32]).

    Every stage, the quadtree included, runs on the device (on CUDA as one captured graph per
    size and parameter set, cached); the host syncs once to read the keypoint count. ``out``
    is not supported (the count is data-dependent) and ignored.
    """
    device = src.device
    h, w = int(src.shape[0]), int(src.shape[1])
    key = (str(device), h, w, int(n_features), float(scale_factor), int(n_levels),
           int(ini_th_fast), int(min_th_fast))
    plan = _acquire(key, lambda: Plan(device, h, w, int(n_features), float(scale_factor),
                                      int(n_levels), int(ini_th_fast), int(min_th_fast)))
    try:
        return plan.run(src)
    finally:
        _release(key, plan)


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
