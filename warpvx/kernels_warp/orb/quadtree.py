"""Kernels of the one-graph extractor's quadtree (``DistributeOctTree`` from node counts; see
:mod:`warpvx.kernels_warp.orb`): every level in each launch, every image of a batch (the first
thread index, 1-D over the images' items, as in :mod:`.kernels`)."""

from __future__ import annotations

import warp as wp

from .funcs import (C_FINAL, C_NODES, C_OVER, MODE_EMPTY, MODE_FULL, MODE_PARTIAL, MODE_PASSES,
                    N_DEPTHS, N_RANK_CHUNKS, N_STRIPES, PATH_LEVEL_SHIFT, STRIPES, Division,
                    LevelInfo, batch_candidate, batch_item, batch_key, batch_offset,
                    depth_counts, flipped_prefix, image_part, key_field, level_holding,
                    node_before, node_index, quadrant, run_start, shared_depth)

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

@wp.kernel
def count_depths(batch: int, paths: wp.array(dtype=wp.int64), counters: wp.array(dtype=wp.int32),
                 n_cap: int, digits: int, singles_at: int, multis_at: int,
                 lcp: wp.array(dtype=wp.int32)):
    """lcp[i]: the digits sorted point i shares with point i - 1 (-1: another root). Point i
    is alone from depth max(lcp[i], lcp[i+1]) + 1 on (one single-point node there); it starts
    a node of several points at each depth in (lcp[i], lcp[i+1]]. Two points sharing all the
    sorted ``digits`` (the plan's bound says they cannot) flag the frame for the host path."""
    b, i, n = batch_candidate(wp.tid(), batch, n_cap, counters)
    if i >= n:
        return
    paths = image_part(paths, b, batch)
    counters = image_part(counters, b, batch)
    lcp = image_part(lcp, b, batch)
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
def alloc_nodes(batch: int, paths: wp.array(dtype=wp.int64), lcp: wp.array(dtype=wp.int32),
                counters: wp.array(dtype=wp.int32), n_cap: int, levels: wp.array(dtype=LevelInfo),
                divisions: wp.array(dtype=Division), groups_at: int,
                node_base: wp.array(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
                node_depth: wp.array(dtype=wp.int32), node_count: wp.array(dtype=wp.int32),
                node_growth: wp.array(dtype=wp.int32), groups: wp.array4d(dtype=wp.int32)):
    """The multi-point nodes the second loop orders (depths K..g*), from the point starting
    them: consecutive entries of the level's pool, one per depth; their size and the nodes a
    division adds (children - 1, the points inside sharing exactly ``depth`` digits). Each is
    also listed in groups[level, depth] (the nodes rank_nodes compares)."""
    b, s, n = batch_candidate(wp.tid(), batch, n_cap, counters)
    if s >= n:
        return
    paths = image_part(paths, b, batch)
    lcp = image_part(lcp, b, batch)
    counters = image_part(counters, b, batch)
    divisions = image_part(divisions, b, batch)
    node_base = image_part(node_base, b, batch)
    node_start = image_part(node_start, b, batch)
    node_depth = image_part(node_depth, b, batch)
    node_count = image_part(node_count, b, batch)
    node_growth = image_part(node_growth, b, batch)
    groups = groups[b]
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
def live_node(t: int, batch: int, node_cap: int, levels: wp.array(dtype=LevelInfo),
              n_levels: int, counters: wp.array(dtype=wp.int32)):
    """(b, v, level): thread ``t`` of a launch over the batch's node slots (``node_cap`` an
    image) is slot v of image b, of quadtree level ``level``; level -1 when the slot holds no
    node: past the level's used nodes, or the level overflowed its capacity (its frame is
    then redone on the host)."""
    b, v = batch_item(t, batch, node_cap)
    level = level_holding(v, levels, n_levels, True)
    used = counters[batch_offset(b, counters.shape[0], batch) + C_NODES + level]
    if v - levels[level].node >= used or used > levels[level].node_cap:
        return b, v, -1
    return b, v, level


@wp.kernel
def link_nodes(batch: int, node_cap: int, levels: wp.array(dtype=LevelInfo), n_levels: int,
               counters: wp.array(dtype=wp.int32),
               divisions: wp.array(dtype=Division), lcp: wp.array(dtype=wp.int32),
               node_base: wp.array(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
               node_depth: wp.array(dtype=wp.int32), node_parent: wp.array(dtype=wp.int32)):
    """Each ordered node's parent (a node of the previous round), -1 at depth K."""
    b, v, level = live_node(wp.tid(), batch, node_cap, levels, n_levels, counters)
    if level < 0:
        return
    divisions = image_part(divisions, b, batch)
    lcp = image_part(lcp, b, batch)
    node_base = image_part(node_base, b, batch)
    node_start = image_part(node_start, b, batch)
    node_depth = image_part(node_depth, b, batch)
    node_parent = image_part(node_parent, b, batch)
    g = node_depth[v]
    k = divisions[level].k
    if g == k:
        node_parent[v] = -1
        return
    ps = run_start(lcp, node_start[v], g - 1)
    node_parent[v] = node_index(node_base, lcp, ps, g - 1, k)


@wp.kernel
def rank_nodes(batch: int, node_cap: int, levels: wp.array(dtype=LevelInfo), n_levels: int,
               counters: wp.array(dtype=wp.int32),
               divisions: wp.array(dtype=Division), paths: wp.array(dtype=wp.int64), groups_at: int,
               groups: wp.array4d(dtype=wp.int32), node_start: wp.array(dtype=wp.int32),
               node_depth: wp.array(dtype=wp.int32), node_count: wp.array(dtype=wp.int32),
               node_growth: wp.array(dtype=wp.int32), node_parent: wp.array(dtype=wp.int32),
               node_rank: wp.array(dtype=wp.int32), node_grown: wp.array(dtype=wp.int32)):
    """A node's place in its round's division order (the nodes of its group divided before
    it), and the nodes those divisions add; thread c of a node compares every
    N_RANK_CHUNKS-th member of its group (both arrays zeroed first, sums by atomics); node v
    of image b is thread row b * node_cap + v."""
    t, c = wp.tid()
    b, v, level = live_node(t, batch, node_cap, levels, n_levels, counters)
    if level < 0:
        return
    g = node_depth[b * node_cap + v]
    members = counters[batch_offset(b, counters.shape[0], batch) + groups_at + level * N_DEPTHS + g]
    if c >= members:
        return
    paths = image_part(paths, b, batch)
    groups = groups[b]
    node_start = image_part(node_start, b, batch)
    node_depth = image_part(node_depth, b, batch)
    node_count = image_part(node_count, b, batch)
    node_growth = image_part(node_growth, b, batch)
    node_parent = image_part(node_parent, b, batch)
    k = image_part(divisions, b, batch)[level].k
    n_ini = levels[level].n_ini
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
        wp.atomic_add(node_rank, b * node_cap + v, rank)
        wp.atomic_add(node_grown, b * node_cap + v, grown)


@wp.kernel
def emit_finals(batch: int, paths: wp.array(dtype=wp.int64), order: wp.array(dtype=wp.int32),
                lcp: wp.array(dtype=wp.int32), cand: wp.array(dtype=wp.int64),
                counters: wp.array(dtype=wp.int32), n_cap: int, levels: wp.array(dtype=LevelInfo),
                divisions: wp.array(dtype=Division), node_base: wp.array(dtype=wp.int32),
                node_rank: wp.array(dtype=wp.int32), node_grown: wp.array(dtype=wp.int32),
                place_bits: int, key_bits: int, final_keys: wp.array(dtype=wp.int64),
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
    b, s, n = batch_candidate(wp.tid(), batch, n_cap, counters)
    if s >= n:
        return
    paths = image_part(paths, b, batch)
    order = image_part(order, b, batch)
    lcp = image_part(lcp, b, batch)
    cand = image_part(cand, b, batch)
    counters = image_part(counters, b, batch)
    divisions = image_part(divisions, b, batch)
    node_base = image_part(node_base, b, batch)
    node_rank = image_part(node_rank, b, batch)
    node_grown = image_part(node_grown, b, batch)
    final_keys = image_part(final_keys, b, batch)
    final_values = image_part(final_values, b, batch)
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
