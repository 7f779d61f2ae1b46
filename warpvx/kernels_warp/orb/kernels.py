"""Kernels of the one-graph ORB extractor: every level in each launch (see :mod:`.plan`)."""

from __future__ import annotations

import warp as wp

from ... import _orb_spec as spec
from .._filtering import round_shift, taps16i
from .._sampling import read_reflect101
from ..fast_corners import fast_score
from .funcs import (C_CAND, C_CAND_R, C_FINAL, C_NODES, C_OVER, C_SURV_R, HALF_PATCH,
                    KEY_CELL_SHIFT, KEY_LEVEL_SHIFT, KEY_X_SHIFT, KEY_Y_SHIFT, MODE_EMPTY,
                    MODE_FULL, MODE_PARTIAL, MODE_PASSES, N_DEPTHS, N_RANK_CHUNKS, N_STRIPES,
                    PATH_DEPTH, PATH_LEVEL_SHIFT, PATH_ROOT_SHIFT, STRIPES, UMAX, Division,
                    LevelInfo, batch_key, batch_level_image, batch_pad, candidate_key,
                    depth_counts, describe_byte, fast_atan2, flipped_prefix, key_field,
                    level_holding, node_before, node_index, quadrant, quadtree_path, run_start,
                    shared_depth)

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

DESCRIPTOR_BYTES = wp.constant(spec.DESCRIPTOR_BYTES)
# Radius of the 7x7 Gaussian ORB describes on.
BLUR_RADIUS = wp.constant(3)

# --------------------------------------------------------------------------------------------
# Kernels of the one-graph extractor (all levels per launch, all images of a batch)
#
# Each kernel runs over (image, ...) of a batch of equal-sized images: its first thread index
# is the image b. Per-image buffers carry the image as their first index and each kernel takes
# its image's part first (``counters = counters[b]``: a view, no copy), so the body reads as
# for one image and every index stored in a buffer is one of the image's own. The pyramids
# are flat and level-major (:func:`.funcs.batch_level_image`); the two radix sorts sort the
# whole batch at once, the image above each key (:func:`.funcs.batch_key`).
# --------------------------------------------------------------------------------------------


@wp.kernel
def blur_edge_rows(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                   kx: taps16i, ky: taps16i, shift: int, blurred: wp.uint64):
    """The 7x7 Gaussian (BORDER_REFLECT_101) of the BLUR_RADIUS rows at the top and bottom
    of every level of every image, from the quantised taps of ``_filtering.blur_taps``: exact
    integer row sums, weighted column sum, one rounding shift, the integers of OpenCV's 8-bit
    GaussianBlur (so bit-exact). The batch's levels are blurred as [batch * h, w] blocks, where
    these rows read the neighbouring image instead of reflecting: this redoes them."""
    b, level, e, x = wp.tid()
    info = levels[level]
    if x >= info.width:
        return
    y = e
    if e >= BLUR_RADIUS:
        y = info.height - 2 * BLUR_RADIUS + e
    img = batch_level_image(pyr, levels, level, batch, b)
    acc = int(0)
    for dy in range(-BLUR_RADIUS, BLUR_RADIUS + 1):
        row = int(0)
        for dx in range(-BLUR_RADIUS, BLUR_RADIUS + 1):
            row += kx[wp.abs(dx)] * read_reflect101(img, y + dy, x + dx)
        acc += ky[wp.abs(dy)] * row
    out = batch_level_image(blurred, levels, level, batch, b)
    out[y, x] = round_shift(acc, shift)


@wp.kernel
def gather_heads(counters: wp.array2d(dtype=wp.int32), heads: wp.array2d(dtype=wp.int32)):
    """heads[b, j] = counters[b, j]: each image's leading counters in one block (one copy to
    the host)."""
    b, j = wp.tid()
    heads[b, j] = counters[b, j]


