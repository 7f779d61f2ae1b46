"""Brute-force Hamming matching on Warp (rules as :mod:`warpvx.kernels_cpu.match_hamming`).

1. ``pack_words``: each descriptor row's bytes as little-endian uint32 words (zero padded);
2. ``find_nearest``: one thread per query row keeps the best and second-best distance over all
   train rows (``wp.bit_count`` of the XOR of 32-bit words; strict ``<`` updates, so the
   lowest train index wins a tie, as cv2's batchDistance);
3. with ``cross_check``: ``find_nearest`` again with the roles swapped (a query is kept when
   its best train row's best query is itself);
4. ``flag_matches``, a prefix sum and ``write_matches`` compact the kept pairs in query order.

Host sync: one, to read the number of matches (the result's length).
"""

from __future__ import annotations

import warp as wp

NO_MATCH = wp.constant(2147483647)


@wp.func
def hamming(a: wp.array2d(dtype=wp.uint32), i: int, b: wp.array2d(dtype=wp.uint32), j: int) -> int:
    d = int(0)
    for w in range(a.shape[1]):
        d += int(wp.bit_count(a[i, w] ^ b[j, w]))
    return d


@wp.kernel
def pack_words(desc: wp.array2d(dtype=wp.uint8), words: wp.array2d(dtype=wp.uint32)):
    i, w = wp.tid()
    v = wp.uint32(0)
    for k in range(4):
        c = w * 4 + k
        if c < desc.shape[1]:
            v = v | (wp.uint32(desc[i, c]) << wp.uint32(8 * k))
    words[i, w] = v


@wp.kernel
def find_nearest(query: wp.array2d(dtype=wp.uint32), train: wp.array2d(dtype=wp.uint32),
                 best_idx: wp.array(dtype=wp.int32), best_dist: wp.array(dtype=wp.int32),
                 second_idx: wp.array(dtype=wp.int32), second_dist: wp.array(dtype=wp.int32)):
    q = wp.tid()
    bd = int(NO_MATCH)
    sd = int(NO_MATCH)
    bi = int(-1)
    si = int(-1)
    for t in range(train.shape[0]):
        d = hamming(query, q, train, t)
        if d < bd:
            sd = bd
            si = bi
            bd = d
            bi = t
        elif d < sd:
            sd = d
            si = t
    best_idx[q] = bi
    best_dist[q] = bd
    second_idx[q] = si
    second_dist[q] = sd


@wp.kernel
def flag_matches(best_idx: wp.array(dtype=wp.int32), best_dist: wp.array(dtype=wp.int32),
                 second_dist: wp.array(dtype=wp.int32), t_query: wp.array(dtype=wp.int32),
                 cross_check: int, use_ratio: int, ratio: wp.float64,
                 pair_idx: wp.array(dtype=wp.int32), pair_dist: wp.array(dtype=wp.int32),
                 keep: wp.array(dtype=wp.int32)):
    q = wp.tid()
    t = best_idx[q]
    d = best_dist[q]
    if cross_check != 0 and t >= 0:
        if t_query[t] != q:
            t = -1
    k = int(0)
    if t >= 0:
        k = 1
        # No second row (a single train row): the test cannot reject.
        if use_ratio != 0 and second_dist[q] != NO_MATCH:
            if not (wp.float64(d) < ratio * wp.float64(second_dist[q])):
                k = 0
    pair_idx[q] = t
    pair_dist[q] = d
    keep[q] = k


@wp.kernel
def write_matches(pair_idx: wp.array(dtype=wp.int32), pair_dist: wp.array(dtype=wp.int32),
                  keep: wp.array(dtype=wp.int32), offset: wp.array(dtype=wp.int32),
                  pairs: wp.array2d(dtype=wp.int32), dist: wp.array(dtype=wp.int32)):
    q = wp.tid()
    if keep[q] != 0:
        m = offset[q]
        pairs[m, 0] = q
        pairs[m, 1] = pair_idx[q]
        dist[m] = pair_dist[q]


@wp.kernel
def count_matches(keep: wp.array(dtype=wp.int32), offset: wp.array(dtype=wp.int32),
                  total: wp.array(dtype=wp.int32)):
    n = keep.shape[0]
    total[0] = offset[n - 1] + keep[n - 1]


