"""goodFeaturesToTrack on Warp: response, threshold, 3x3 maxima, sort, min-distance selection.

OpenCV's ``goodFeaturesToTrack`` (``featureselect.cpp``), all on ``src.device``:

1. the Harris or minimum-eigenvalue map (:mod:`.harris_response` kernels);
2. its maximum (``reduce_max_rows`` + ``atomic_max``), kept on the device;
3. candidates: pixels 1 px inside the image whose value survives THRESH_TOZERO at
   ``quality_level * max`` and equals the 3x3 dilation of the thresholded map, compacted
   with an atomic counter as 64-bit keys (value descending, then raster index descending:
   OpenCV's ``greaterThanPtr`` tie break), then radix-sorted;
4. the greedy min-distance pass. OpenCV walks the sorted list and keeps a point when no kept
   point lies within ``min_distance`` (and within the neighbouring grid cells of size
   ``round(min_distance)``). Its result is the lexicographically first maximal independent
   set of the conflict graph, which ``select_candidates`` reaches in parallel rounds: a
   candidate is rejected once a conflicting better-ranked candidate is accepted, accepted
   once all conflicting better-ranked ones are rejected. Decisions are final, so racing reads
   only delay a decision to the next round; the result equals the sequential one exactly.
5. the first ``max_corners`` accepted points in rank order (a prefix scan), as float32 [N, 2].

Host syncs: the candidate count (to size the sort), one flag read per batch of rounds, and
the final count.
"""

from __future__ import annotations

import math

import warp as wp

from .harris_response import corner_response

UNDECIDED = wp.constant(0)
ACCEPTED = wp.constant(1)
REJECTED = wp.constant(2)

ROW_CHUNK = 64  # pixels per thread in the max reduction
ROUNDS_PER_CHECK = 4


@wp.func
def float_order_key(v: float, bits: int) -> wp.int64:
    """A 32-bit unsigned key (in an int64) that orders like the float whose bits are given."""
    b = wp.int64(bits) & wp.int64(0xFFFFFFFF)
    if v < 0.0:
        return wp.int64(0xFFFFFFFF) - b
    return b | wp.int64(0x80000000)


@wp.func
def thresholded(v: float, thresh: float) -> float:
    """THRESH_TOZERO: v where v > thresh, else 0."""
    if v > thresh:
        return v
    return 0.0


@wp.kernel
def reduce_max_rows(response: wp.array2d(dtype=wp.float32), chunk: int,
                    max_value: wp.array(dtype=wp.float32)):
    y, cx = wp.tid()
    w = response.shape[1]
    x0 = cx * chunk
    m = response[y, x0]
    for x in range(x0 + 1, wp.min(x0 + chunk, w)):
        m = wp.max(m, response[y, x])
    wp.atomic_max(max_value, 0, m)


@wp.kernel
def collect_candidates(
    response: wp.array2d(dtype=wp.float32),
    response_bits: wp.array2d(dtype=wp.int32),
    max_value: wp.array(dtype=wp.float32),
    quality_level: float,
    count: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int64),
):
    y, x = wp.tid()
    h = response.shape[0]
    w = response.shape[1]
    if y < 1 or x < 1 or y >= h - 1 or x >= w - 1:
        return
    thresh = max_value[0] * quality_level
    v = thresholded(response[y, x], thresh)
    if v == 0.0:
        return
    for i in range(-1, 2):
        for j in range(-1, 2):
            if thresholded(response[y + i, x + j], thresh) > v:
                return
    slot = wp.atomic_add(count, 0, 1)
    if slot < keys.shape[0] // 2:
        order = wp.int64(0xFFFFFFFF) - float_order_key(v, response_bits[y, x])
        raster = wp.int64(y * w + x)
        keys[slot] = (order << wp.int64(31)) | (wp.int64(0x7FFFFFFF) - raster)


@wp.kernel
def rank_candidates(
    keys: wp.array(dtype=wp.int64),
    width: int,
    cand_x: wp.array(dtype=wp.int32),
    cand_y: wp.array(dtype=wp.int32),
    rank: wp.array2d(dtype=wp.int32),
):
    i = wp.tid()
    raster = int(wp.int64(0x7FFFFFFF) - (keys[i] & wp.int64(0x7FFFFFFF)))
    y = raster // width
    x = raster - y * width
    cand_x[i] = x
    cand_y[i] = y
    rank[y, x] = i