@wp.kernel
def score_pixels(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo), n_levels: int,
                 row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                 threshold: int, scores: wp.array2d(dtype=wp.uint8)):
    """FAST score at ``threshold`` of each pixel a cell owns (>= 19 px inside), 0 elsewhere."""
    b, i = wp.tid()
    scores = scores[b]
    level = level_holding(i, levels, n_levels, False)
    info = levels[level]
    w = info.width
    r = i - info.pix
    y = r // w
    x = r - y * w
    s = int(0)
    if row_of_y[info.row + y] >= 0 and col_of_x[info.col + x] >= 0:
        s = fast_score(batch_level_image(pyr, levels, level, batch, b), y, x, threshold)
    scores[i] = wp.uint8(s)


@wp.kernel
def suppress_pixels(levels: wp.array(dtype=LevelInfo), n_levels: int,
                    row_of_y: wp.array(dtype=wp.int32), col_of_x: wp.array(dtype=wp.int32),
                    scores: wp.array2d(dtype=wp.uint8), ini_th: int, cells_at: int, region: int,
                    counters: wp.array2d(dtype=wp.int32), survivors: wp.array2d(dtype=wp.int64)):
    """OpenCV's strict 3x3 maximum within the cell: append the survivors (candidate keys) to
    the region of stripe i % N_STRIPES, and count those >= ``ini_th`` per cell."""
    b, i = wp.tid()
    scores = scores[b]
    counters = counters[b]
    survivors = survivors[b]
    s = int(scores[i])
    if s == 0:
        return
    level = level_holding(i, levels, n_levels, False)
    info = levels[level]
    w = info.width
    r = i - info.pix
    y = r // w
    x = r - y * w
    ro = info.row
    co = info.col
    cr = row_of_y[ro + y]
    cc = col_of_x[co + x]
    # Owned pixels lie >= 19 px inside the level: the neighbours exist.
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if dy != 0 or dx != 0:
                if row_of_y[ro + y + dy] == cr and col_of_x[co + x + dx] == cc:
                    if int(scores[i + dy * w + dx]) >= s:
                        return
    cell = cr * info.n_cols + cc
    if s >= ini_th:
        wp.atomic_add(counters, cells_at + info.cell + cell, 1)
    stripe = i % N_STRIPES
    slot = wp.atomic_add(counters, C_SURV_R + stripe, 1)
    # Past the capacity the count still grows: pad_paths flags it, the frame takes extract_host.
    if slot < region:
        survivors[stripe * region + slot] = candidate_key(level, cell, y, x, s)


@wp.kernel
def select_candidates(survivors: wp.array2d(dtype=wp.int64), surv_region: int,
                      levels: wp.array(dtype=LevelInfo),
                      roots: wp.array(dtype=wp.int32), ini_th: int, min_th: int, cells_at: int,
                      cand_region: int, digits: int, root_bits: int, key_bits: int,
                      counters: wp.array2d(dtype=wp.int32), cand: wp.array2d(dtype=wp.int64),
                      paths: wp.array2d(dtype=wp.int64), sort_keys: wp.array2d(dtype=wp.int64),
                      order: wp.array2d(dtype=wp.int32)):
    """Keep a survivor when its score reaches its cell's threshold; write its candidate key,
    its quadtree path, the path's sort key (level | root | first ``digits`` quadrants) and its
    slot (the sort's value) into the region of stripe j % N_STRIPES."""
    b, j = wp.tid()
    survivors = survivors[b]
    counters = counters[b]
    cand = cand[b]
    paths = paths[b]
    sort_keys = sort_keys[b]
    order = order[b]
    r = j // surv_region
    if j - r * surv_region >= wp.min(counters[C_SURV_R + r], surv_region):
        return
    key = survivors[j]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    cell = key_field(key, KEY_CELL_SHIFT, 0x3FFFF)
    s = key_field(key, 0, 0xFF)
    th = min_th
    if counters[cells_at + levels[level].cell + cell] > 0:
        th = ini_th
    if s < th:
        return
    stripe = j % N_STRIPES
    slot = wp.atomic_add(counters, C_CAND_R + stripe, 1)
    if slot < cand_region:
        at = stripe * cand_region + slot
        cand[at] = key
        path = quadtree_path(level, key_field(key, KEY_X_SHIFT, 0xFFFF),
                             key_field(key, KEY_Y_SHIFT, 0xFFFF), levels, roots)
        paths[at] = path
        root = (path >> wp.int64(PATH_ROOT_SHIFT)) & wp.int64(511)
        kept = (path & wp.int64(0xFFFFFFFF)) >> wp.int64(2 * (PATH_DEPTH - digits))
        sort_keys[at] = batch_key(b, key_bits, (((wp.int64(level) << wp.int64(root_bits)) | root)
                                                << wp.int64(2 * digits)) | kept)
        order[at] = at


