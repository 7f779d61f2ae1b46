"""The Warp ORB extractor's constants, key layouts and device functions (``@wp.func``).

Shared by the one-graph kernels (:mod:`.kernels`) and the host-quadtree path (:mod:`.host`);
the algorithm's own constants come from :mod:`warpvx._orb_spec`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

from ... import _orb_spec as spec
from .._sampling import read_reflect101, round_coord

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

vec16i = wp.types.vector(length=16, dtype=wp.int32)

UMAX = wp.constant(vec16i(*[int(v) for v in spec.umax()]))
HALF_PATCH = wp.constant(spec.HALF_PATCH_SIZE)
ATAN_P1 = wp.constant(wp.float32(spec.ATAN_P1))
ATAN_P3 = wp.constant(wp.float32(spec.ATAN_P3))
ATAN_P5 = wp.constant(wp.float32(spec.ATAN_P5))
ATAN_P7 = wp.constant(wp.float32(spec.ATAN_P7))
ATAN_EPS = wp.constant(wp.float32(spec.ATAN_EPS))
DEG_TO_RAD = wp.constant(wp.float32(np.float32(np.pi / 180.0)))
MIN_BORDER = wp.constant(spec.MIN_BORDER)

# Candidate keys, int64: level (5 bits) | cell (18) | y (16) | x (16) | score (8), so that
# sorting the keys sorts the candidates in ORB-SLAM2's order (level, cell row, cell column,
# y, x) and no key is negative. Images up to _orb_spec.MAX_SIDE px a side fit.
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


@wp.struct
class LevelInfo:
    """One pyramid level of a plan: its place in the flat buffers, its cell grid and its
    quadtree's constants (an array of these, one per level, is the plan's level table)."""

    pix: int  # offset of the level in the flat pyramids (pixels)
    width: int
    height: int
    row: int  # offset of its row_of_y in the flat table
    col: int  # offset of its col_of_x
    n_cols: int  # cell columns
    cell: int  # offset of its cells in the per-cell counts
    want: int  # features wanted (n_l)
    n_ini: int  # root nodes
    root: int  # offset of its root boundaries
    qt_height: int  # quadtree height (maxBorderY - minBorderY)
    node: int  # offset of its node pool
    node_cap: int  # its node pool's size
    hx: float  # root node width
    scale: float  # s_l
    kp_size: float  # ORB-SLAM2's keypoint size, int(31 s_l)


@wp.struct
class Division:
    """DistributeOctTree's decisions for one level (written by ``plan_divisions``)."""

    k: int  # pass at which the first loop stops
    gstar: int  # depth of the last division round (k when there is none)
    mode: int  # MODE_*
    size: int  # list size before the last round


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
def batch_level_image(base: wp.uint64, levels: wp.array(dtype=LevelInfo), level: int,
                      batch: int, b: int):
    """Level ``level`` of image ``b`` of a batch of ``batch`` flat pyramids (a view, no copy).

    The batch's pyramids are stored level-major: level l of every image, one after the other,
    from ``batch * pix_l``, so level l of the whole batch is one [batch, h_l, w_l] block (one
    resize or blur launch covers it). With ``batch`` 1: level l at ``pix_l``.

    A raw pointer because the 2-D device functions (``fast_score``, ``read_reflect101``,
    ``describe_byte``) take a 2-D array and Warp cannot reshape part of a typed 1-D array in a
    kernel. In bounds: the view spans ``width * height`` pixels of a buffer the plan allocated
    as ``batch`` times the sum of all level sizes, and every read through it is a pixel of the
    view (FAST on owned pixels, >= 19 px inside the level; the other reads reflect into it).
    """
    info = levels[level]
    offset = batch * info.pix + b * info.width * info.height
    return wp.array(ptr=base + wp.uint64(offset), shape=(info.height, info.width),
                    dtype=wp.uint8)


@wp.func
def batch_key(b: int, bits: int, key: wp.int64) -> wp.int64:
    """Sort key ``key`` (< 2^bits) of image ``b`` of a batch: the image above it, so one radix
    sort of the whole batch leaves each image's keys in one run, images in order."""
    return (wp.int64(b) << wp.int64(bits)) | key


