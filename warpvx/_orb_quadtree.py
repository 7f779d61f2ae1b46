"""ORB-SLAM2's ``DistributeOctTree`` on the host (NumPy), sequential as there.

Neutral module: the CPU extractor (``kernels_cpu.orb``) runs it on every level, the Warp
extractor (``kernels_warp.orb``) on a frame that overflows its device plan, and the tests
check the Warp device quadtree against it.
"""

from __future__ import annotations

import numpy as np

from ._orb_spec import MIN_BORDER, CellGrid, root_geometry

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
    n_ini, h_x, bounds, height = root_geometry(grid)
    px = (x.astype(np.float32) - np.float32(MIN_BORDER))
    py = (y.astype(np.float32) - np.float32(MIN_BORDER))
    resp = np.asarray(response, np.float32)
    point_node = np.minimum((px / h_x).astype(np.int64), n_ini - 1)
    counts = np.bincount(point_node, minlength=n_ini)
    alive = np.flatnonzero(counts > 0)  # empty root nodes are erased
    # The node list, in list order: bounds, point count, creation id (heap-address proxy).
    nodes = np.zeros((alive.size, 6), np.int64)
    nodes[:, _X0] = np.asarray(bounds)[alive]
    nodes[:, _X1] = np.asarray(bounds)[alive + 1]
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