@wp.kernel
def pad_paths(counters: wp.array2d(dtype=wp.int32), surv_region: int, cand_region: int,
              key_bits: int, sort_keys: wp.array2d(dtype=wp.int64)):
    """Pad the candidate regions' unused slots (a fixed-size sort puts them last); thread 0
    writes the candidate total and whether a region overflowed."""
    b, i = wp.tid()
    counters = counters[b]
    sort_keys = sort_keys[b]
    r = i // cand_region
    if i - r * cand_region >= counters[C_CAND_R + r]:
        sort_keys[i] = batch_pad(b, key_bits)
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
def pad_keys(counters: wp.array2d(dtype=wp.int32), which: int, key_bits: int,
             keys: wp.array2d(dtype=wp.int64)):
    """keys[i] = the image's padding key past the count (a fixed-size sort puts them last)."""
    b, i = wp.tid()
    counters = counters[b]
    keys = keys[b]
    if i >= counters[which]:
        keys[i] = batch_pad(b, key_bits)


@wp.kernel
def gather_paths(order: wp.array2d(dtype=wp.int32), counters: wp.array2d(dtype=wp.int32),
                 paths: wp.array2d(dtype=wp.int64), sorted_paths: wp.array2d(dtype=wp.int64)):
    """The full paths in sorted order."""
    b, i = wp.tid()
    order = order[b]
    counters = counters[b]
    paths = paths[b]
    sorted_paths = sorted_paths[b]
    if i < counters[C_CAND]:
        sorted_paths[i] = paths[order[i]]


@wp.kernel
def count_depths(paths: wp.array2d(dtype=wp.int64), counters: wp.array2d(dtype=wp.int32),
                 n_cap: int,
                 digits: int, singles_at: int, multis_at: int, lcp: wp.array2d(dtype=wp.int32)):
    """lcp[i]: the digits sorted point i shares with point i - 1 (-1: another root). Point i
    is alone from depth max(lcp[i], lcp[i+1]) + 1 on (one single-point node there); it starts
    a node of several points at each depth in (lcp[i], lcp[i+1]]. Two points sharing all the
    sorted ``digits`` (the plan's bound says they cannot) flag the frame for the host path."""
    b, i = wp.tid()
    paths = paths[b]
    counters = counters[b]
    lcp = lcp[b]
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
def sum_depth_counts(counters: wp.array2d(dtype=wp.int32), singles_at: int, multis_at: int,
                     totals: wp.array4d(dtype=wp.int32)):
    """totals[level, 0 | 1, depth]: single- | multi-point nodes, summed over the stripes."""
    b, level, which, g = wp.tid()
    counters = counters[b]
    totals = totals[b]
    base = singles_at
    if which == 1:
        base = multis_at
    total = int(0)
    for s in range(STRIPES):
        total += counters[base + (level * N_STRIPES + s) * N_DEPTHS + g]
    totals[level, which, g] = total


@wp.kernel
def plan_divisions(levels: wp.array(dtype=LevelInfo), totals: wp.array4d(dtype=wp.int32),
                   divisions: wp.array2d(dtype=Division)):
    """DistributeOctTree's control flow from node counts (one thread per level).

    With S_g, M_g the single- and multi-point nodes created at depth g (a node is created when
    its parent has several points), A_g = S_g + M_g, pass k of the first loop leaves
    N_k = A_k + sum_{g<k} S_g nodes; it stops at the first k with N_k >= n or no growth
    (MODE_PASSES), or goes on to divide largest first when N_k + 3 M_k > n. Each round of that
    second loop divides the multi-point nodes of one depth g, adding A_{g+1} - M_g nodes; the
    last round is the one reaching n (MODE_PARTIAL) or adding nothing (MODE_FULL).
    """
    b, level = wp.tid()
    totals = totals[b]
    divisions = divisions[b]
    n = levels[level].want
    singles = depth_counts(totals, level, 0)
    multis = depth_counts(totals, level, 1)
    if singles[0] + multis[0] == 0:
        empty = Division()
        empty.mode = MODE_EMPTY
        divisions[level] = empty
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
    d = Division()
    d.k = k
    d.gstar = g
    d.mode = mode
    d.size = size
    divisions[level] = d