def _words(desc):
    n, width = desc.shape
    words = wp.empty((n, max(1, (width + 3) // 4)), dtype=wp.uint32, device=desc.device)
    if n:
        wp.launch(pack_words, dim=words.shape, inputs=[desc], outputs=[words], device=desc.device)
    return words


def _nearest(query_words, train_words):
    """(best index, best distance, second index, second distance) per query row."""
    n = query_words.shape[0]
    device = query_words.device
    out = [wp.empty(n, dtype=wp.int32, device=device) for _ in range(4)]
    wp.launch(find_nearest, dim=n, inputs=[query_words, train_words], outputs=out,
              device=device)
    return out


@wp.kernel
def write_knn(best_idx: wp.array(dtype=wp.int32), best_dist: wp.array(dtype=wp.int32),
              second_idx: wp.array(dtype=wp.int32), second_dist: wp.array(dtype=wp.int32),
              idx: wp.array2d(dtype=wp.int32), dist: wp.array2d(dtype=wp.int32)):
    q = wp.tid()
    idx[q, 0] = best_idx[q]
    dist[q, 0] = best_dist[q]
    if idx.shape[1] > 1:
        idx[q, 1] = second_idx[q]
        dist[q, 1] = second_dist[q]


def knn_match_hamming(desc1, desc2, k: int, *, out=None) -> tuple:
    """(int32 [N1, k] train indices, int32 [N1, k] distances), nearest first, k in {1, 2},
    k <= N2 (``find_nearest``'s best and second best). No host sync; ``out`` is ignored."""
    device = desc1.device
    nq = desc1.shape[0]
    idx = wp.empty((nq, k), dtype=wp.int32, device=device)
    dist = wp.empty((nq, k), dtype=wp.int32, device=device)
    if nq == 0 or k == 0:
        return idx, dist
    nearest = _nearest(_words(desc1), _words(desc2))
    wp.launch(write_knn, dim=nq, inputs=nearest, outputs=[idx, dist], device=device)
    return idx, dist


def match_hamming(desc1, desc2, cross_check: bool, ratio, *, out=None) -> tuple:
    """(int32 [M, 2] (query, train) pairs, int32 [M] distances) on ``desc1.device``.

    Pairs are listed by increasing query index. One host sync reads M; ``out`` is ignored.
    """
    device = desc1.device
    nq, nt = desc1.shape[0], desc2.shape[0]
    if nq == 0 or nt == 0:
        return (wp.zeros((0, 2), dtype=wp.int32, device=device),
                wp.zeros(0, dtype=wp.int32, device=device))
    qw, tw = _words(desc1), _words(desc2)
    best_idx, best_dist, _, second_dist = _nearest(qw, tw)
    t_query = _nearest(tw, qw)[0] if cross_check else best_idx  # unread without cross_check
    pair_idx = wp.empty(nq, dtype=wp.int32, device=device)
    pair_dist = wp.empty(nq, dtype=wp.int32, device=device)
    keep = wp.empty(nq, dtype=wp.int32, device=device)
    wp.launch(flag_matches, dim=nq,
              inputs=[best_idx, best_dist, second_dist, t_query, int(bool(cross_check)),
                      int(ratio is not None), wp.float64(0.0 if ratio is None else ratio)],
              outputs=[pair_idx, pair_dist, keep], device=device)
    offset = wp.empty(nq, dtype=wp.int32, device=device)
    wp.utils.array_scan(keep, offset, inclusive=False)
    total = wp.empty(1, dtype=wp.int32, device=device)
    wp.launch(count_matches, dim=1, inputs=[keep, offset], outputs=[total], device=device)
    m = int(total.numpy()[0])  # the one host sync: the number of matches sizes the result
    pairs = wp.empty((m, 2), dtype=wp.int32, device=device)
    dist = wp.empty(m, dtype=wp.int32, device=device)
    if m:
        wp.launch(write_matches, dim=nq, inputs=[pair_idx, pair_dist, keep, offset],
                  outputs=[pairs, dist], device=device)
    return pairs, dist


__all__ = ["match_hamming", "knn_match_hamming"]