@wp.kernel
def select_candidates(
    cand_x: wp.array(dtype=wp.int32),
    cand_y: wp.array(dtype=wp.int32),
    rank: wp.array2d(dtype=wp.int32),
    radius: int,
    cell: int,
    min_dist_sq: wp.float64,
    state: wp.array(dtype=wp.int32),
    undecided: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    if state[i] != UNDECIDED:
        return
    x = cand_x[i]
    y = cand_y[i]
    h = rank.shape[0]
    w = rank.shape[1]
    cx = x // cell
    cy = y // cell
    blocked = bool(False)
    for yy in range(wp.max(y - radius, 0), wp.min(y + radius, h - 1) + 1):
        if wp.abs(yy // cell - cy) <= 1:
            for xx in range(wp.max(x - radius, 0), wp.min(x + radius, w - 1) + 1):
                j = rank[yy, xx]
                if j >= 0 and j < i and wp.abs(xx // cell - cx) <= 1:
                    d2 = wp.float64((xx - x) * (xx - x) + (yy - y) * (yy - y))
                    if d2 < min_dist_sq:
                        s = state[j]
                        if s == ACCEPTED:
                            state[i] = REJECTED
                            return
                        if s == UNDECIDED:
                            blocked = True
    if blocked:
        wp.atomic_add(undecided, 0, 1)
    else:
        state[i] = ACCEPTED


@wp.kernel
def flag_accepted(state: wp.array(dtype=wp.int32), flags: wp.array(dtype=wp.int32)):
    i = wp.tid()
    flags[i] = wp.where(state[i] == ACCEPTED, 1, 0)


@wp.kernel
def write_selected(
    cand_x: wp.array(dtype=wp.int32),
    cand_y: wp.array(dtype=wp.int32),
    flags: wp.array(dtype=wp.int32),
    slots: wp.array(dtype=wp.int32),
    limit: int,
    points: wp.array2d(dtype=wp.float32),
):
    i = wp.tid()
    s = slots[i] - 1  # inclusive scan: the rank among accepted points, from 1
    if flags[i] == 1 and s < limit:
        points[s, 0] = float(cand_x[i])
        points[s, 1] = float(cand_y[i])


def harris_corners(src, max_corners: int, quality_level: float, min_distance: float,
                   block_size: int, k: float, *, ksize: int = 3, score: str = "harris",
                   out=None):
    """Strongest corners of a gray uint8 ``wp.array2d``: float32 [N, 2] (x, y) on its device."""
    device = src.device
    h, w = src.shape
    response = wp.empty((h, w), dtype=wp.float32, device=device)
    corner_response(src, block_size, ksize, k, score, response)
    if h < 3 or w < 3:  # no pixel 1 px inside the image
        return wp.empty((0, 2), dtype=wp.float32, device=device)

    max_value = wp.full(1, -math.inf, dtype=wp.float32, device=device)
    chunks = (w + ROW_CHUNK - 1) // ROW_CHUNK
    wp.launch(reduce_max_rows, dim=(h, chunks), inputs=[response, ROW_CHUNK],
              outputs=[max_value], device=device)

    # The float map seen as its bit patterns, to build exact sort keys.
    bits = response.view(wp.int32)
    capacity = (h - 2) * (w - 2)
    count = wp.zeros(1, dtype=wp.int32, device=device)
    keys = wp.empty(2 * capacity, dtype=wp.int64, device=device)
    wp.launch(collect_candidates, dim=(h, w),
              inputs=[response, bits, max_value, float(quality_level)],
              outputs=[count, keys], device=device)
    n = min(int(count.numpy()[0]), capacity)  # host sync: sizes the sort
    if n == 0:
        return wp.empty((0, 2), dtype=wp.float32, device=device)
    values = wp.empty(2 * n, dtype=wp.int32, device=device)
    wp.utils.radix_sort_pairs(keys, values, n, 0, 63)

    cand_x = wp.empty(n, dtype=wp.int32, device=device)
    cand_y = wp.empty(n, dtype=wp.int32, device=device)
    rank = wp.full((h, w), -1, dtype=wp.int32, device=device)
    wp.launch(rank_candidates, dim=n, inputs=[keys, w], outputs=[cand_x, cand_y, rank],
              device=device)

    state = wp.zeros(n, dtype=wp.int32, device=device)
    if min_distance >= 1:
        cell = int(round(min_distance))  # cvRound (half to even, as Python's round)
        radius = int(math.ceil(min_distance))
        undecided = wp.zeros(1, dtype=wp.int32, device=device)
        while True:
            for _ in range(ROUNDS_PER_CHECK):
                undecided.zero_()
                wp.launch(select_candidates, dim=n,
                          inputs=[cand_x, cand_y, rank, radius, cell,
                                  float(min_distance) ** 2],
                          outputs=[state, undecided], device=device)
            if int(undecided.numpy()[0]) == 0:  # host sync per batch of rounds
                break
    else:
        state.fill_(1)  # no suppression: every candidate is kept

    flags = wp.empty(n, dtype=wp.int32, device=device)
    wp.launch(flag_accepted, dim=n, inputs=[state], outputs=[flags], device=device)
    slots = wp.empty(n, dtype=wp.int32, device=device)
    wp.utils.array_scan(flags, slots, inclusive=True)
    limit = n if max_corners <= 0 else min(int(max_corners), n)
    points = wp.empty((limit, 2), dtype=wp.float32, device=device)
    wp.launch(write_selected, dim=n, inputs=[cand_x, cand_y, flags, slots, limit],
              outputs=[points], device=device)
    accepted = int(slots[n - 1 :].numpy()[0])  # host sync: the count
    return points[: min(accepted, limit)]
