"""Brute-force Hamming matching on Warp (rules as :mod:`warpvx.kernels_cpu.match_hamming`).

1. ``pack_words``: each descriptor row's bytes as little-endian uint32 words (zero padded);
2. ``find_nearest_sliced``: the train rows are cut into slices; a thread per (slice, query
   row) keeps the best and second-best (distance, index) pair of its slice as int64 keys
   (distance high, index low: the smaller key is the smaller distance, then the lower index,
   cv2's batchDistance tie rule). The query row's words sit in registers and the threads of
   a warp read the same train row at the same time (one broadcast load per word). Rows up to
   :data:`MAX_WORDS` words (64 bytes: ORB, BRISK); wider ones take ``find_nearest``, a thread
   per query over all train rows. ``merge_slices`` keeps the two smallest keys per query;
3. with ``cross_check``: the same with the roles swapped (a query is kept when its best
   train row's best query is itself);
4. ``compact_matches``: one block flags the kept queries, scans the flags and writes the
   pairs in query order, and the number of matches.

Host sync: one, to read the number of matches (the result's length). Scratch buffers and
recorded launches are reused between calls of the same sizes
(:func:`._launch.workspace`).
"""

from __future__ import annotations

import warp as wp

from ..errors import UnsupportedError
from ._launch import HostReadback, Recorded, workspace

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

NO_MATCH = wp.constant(2147483647)
NONE_KEY = wp.constant(wp.int64(0x7FFFFFFFFFFFFFFF))

MAX_WORDS = 16
TARGET_THREADS = 65536  # (slice, query) threads to aim for
MIN_SLICE_ROWS = 16  # train rows per slice at least
COMPACT_BLOCK = 1024  # lanes of compact_matches

vec16u = wp.types.vector(length=MAX_WORDS, dtype=wp.uint32)
vec2l = wp.types.vector(length=2, dtype=wp.int64)


@wp.struct
class Nearest:
    """Best and second-best train row of each query row (-1 and :data:`NO_MATCH` where there
    is none): int32 [N1] each."""

    best_idx: wp.array(dtype=wp.int32)
    best_dist: wp.array(dtype=wp.int32)
    second_idx: wp.array(dtype=wp.int32)
    second_dist: wp.array(dtype=wp.int32)


@wp.struct
class MatchRule:
    """Which pairs ``compact_matches`` keeps: mutual best matches only (``cross_check`` 1,
    ``t_query[t]`` the best query row of train row t), and/or Lowe's ratio test
    (``use_ratio`` 1: distance < ``ratio`` x second-best distance, in double as cv2)."""

    cross_check: int
    use_ratio: int
    ratio: wp.float64
    t_query: wp.array(dtype=wp.int32)


@wp.func
def pair_key(dist: int, index: int) -> wp.int64:
    return (wp.int64(dist) << wp.int64(32)) | wp.int64(index)


@wp.func
def push_top2(top: vec2l, key: wp.int64) -> vec2l:
    """The two smallest of ``top`` and ``key``, smallest first."""
    if key < top[0]:
        return vec2l(key, top[0])
    if key < top[1]:
        return vec2l(top[0], key)
    return top


@wp.func
def write_top2(q: int, top: vec2l, nearest: Nearest):
    """Query row ``q``'s entries of ``nearest`` from its two smallest keys."""
    nearest.best_idx[q] = -1
    nearest.best_dist[q] = NO_MATCH
    nearest.second_idx[q] = -1
    nearest.second_dist[q] = NO_MATCH
    if top[0] != NONE_KEY:
        nearest.best_idx[q] = int(top[0] & wp.int64(0xFFFFFFFF))
        nearest.best_dist[q] = int(top[0] >> wp.int64(32))
    if top[1] != NONE_KEY:
        nearest.second_idx[q] = int(top[1] & wp.int64(0xFFFFFFFF))
        nearest.second_dist[q] = int(top[1] >> wp.int64(32))


@wp.func
def kept_pair(q: int, nearest: Nearest, rule: MatchRule) -> int:
    """The train row matched to query ``q``, or -1 when the pair is dropped."""
    t = nearest.best_idx[q]
    if rule.cross_check != 0 and t >= 0:
        if rule.t_query[t] != q:
            t = -1
    # No second row (a single train row): the ratio test cannot reject.
    if t >= 0 and rule.use_ratio != 0 and nearest.second_dist[q] != NO_MATCH:
        if not (wp.float64(nearest.best_dist[q]) < rule.ratio * wp.float64(nearest.second_dist[q])):
            t = -1
    return t


@wp.kernel
def pack_words(desc: wp.array2d(dtype=wp.uint8), words: wp.array2d(dtype=wp.uint32)):
    """``words[i, w]``: bytes 4w..4w+3 of descriptor row i, little-endian, zero padded."""
    i, w = wp.tid()
    v = wp.uint32(0)
    for k in range(4):
        c = w * 4 + k
        if c < desc.shape[1]:
            v = v | (wp.uint32(desc[i, c]) << wp.uint32(8 * k))
    words[i, w] = v