@wp.kernel
def alloc_nodes(paths: wp.array2d(dtype=wp.int64), lcp: wp.array2d(dtype=wp.int32),
                counters: wp.array2d(dtype=wp.int32), n_cap: int, levels: wp.array(dtype=LevelInfo),
                divisions: wp.array2d(dtype=Division), groups_at: int,
                node_base: wp.array2d(dtype=wp.int32), node_start: wp.array2d(dtype=wp.int32),
                node_depth: wp.array2d(dtype=wp.int32), node_count: wp.array2d(dtype=wp.int32),
                node_growth: wp.array2d(dtype=wp.int32), groups: wp.array4d(dtype=wp.int32)):
    """The multi-point nodes the second loop orders (depths K..g*), from the point starting
    them: consecutive entries of the level's pool, one per depth; their size and the nodes a
    division adds (children - 1, the points inside sharing exactly ``depth`` digits). Each is
    also listed in groups[level, depth] (the nodes rank_nodes compares)."""
    b, s = wp.tid()
    paths = paths[b]
    lcp = lcp[b]
    counters = counters[b]
    divisions = divisions[b]
    node_base = node_base[b]
    node_start = node_start[b]
    node_depth = node_depth[b]
    node_count = node_count[b]
    node_growth = node_growth[b]
    groups = groups[b]
    n = wp.min(counters[C_CAND], n_cap)
    if s >= n:
        return
    level = int(paths[s] >> wp.int64(PATH_LEVEL_SHIFT))
    mode = divisions[level].mode
    node_base[s] = -1
    if mode != MODE_FULL and mode != MODE_PARTIAL:
        return
    k = divisions[level].k
    hi = int(-1)
    if s + 1 < n:
        hi = lcp[s + 1]
    g0 = wp.max(lcp[s] + 1, k)
    g1 = wp.min(hi, divisions[level].gstar)
    if g0 > g1:
        return
    base = wp.atomic_add(counters, C_NODES + level, g1 - g0 + 1)
    if base + g1 - g0 + 1 > levels[level].node_cap:
        return  # the host sees the count past the capacity
    first = levels[level].node + base
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
def live_node_level(v: int, levels: wp.array(dtype=LevelInfo), n_levels: int,
                    counters: wp.array(dtype=wp.int32)) -> int:
    """The level of node slot ``v``, or -1 when the slot holds no node: past the level's used
    nodes, or the level overflowed its capacity (its frame is then redone on the host)."""
    level = level_holding(v, levels, n_levels, True)
    used = counters[C_NODES + level]
    if v - levels[level].node >= used or used > levels[level].node_cap:
        return -1
    return level


@wp.kernel
def link_nodes(levels: wp.array(dtype=LevelInfo), n_levels: int, counters: wp.array2d(dtype=wp.int32),
               divisions: wp.array2d(dtype=Division), lcp: wp.array2d(dtype=wp.int32),
               node_base: wp.array2d(dtype=wp.int32), node_start: wp.array2d(dtype=wp.int32),
               node_depth: wp.array2d(dtype=wp.int32), node_parent: wp.array2d(dtype=wp.int32)):
    """Each ordered node's parent (a node of the previous round), -1 at depth K."""
    b, v = wp.tid()
    counters = counters[b]
    divisions = divisions[b]
    lcp = lcp[b]
    node_base = node_base[b]
    node_start = node_start[b]
    node_depth = node_depth[b]
    node_parent = node_parent[b]
    level = live_node_level(v, levels, n_levels, counters)
    if level < 0:
        return
    g = node_depth[v]
    k = divisions[level].k
    if g == k:
        node_parent[v] = -1
        return
    ps = run_start(lcp, node_start[v], g - 1)
    node_parent[v] = node_index(node_base, lcp, ps, g - 1, k)