@wp.func
def batch_pad(b: int, bits: int) -> wp.int64:
    """The padding key of image ``b``: after its real keys (< 2^(bits-1)), before image b+1's."""
    return batch_key(b, bits, (wp.int64(1) << wp.int64(bits)) - wp.int64(1))


@wp.func
def level_holding(i: int, levels: wp.array(dtype=LevelInfo), n_levels: int, node: bool) -> int:
    """The level whose range starts at or before ``i``: of flat pixels, or of quadtree node
    slots when ``node``."""
    level = int(0)
    while level + 1 < n_levels:
        start = levels[level + 1].pix
        if node:
            start = levels[level + 1].node
        if i < start:
            break
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
def quadtree_path(level: int, x: int, y: int, levels: wp.array(dtype=LevelInfo),
                  roots: wp.array(dtype=wp.int32)) -> wp.int64:
    """Path key of a candidate: its root column (``vpIniNodes[x / hX]``) and the quadrant it
    falls in at each of 16 successive ``DivideNode`` splits (float coordinates relative to the
    border, integer node bounds, split at ceil(half) as there)."""
    info = levels[level]
    px = float(x - MIN_BORDER)
    py = float(y - MIN_BORDER)
    root = wp.min(int(px / info.hx), info.n_ini - 1)
    x0 = roots[info.root + root]
    x1 = roots[info.root + root + 1]
    y0 = int(0)
    y1 = info.qt_height
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


@wp.func
def batch_image(t: int, batch: int, n: int) -> int:
    """The image of item ``t`` of a batch's flat range (``batch`` runs of ``n``): t // n,
    without the division for one image (it costs every thread on the CPU device)."""
    if batch == 1:
        return 0
    return t // n


@wp.func
def batch_item(t: int, batch: int, n: int):
    """(b, i): item ``t`` of a batch's flat range is item i of image b (:func:`batch_image`).
    A pair costs a little per thread on the CPU device: kernels of a thread per pixel use
    :func:`batch_image`."""
    b = batch_image(t, batch, n)
    return b, t - b * n


@wp.func
def image_part(a: wp.array(dtype=Any), b: int, batch: int):
    """Image ``b``'s part of a per-image buffer seen flat (``batch`` equal parts): a view,
    no copy; no division for one image."""
    n = a.shape[0]
    if batch > 1:
        n = n // batch
    return a[b * n:(b + 1) * n]


@wp.func
def batch_offset(b: int, size: int, batch: int) -> int:
    """Where image ``b``'s part starts in a per-image buffer of ``size`` items seen flat (1-D
    arrays only: Warp's CPU device runs such kernels with constant strides); no division for
    image 0."""
    if b == 0:
        return 0
    return b * (size // batch)


@wp.func
def batch_candidate(t: int, batch: int, n_cap: int, counters: wp.array(dtype=wp.int32)):
    """(b, s, n): thread ``t`` of a launch over the batch's candidate slots (``n_cap`` an image)
    is slot s of image b, which holds n = min(its candidate count, n_cap) candidates (s >= n:
    no candidate); ``counters`` the batch's counters seen flat."""
    b, s = batch_item(t, batch, n_cap)
    return b, s, wp.min(counters[batch_offset(b, counters.shape[0], batch) + C_CAND], n_cap)


@wp.func
def batch_final(t: int, batch: int, final_cap: int, counters: wp.array2d(dtype=wp.int32),
                final_values: wp.array2d(dtype=wp.int32), cand: wp.array2d(dtype=wp.int64)):
    """(b, i, key, level, x, y): thread ``t`` of a launch over the batch's final slots
    (``final_cap`` an image) is final keypoint i of image b: its candidate key, level and
    level coordinates; i = -1 past the image's keypoints (the rest then 0)."""
    b, i = batch_item(t, batch, final_cap)
    if i >= wp.min(counters[b, C_FINAL], final_cap):
        return b, -1, wp.int64(0), 0, 0, 0
    key = cand[b, final_values[b, i]]
    return (b, i, key, key_field(key, KEY_LEVEL_SHIFT, 31), key_field(key, KEY_X_SHIFT, 0xFFFF),
            key_field(key, KEY_Y_SHIFT, 0xFFFF))