@wp.kernel
def find_nearest_sliced(query: wp.array2d(dtype=wp.uint32), train: wp.array2d(dtype=wp.uint32),
                        slice_rows: int, partial: wp.array3d(dtype=wp.int64)):
    """partial[s, q] = the two smallest keys of query row q over train rows of slice s."""
    s, q = wp.tid()
    nwords = query.shape[1]
    qv = vec16u()
    for w in range(MAX_WORDS):
        if w < nwords:
            qv[w] = query[q, w]
    t0 = s * slice_rows
    t1 = wp.min(t0 + slice_rows, train.shape[0])
    top = vec2l(NONE_KEY, NONE_KEY)
    for t in range(t0, t1):
        d = int(0)
        for w in range(MAX_WORDS):
            if w < nwords:
                d += int(wp.bit_count(qv[w] ^ train[t, w]))
        top = push_top2(top, pair_key(d, t))
    partial[s, q, 0] = top[0]
    partial[s, q, 1] = top[1]


@wp.kernel
def merge_slices(partial: wp.array3d(dtype=wp.int64), nearest: Nearest):
    q = wp.tid()
    top = vec2l(NONE_KEY, NONE_KEY)
    for s in range(partial.shape[0]):
        top = push_top2(top, partial[s, q, 0])
        top = push_top2(top, partial[s, q, 1])
    write_top2(q, top, nearest)


@wp.kernel
def find_nearest(query: wp.array2d(dtype=wp.uint32), train: wp.array2d(dtype=wp.uint32),
                 nearest: Nearest):
    """Rows wider than MAX_WORDS words: a thread per query row over all train rows."""
    q = wp.tid()
    top = vec2l(NONE_KEY, NONE_KEY)
    for t in range(train.shape[0]):
        d = int(0)
        for w in range(query.shape[1]):
            d += int(wp.bit_count(query[q, w] ^ train[t, w]))
        top = push_top2(top, pair_key(d, t))
    write_top2(q, top, nearest)


@wp.kernel
def compact_matches(nearest: Nearest, rule: MatchRule, pairs: wp.array2d(dtype=wp.int32),
                    dist: wp.array(dtype=wp.int32), total: wp.array(dtype=wp.int32)):
    """Kept pairs in query order (one block: a scan of the keep flags per chunk)."""
    _blk, lane = wp.tid()
    lanes = wp.block_dim()
    nq = nearest.best_idx.shape[0]
    base = int(0)
    start = int(0)
    while start < nq:
        q = start + lane
        t = int(-1)
        if q < nq:
            t = kept_pair(q, nearest, rule)
        keep = int(0)
        if t >= 0:
            keep = 1
        flags = wp.tile(keep)
        m = base + wp.untile(wp.tile_scan_inclusive(flags)) - keep
        if keep == 1:
            pairs[m, 0] = q
            pairs[m, 1] = t
            dist[m] = nearest.best_dist[q]
        base += wp.tile_extract(wp.tile_sum(flags), 0)
        start += lanes
    if lane == 0:
        total[0] = base


@wp.kernel
def write_knn(nearest: Nearest, idx: wp.array2d(dtype=wp.int32), dist: wp.array2d(dtype=wp.int32)):
    """``idx[q]``, ``dist[q]``: the best (and, for k = 2 columns, second-best) of query q."""
    q = wp.tid()
    idx[q, 0] = nearest.best_idx[q]
    dist[q, 0] = nearest.best_dist[q]
    if idx.shape[1] > 1:
        idx[q, 1] = nearest.second_idx[q]
        dist[q, 1] = nearest.second_dist[q]


# --- host side -------------------------------------------------------------------------------