@wp.kernel
def rank_nodes(levels: wp.array(dtype=LevelInfo), n_levels: int, counters: wp.array2d(dtype=wp.int32),
               divisions: wp.array2d(dtype=Division), paths: wp.array2d(dtype=wp.int64), groups_at: int,
               groups: wp.array4d(dtype=wp.int32), node_start: wp.array2d(dtype=wp.int32),
               node_depth: wp.array2d(dtype=wp.int32), node_count: wp.array2d(dtype=wp.int32),
               node_growth: wp.array2d(dtype=wp.int32), node_parent: wp.array2d(dtype=wp.int32),
               node_rank: wp.array2d(dtype=wp.int32), node_grown: wp.array2d(dtype=wp.int32)):
    """A node's place in its round's division order (the nodes of its group divided before
    it), and the nodes those divisions add; thread c of a node compares every
    N_RANK_CHUNKS-th member of its group (both arrays zeroed first, sums by atomics)."""
    b, v, c = wp.tid()
    counters = counters[b]
    divisions = divisions[b]
    paths = paths[b]
    groups = groups[b]
    node_start = node_start[b]
    node_depth = node_depth[b]
    node_count = node_count[b]
    node_growth = node_growth[b]
    node_parent = node_parent[b]
    node_rank = node_rank[b]
    node_grown = node_grown[b]
    level = live_node_level(v, levels, n_levels, counters)
    if level < 0:
        return
    g = node_depth[v]
    k = divisions[level].k
    n_ini = levels[level].n_ini
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
def emit_finals(paths: wp.array2d(dtype=wp.int64), order: wp.array2d(dtype=wp.int32),
                lcp: wp.array2d(dtype=wp.int32), cand: wp.array2d(dtype=wp.int64),
                counters: wp.array2d(dtype=wp.int32), n_cap: int, levels: wp.array(dtype=LevelInfo),
                divisions: wp.array2d(dtype=Division), node_base: wp.array2d(dtype=wp.int32),
                node_rank: wp.array2d(dtype=wp.int32), node_grown: wp.array2d(dtype=wp.int32),
                place_bits: int, key_bits: int, final_keys: wp.array2d(dtype=wp.int64),
                final_values: wp.array2d(dtype=wp.int32)):
    """For each node of the final list (from the point starting it): its strongest point and
    its list position key.

    A point alone from depth sd on ends in that single-point node when sd <= g*; otherwise it
    lies in a multi-point node of depth g*, final unless the last round divided it (then its
    child is). Segments, newest first: the children of the last round, then each round's and
    pass's nodes back to the roots; inside a segment, a node created by the second loop goes
    by its parent's division order (reversed) and quadrant (reversed), a node of the first
    loop by ``flipped_prefix``.
    """
    b, s = wp.tid()
    paths = paths[b]
    order = order[b]
    lcp = lcp[b]
    cand = cand[b]
    counters = counters[b]
    divisions = divisions[b]
    node_base = node_base[b]
    node_rank = node_rank[b]
    node_grown = node_grown[b]
    final_keys = final_keys[b]
    final_values = final_values[b]
    n = wp.min(counters[C_CAND], n_cap)
    if s >= n:
        return
    path = paths[s]
    level = int(path >> wp.int64(PATH_LEVEL_SHIFT))
    mode = divisions[level].mode
    k = divisions[level].k
    gstar = divisions[level].gstar
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
            if divisions[level].size + node_grown[node] < levels[level].want:
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
        place = flipped_prefix(path, depth, levels[level].n_ini)
    else:
        parent = node_index(node_base, lcp, run_start(lcp, s, depth - 1), depth - 1, k)
        if parent < 0:
            return
        rank_max = (wp.int64(1) << wp.int64(place_bits - 2)) - wp.int64(1)
        place = (((rank_max - wp.int64(node_rank[parent])) << wp.int64(2))
                 | wp.int64(3 - quadrant(path, depth)))
    slot = wp.atomic_add(counters, C_FINAL, 1)
    if slot < final_keys.shape[0]:
        segment = (wp.int64(level) << wp.int64(5)) | wp.int64(31 - depth)
        final_keys[slot] = batch_key(b, key_bits, (segment << wp.int64(place_bits)) | place)
        final_values[slot] = best


@wp.kernel
def accumulate_moments(pyr: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                       counters: wp.array2d(dtype=wp.int32),
                       final_values: wp.array2d(dtype=wp.int32),
                       cand: wp.array2d(dtype=wp.int64), moments: wp.array3d(dtype=wp.int32)):
    """IC_Angle's moments of keypoint i, one disc row v per thread: m10 += sum u I,
    m01 += v sum I (integer sums: the order of the atomics does not matter)."""
    b, i, r = wp.tid()
    counters = counters[b]
    final_values = final_values[b]
    cand = cand[b]
    moments = moments[b]
    if i >= wp.min(counters[C_FINAL], moments.shape[0]):
        return
    key = cand[final_values[i]]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    cx = key_field(key, KEY_X_SHIFT, 0xFFFF)
    cy = key_field(key, KEY_Y_SHIFT, 0xFFFF)
    img = batch_level_image(pyr, levels, level, batch, b)
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
def describe_levels(blurred: wp.uint64, batch: int, levels: wp.array(dtype=LevelInfo),
                    counters: wp.array2d(dtype=wp.int32),
                    final_values: wp.array2d(dtype=wp.int32), cand: wp.array2d(dtype=wp.int64),
                    moments: wp.array3d(dtype=wp.int32), pattern: wp.array2d(dtype=wp.int32),
                    kp_fields: wp.array2d(dtype=wp.float32), kp_octave: wp.array2d(dtype=wp.int32),
                    desc: wp.array3d(dtype=wp.uint8)):
    """Descriptor byte j of keypoint i on its blurred level; thread j = 0 also writes the
    keypoint's level-0 fields. ``kp_fields`` holds x, y, response, size, angle as a (5, n)
    block, n the keypoint count, so one contiguous copy takes them out."""
    b, i, j = wp.tid()
    counters = counters[b]
    final_values = final_values[b]
    cand = cand[b]
    moments = moments[b]
    kp_fields = kp_fields[b]
    kp_octave = kp_octave[b]
    desc = desc[b]
    n = wp.min(counters[C_FINAL], desc.shape[0])
    if i >= n:
        return
    key = cand[final_values[i]]
    level = key_field(key, KEY_LEVEL_SHIFT, 31)
    x = key_field(key, KEY_X_SHIFT, 0xFFFF)
    y = key_field(key, KEY_Y_SHIFT, 0xFFFF)
    angle = fast_atan2(float(moments[i, 1]), float(moments[i, 0]))
    img = batch_level_image(blurred, levels, level, batch, b)
    desc[i, j] = wp.uint8(describe_byte(img, y, x, angle, pattern, j))
    if j == 0:
        s = levels[level].scale
        kp_fields[i] = float(x) * s
        kp_fields[n + i] = float(y) * s
        kp_fields[2 * n + i] = float(key_field(key, 0, 0xFF))
        kp_fields[3 * n + i] = levels[level].kp_size
        kp_fields[4 * n + i] = angle
        kp_octave[i] = level




@wp.kernel
def pack_outputs(starts: wp.array(dtype=wp.int32), kp_fields: wp.array2d(dtype=wp.float32),
                 kp_octave: wp.array2d(dtype=wp.int32), desc: wp.array3d(dtype=wp.uint8),
                 fields: wp.array2d(dtype=wp.float32), octave: wp.array(dtype=wp.int32),
                 packed: wp.array2d(dtype=wp.uint8)):
    """Keypoint i of image b (describe_levels' per-image rows) to row starts[b] + i of the
    batch's packed outputs: its descriptor, its five fields (a (5, N) block) and octave."""
    b, i = wp.tid()
    at = starts[b]
    n = starts[b + 1] - at
    if i >= n:
        return
    for j in range(DESCRIPTOR_BYTES):
        packed[at + i, j] = desc[b, i, j]
    for f in range(5):
        fields[f, at + i] = kp_fields[b, f * n + i]
    octave[at + i] = kp_octave[b, i]