class _Words:
    """A descriptor set packed into uint32 words (a recorded ``pack_words`` launch)."""

    def __init__(self, desc):
        n, width = desc.shape
        self.words = wp.empty((n, (width + 3) // 4), dtype=wp.uint32, device=desc.device)
        self.cmd = Recorded(pack_words, self.words.shape, desc.device, desc=desc, words=self.words)

    def pack(self, desc):
        self.cmd.launch(desc=desc)
        return self.words


class _Nearest:
    """Best/second-best train row of each query row for one pair of packed word sets."""

    def __init__(self, query_words, train_words):
        device = query_words.device
        nq, words = query_words.shape
        nt = train_words.shape[0]
        self.out = Nearest()
        self.out.best_idx, self.out.best_dist, self.out.second_idx, self.out.second_dist = (
            wp.empty(nq, dtype=wp.int32, device=device) for _ in range(4))
        if words <= MAX_WORDS:
            slices = max(1, min(-(-nt // MIN_SLICE_ROWS), -(-TARGET_THREADS // nq)))
            rows = -(-nt // slices)
            slices = -(-nt // rows)
            partial = wp.empty((slices, nq, 2), dtype=wp.int64, device=device)
            self.cmds = [
                Recorded(find_nearest_sliced, (slices, nq), device, query=query_words,
                         train=train_words, slice_rows=rows, partial=partial),
                Recorded(merge_slices, nq, device, partial=partial, nearest=self.out),
            ]
        else:
            self.cmds = [Recorded(find_nearest, nq, device, query=query_words, train=train_words,
                                  nearest=self.out)]

    def run(self) -> Nearest:
        for cmd in self.cmds:
            cmd.launch()
        return self.out


class _MatchWorkspace:
    def __init__(self, desc1, desc2):
        device = desc1.device
        nq = desc1.shape[0]
        self.query = _Words(desc1)
        self.train = _Words(desc2)
        self.forward = _Nearest(self.query.words, self.train.words)
        self.backward = None  # cross check: train rows against the query rows
        self.total = wp.zeros(1, dtype=wp.int32, device=device)
        self.readback = HostReadback(1, wp.int32, device)
        self.rule_values = None  # (cross_check, ratio) of the recorded rule
        self.compact = Recorded(compact_matches, [1], device, block_dim=COMPACT_BLOCK,
                                nearest=self.forward.out, rule=MatchRule(),
                                pairs=wp.empty((nq, 2), dtype=wp.int32, device=device),
                                dist=wp.empty(nq, dtype=wp.int32, device=device),
                                total=self.total)
        self.knn = Recorded(write_knn, nq, device, nearest=self.forward.out,
                            idx=wp.empty((nq, 2), dtype=wp.int32, device=device),
                            dist=wp.empty((nq, 2), dtype=wp.int32, device=device))

    def nearest(self, desc1, desc2, cross_check: bool) -> Nearest:
        """The forward best/second-best rows; with ``cross_check``, the backward ones too
        (each train row's best query row), which the match rule then reads."""
        self.query.pack(desc1)
        self.train.pack(desc2)
        forward = self.forward.run()
        if cross_check:
            if self.backward is None:
                self.backward = _Nearest(self.train.words, self.query.words)
            self.backward.run()
        return forward

    def set_rule(self, cross_check: bool, ratio) -> None:
        """Make ``compact`` keep the pairs ``cross_check`` and ``ratio`` keep (a new
        :class:`MatchRule` when they change)."""
        values = (bool(cross_check), ratio)
        if values != self.rule_values:
            rule = MatchRule()
            rule.cross_check = int(values[0])
            rule.use_ratio = int(ratio is not None)
            rule.ratio = 0.0 if ratio is None else float(ratio)
            # Each train row's best query row; unread without cross_check.
            rule.t_query = (self.backward if cross_check else self.forward).out.best_idx
            self.rule_values = values
            self.compact.set(rule=rule)


def _workspace(desc1, desc2) -> _MatchWorkspace:
    return workspace("match_hamming", (desc1.shape[0], desc2.shape[0], desc1.shape[1]),
                     desc1.device, lambda: _MatchWorkspace(desc1, desc2))


def knn_match_hamming(desc1, desc2, k: int, *, out=None) -> tuple:
    """(int32 [N1, k] train indices, int32 [N1, k] distances), nearest first, k in {1, 2},
    k <= N2 (the best and second best); written into ``out`` = (indices, distances) on
    ``desc1.device`` when given. No host sync."""
    device = desc1.device
    nq = desc1.shape[0]
    if out is None:
        idx = wp.empty((nq, k), dtype=wp.int32, device=device)
        dist = wp.empty((nq, k), dtype=wp.int32, device=device)
    else:
        idx, dist = out
    if nq == 0 or k == 0:
        return idx, dist
    ws = _workspace(desc1, desc2)
    ws.nearest(desc1, desc2, False)
    ws.knn.launch(idx=idx, dist=dist)
    return idx, dist


def match_hamming(desc1, desc2, cross_check: bool, ratio, *, out=None) -> tuple:
    """(int32 [M, 2] (query, train) pairs, int32 [M] distances) on ``desc1.device``.

    Pairs are listed by increasing query index. One host sync reads M (the arrays are views
    of the first M rows of [N1]-row allocations). ``out`` is refused: M depends on the data.
    """
    if out is not None:
        raise UnsupportedError("out: match_hamming returns a data-dependent number of pairs; "
                               "it takes no out=")
    device = desc1.device
    nq, nt = desc1.shape[0], desc2.shape[0]
    if nq == 0 or nt == 0:
        return (wp.zeros((0, 2), dtype=wp.int32, device=device),
                wp.zeros(0, dtype=wp.int32, device=device))
    ws = _workspace(desc1, desc2)
    ws.nearest(desc1, desc2, bool(cross_check))
    ws.set_rule(cross_check, ratio)
    pairs = wp.empty((nq, 2), dtype=wp.int32, device=device)
    dist = wp.empty(nq, dtype=wp.int32, device=device)
    ws.compact.launch(pairs=pairs, dist=dist)
    m = int(ws.readback.read(ws.total)[0])  # the one host sync: the number of matches
    return pairs[:m], dist[:m]


__all__ = ["match_hamming", "knn_match_hamming"]
