"""goodFeaturesToTrack on Warp: response, threshold, 3x3 maxima, sort, min-distance selection.

OpenCV's ``goodFeaturesToTrack`` (``featureselect.cpp``), all on ``src.device``:

1. the Harris or minimum-eigenvalue map (:mod:`.harris_response` kernels);
2. its maximum: a block reduction per row (``reduce_row_max``), then one block over the rows
   (``finish_max``, which also resets the per-call counters), kept on the device;
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
   First ``find_conflicts`` walks each candidate's window once (a thread per window row) and
   lists its better-ranked conflicts (up to :data:`MAX_CONFLICTS`; a candidate with more
   walks its window in every round), so the rounds only read short lists. Rounds are launched in
   batches; a round whose predecessor left nothing undecided returns at once, so no host
   sync is needed between rounds.
5. the first ``max_corners`` accepted points in rank order (a block scan, ``write_selected``,
   which stops once ``max_corners`` are written), as float32 [N, 2].

Host syncs: two; the candidate count (to size the sort), and the accepted count together with
the number of candidates still undecided after the batch (a further batch runs when it is not
zero, which the batch size, learnt from the previous call, makes rare). With ``out=`` (a
:class:`~warpvx._counted.Counted`: a graph's fixed buffers) none:
:class:`.harris_counted.DeviceCorners` sorts and decides the rounds on the device, so the
call can be captured. Scratch buffers
(response, keys, rank map) and recorded launches are reused between calls of one image size
(:func:`._launch.workspace`); the rank map is kept at -1 between calls by clearing only
the entries a call set.
"""

from __future__ import annotations

import math

import warp as wp

from .._counted import refuse_uncounted
from ._launch import HostReadback, Recorded, drop_workspace, workspace
from .harris_response import corner_response

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

UNDECIDED = wp.constant(0)
ACCEPTED = wp.constant(1)
REJECTED = wp.constant(2)

BLOCK = 256  # lanes of the block reductions
# Lanes of the output scan (``write_selected``): it walks the ranked candidates a block at a
# time until ``max_corners`` are accepted, thousands on a real frame: wider blocks, fewer steps.
SCAN_BLOCK = 1024
MAX_ROUNDS = 64  # undecided counters per call (rounds launched over all batches)
FIRST_BATCH = 8  # rounds launched in the first call of a size (later: learnt)
MAX_CONFLICTS = 16  # better-ranked conflicts listed per candidate (more: walk the window)
# Threads of a per-candidate launch at most, each taking every CANDIDATE_THREADS-th candidate.
# A graph's corners are sized for every pixel (a million slots at 1280x720), and a launch over
# all of them, nearly all idle, cost ~8 us of device time on an H100 (16 selection rounds:
# 135 us a two-camera frame); real frames have some thousands of candidates.
CANDIDATE_THREADS = 16384
NEG_INF = wp.constant(-math.inf)


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
def reduce_row_max(response: wp.array2d(dtype=wp.float32), row_max: wp.array(dtype=wp.float32)):
    """row_max[y] = max of row y (one block per row)."""
    y, lane = wp.tid()
    lanes = wp.block_dim()
    w = response.shape[1]
    m = float(NEG_INF)
    x = lane
    while x < w:
        m = wp.max(m, response[y, x])
        x += lanes
    v = wp.tile_extract(wp.tile_max(wp.tile(m)), 0)
    if lane == 0:
        row_max[y] = v


@wp.kernel
def finish_max(
    row_max: wp.array(dtype=wp.float32),
    max_value: wp.array(dtype=wp.float32),
    count: wp.array(dtype=wp.int32),
    undecided: wp.array(dtype=wp.int32),
):
    """max_value[0] = max of row_max (one block); also resets the per-call counters."""
    _blk, lane = wp.tid()
    lanes = wp.block_dim()
    m = float(NEG_INF)
    y = lane
    while y < row_max.shape[0]:
        m = wp.max(m, row_max[y])
        y += lanes
    v = wp.tile_extract(wp.tile_max(wp.tile(m)), 0)
    if lane == 0:
        max_value[0] = v
        count[0] = 0
    r = lane
    while r < undecided.shape[0]:
        undecided[r] = 0
        r += lanes


@wp.struct
class CandidateKeys:
    """Candidates compacted as unique sort keys: ``keys[:count[0]]`` (the upper half of
    ``keys`` is the radix sort's scratch). A key is the value's order (descending) above the
    raster index (descending) in its low ``raster_bits`` bits."""

    keys: wp.array(dtype=wp.int64)
    count: wp.array(dtype=wp.int32)
    raster_bits: int


@wp.struct
class Candidates:
    """The sorted candidates: candidate ``i`` (its rank) lies at ``(x[i], y[i])`` and has
    decision ``state[i]``; ``rank[y, x]`` is ``i`` on its pixel and -1 elsewhere. There are
    ``count[0]`` of them, capped at ``len(x)`` (the counter of :class:`CandidateKeys`)."""

    x: wp.array(dtype=wp.int32)
    y: wp.array(dtype=wp.int32)
    state: wp.array(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)
    rank: wp.array2d(dtype=wp.int32)


@wp.struct
class Spacing:
    """The min-distance rule: candidates conflict when closer than ``sqrt(min_dist_sq)``
    (``radius`` = its ceiling) and in neighbouring grid cells of ``cell`` px."""

    radius: int
    cell: int
    min_dist_sq: wp.float64


@wp.struct
class Conflicts:
    """Each candidate's better-ranked conflicts: ``lists[i, :count[i]]``; a ``count[i]`` above
    the list's room means the list overflowed and the window is walked instead."""

    lists: wp.array2d(dtype=wp.int32)
    count: wp.array(dtype=wp.int32)


@wp.func
def candidate_count(cands: Candidates) -> int:
    return wp.min(cands.count[0], cands.x.shape[0])


@wp.kernel
def collect_candidates(
    response: wp.array2d(dtype=wp.float32),
    response_bits: wp.array2d(dtype=wp.int32),
    max_value: wp.array(dtype=wp.float32),
    quality_level: float,
    keys: CandidateKeys,
):
    """Pixels 1 px inside whose thresholded value is a 3x3 maximum, as sort keys."""
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
    slot = wp.atomic_add(keys.count, 0, 1)
    if slot < keys.keys.shape[0] // 2:
        order = wp.int64(0xFFFFFFFF) - float_order_key(v, response_bits[y, x])
        mask = (wp.int64(1) << wp.int64(keys.raster_bits)) - wp.int64(1)
        raster = wp.int64(y * w + x)
        keys.keys[slot] = (order << wp.int64(keys.raster_bits)) | (mask - raster)


@wp.kernel
def rank_candidates(keys: CandidateKeys, initial_state: int, cands: Candidates,
                    conflicts: Conflicts, stride: int):
    """Candidate ``i`` from sorted key ``i``: its position, its rank on the map, its initial
    state; its conflict count zeroed. Thread ``t`` of ``stride`` takes ``t, t + stride, ..``."""
    width = cands.rank.shape[1]
    mask = (wp.int64(1) << wp.int64(keys.raster_bits)) - wp.int64(1)
    for i in range(wp.tid(), candidate_count(cands), stride):
        if i < conflicts.count.shape[0]:
            conflicts.count[i] = 0
        raster = int(mask - (keys.keys[i] & mask))
        y = raster // width
        x = raster - y * width
        cands.x[i] = x
        cands.y[i] = y
        cands.rank[y, x] = i
        cands.state[i] = initial_state


@wp.func
def conflicts_in_row(i: int, yy: int, cands: Candidates, spacing: Spacing,
                     conflicts: Conflicts, record_list: bool) -> wp.vec2i:
    """The better-ranked candidates in row ``yy`` conflicting with candidate ``i`` (within
    the min distance, in the neighbouring grid cells). With ``record_list`` they are appended
    to ``conflicts.lists[i]`` (counted in ``conflicts.count[i]``, kept while there is room);
    else their states are read: returns (any accepted, any undecided), stopping at the first
    accepted."""
    x = cands.x[i]
    y = cands.y[i]
    w = cands.rank.shape[1]
    cell = spacing.cell
    radius = spacing.radius
    cx = x // cell
    accepted = int(0)
    undecided = int(0)
    if wp.abs(yy // cell - y // cell) <= 1:
        for xx in range(wp.max(x - radius, 0), wp.min(x + radius, w - 1) + 1):
            j = cands.rank[yy, xx]
            if j >= 0 and j < i and wp.abs(xx // cell - cx) <= 1:
                d2 = wp.float64((xx - x) * (xx - x) + (yy - y) * (yy - y))
                if d2 < spacing.min_dist_sq:
                    if record_list:
                        slot = wp.atomic_add(conflicts.count, i, 1)
                        if slot < conflicts.lists.shape[1]:
                            conflicts.lists[i, slot] = j
                    else:
                        s = cands.state[j]
                        if s == ACCEPTED:
                            return wp.vec2i(1, undecided)
                        if s == UNDECIDED:
                            undecided = 1
    return wp.vec2i(accepted, undecided)


@wp.kernel
def find_conflicts(cands: Candidates, spacing: Spacing, conflicts: Conflicts,
                   undecided: wp.array(dtype=wp.int32), stride: int):
    """List each candidate's better-ranked conflicts once, a thread per (candidate, window
    row); thread ``(t, row)`` takes candidates ``t, t + stride, ..``."""
    t, row = wp.tid()
    if t == 0 and row == 0:
        undecided[0] = 1  # round 1 decides (a candidate without conflicts is accepted there)
    n = wp.min(candidate_count(cands), conflicts.count.shape[0])
    for i in range(t, n, stride):
        yy = cands.y[i] - spacing.radius + row
        if yy >= 0 and yy < cands.rank.shape[0]:
            conflicts_in_row(i, yy, cands, spacing, conflicts, True)


@wp.func
def decide(i: int, cands: Candidates, spacing: Spacing, conflicts: Conflicts,
           round_index: int, undecided: wp.array(dtype=wp.int32)):
    """Undecided candidate ``i``: rejected when a conflict is accepted, accepted when all its
    conflicts are rejected, else counted in ``undecided[round_index]``."""
    accepted = int(0)
    blocked = int(0)
    listed = conflicts.count[i]
    if listed <= conflicts.lists.shape[1]:
        for c in range(listed):
            s = cands.state[conflicts.lists[i, c]]
            if s == ACCEPTED:
                accepted = 1
                break
            if s == UNDECIDED:
                blocked = 1
    else:
        y = cands.y[i]
        for yy in range(wp.max(y - spacing.radius, 0), wp.min(y + spacing.radius, cands.rank.shape[0] - 1) + 1):
            if accepted == 0:
                r = conflicts_in_row(i, yy, cands, spacing, conflicts, False)
                accepted = r[0]
                blocked = wp.max(blocked, r[1])
    if accepted != 0:
        cands.state[i] = REJECTED
    elif blocked != 0:
        wp.atomic_add(undecided, round_index, 1)
    else:
        cands.state[i] = ACCEPTED


@wp.kernel
def select_candidates(cands: Candidates, spacing: Spacing, conflicts: Conflicts,
                      round_index: int, undecided: wp.array(dtype=wp.int32), stride: int):
    """One round (``round_index`` >= 1) deciding candidates' states; ``undecided[round_index]``
    counts the candidates it left undecided. Thread ``t`` takes ``t, t + stride, ..``."""
    if undecided[round_index - 1] == 0:
        return  # the previous round decided everything
    for i in range(wp.tid(), candidate_count(cands), stride):
        if cands.state[i] == UNDECIDED:
            decide(i, cands, spacing, conflicts, round_index, undecided)


@wp.kernel
def write_selected(
    cands: Candidates,
    undecided: wp.array(dtype=wp.int32),
    last_round: int,
    points: wp.array2d(dtype=wp.float32),
    result: wp.array(dtype=wp.int32),
):
    """The first ``len(points)`` accepted candidates in rank order (one block, a scan per
    chunk of candidates); result = (points written, undecided after ``last_round``, rounds
    that had work)."""
    _blk, lane = wp.tid()
    lanes = wp.block_dim()
    n = candidate_count(cands)
    limit = points.shape[0]
    base = int(0)
    start = int(0)
    while start < n:
        if base >= limit:
            break
        i = start + lane
        f = int(0)
        if i < n:
            if cands.state[i] == ACCEPTED:
                f = 1
        t = wp.tile(f)
        rank_incl = wp.untile(wp.tile_scan_inclusive(t))
        s = base + rank_incl - f
        if f == 1 and s < limit:
            points[s, 0] = float(cands.x[i])
            points[s, 1] = float(cands.y[i])
        base += wp.tile_extract(wp.tile_sum(t), 0)
        start += lanes
    if lane == 0:
        result[0] = wp.min(base, limit)
        result[1] = undecided[last_round]
        used = last_round + 1
        for r in range(last_round + 1):
            if used == last_round + 1 and undecided[r] == 0:
                used = r + 1
        result[2] = used


@wp.kernel
def clear_ranks(cands: Candidates, stride: int):
    """Put the rank map back to -1 where this call wrote it (thread ``t`` takes candidates
    ``t, t + stride, ..``)."""
    for i in range(wp.tid(), candidate_count(cands), stride):
        cands.rank[cands.y[i], cands.x[i]] = -1


def _bucket(n: int) -> int:
    """Launch size for ``n`` candidates: a power of two, so it rarely changes between calls."""
    return max(256, 1 << (n - 1).bit_length())


class _CornersWorkspace:
    """Scratch of one image size, with recorded launches of the fixed-size kernels."""

    def __init__(self, h: int, w: int, device):
        self.device = device
        capacity = (h - 2) * (w - 2)
        self.capacity = capacity
        self.response = wp.empty((h, w), dtype=wp.float32, device=device)
        self.row_max = wp.empty(h, dtype=wp.float32, device=device)
        self.max_value = wp.empty(1, dtype=wp.float32, device=device)
        self.undecided = wp.zeros(MAX_ROUNDS, dtype=wp.int32, device=device)
        self.result = wp.zeros(3, dtype=wp.int32, device=device)
        self.keys = CandidateKeys()
        self.keys.keys = wp.empty(2 * capacity, dtype=wp.int64, device=device)
        self.keys.count = wp.zeros(1, dtype=wp.int32, device=device)
        self.keys.raster_bits = max(1, int(h * w - 1).bit_length())
        self.values = wp.empty(2 * capacity, dtype=wp.int32, device=device)
        self.cands = Candidates()
        self.cands.x = wp.empty(capacity, dtype=wp.int32, device=device)
        self.cands.y = wp.empty(capacity, dtype=wp.int32, device=device)
        self.cands.state = wp.empty(capacity, dtype=wp.int32, device=device)
        self.cands.count = self.keys.count
        self.cands.rank = wp.full((h, w), -1, dtype=wp.int32, device=device)
        self.conflicts = Conflicts()  # sized by resize()
        self.count_back = HostReadback(1, wp.int32, device)
        self.result_back = HostReadback(3, wp.int32, device)
        self.batch = FIRST_BATCH
        self.row_max_cmd = Recorded(reduce_row_max, [h], device, block_dim=BLOCK,
                                    response=self.response, row_max=self.row_max)
        self.finish_cmd = Recorded(finish_max, [1], device, block_dim=BLOCK, row_max=self.row_max,
                                   max_value=self.max_value, count=self.keys.count,
                                   undecided=self.undecided)
        self.collect_cmd = Recorded(collect_candidates, (h, w), device, response=self.response,
                                    # The float map seen as its bit patterns, for exact keys.
                                    response_bits=self.response.view(wp.int32),
                                    max_value=self.max_value, quality_level=0.0, keys=self.keys)
        self.bucket = 256
        self.threads = self.bucket  # of the per-candidate launches (their stride)
        self.rank_cmd = Recorded(rank_candidates, self.threads, device, keys=self.keys,
                                 initial_state=0, cands=self.cands, conflicts=self.conflicts,
                                 stride=self.threads)
        self.clear_cmd = Recorded(clear_ranks, self.threads, device, cands=self.cands,
                                  stride=self.threads)
        self.select_cmd = Recorded(write_selected, [1], device, block_dim=SCAN_BLOCK, cands=self.cands,
                                   undecided=self.undecided, last_round=0,
                                   points=wp.empty((0, 2), dtype=wp.float32, device=device),
                                   result=self.result)
        self.spacing = None
        self.find_cmd = None
        self.round_cmds: list = [None]  # recorded per round index (>= 1) on first use

    def resize(self, n: int):
        """Size the conflict lists for ``_bucket(n)`` candidates and launch the per-candidate
        kernels over as many threads, at most :data:`CANDIDATE_THREADS`."""
        b = _bucket(n)
        self.bucket = b
        threads = min(b, CANDIDATE_THREADS)
        if threads != self.threads:
            self.threads = threads
            for cmd in [self.rank_cmd, self.clear_cmd, *self.round_cmds]:
                if cmd is not None:
                    cmd.set_dim(threads)
                    cmd.set(stride=threads)
            if self.find_cmd is not None:
                self.find_cmd.set_dim((threads, 2 * self.spacing.radius + 1))
                self.find_cmd.set(stride=threads)
        if self.conflicts.count is None or self.conflicts.count.shape[0] < b:
            # Sized by the bucket; the recorded launches take it at their next use.
            self.conflicts = Conflicts()
            self.conflicts.lists = wp.empty((b, MAX_CONFLICTS), dtype=wp.int32, device=self.device)
            self.conflicts.count = wp.empty(b, dtype=wp.int32, device=self.device)

    def set_spacing(self, radius: int, cell: int, min_dist_sq: float):
        """Record :data:`find_conflicts` for a min-distance rule; the rounds are recorded again
        on first use."""
        values = (radius, cell, min_dist_sq)
        if self.spacing is not None and values == (self.spacing.radius, self.spacing.cell,
                                                   self.spacing.min_dist_sq):
            return
        self.spacing = Spacing()
        self.spacing.radius, self.spacing.cell, self.spacing.min_dist_sq = values
        self.round_cmds = [None]
        self.find_cmd = Recorded(find_conflicts, (self.threads, 2 * radius + 1), self.device,
                                 cands=self.cands, spacing=self.spacing,
                                 conflicts=self.conflicts, undecided=self.undecided,
                                 stride=self.threads)

    def find(self):
        self.find_cmd.launch(conflicts=self.conflicts)

    def run_round(self, r: int):
        """Launch round ``r`` >= 1 (recorded on first use)."""
        while len(self.round_cmds) <= r:
            self.round_cmds.append(Recorded(
                select_candidates, self.threads, self.device, cands=self.cands,
                spacing=self.spacing, conflicts=self.conflicts,
                round_index=len(self.round_cmds), undecided=self.undecided,
                stride=self.threads))
        self.round_cmds[r].launch(conflicts=self.conflicts)


def harris_corners(src, max_corners: int, quality_level: float, min_distance: float,
                   block_size: int, k: float, *, ksize: int = 3, score: str = "harris",
                   out=None):
    """Strongest corners of a gray uint8 ``wp.array2d``: float32 [N, 2] (x, y) on its device.

    ``out``: a :class:`~warpvx._counted.Counted` of ``max_corners`` (> 0) float32 rows and
    an int32 [1] count on ``src.device`` (a graph's fixed buffers): the same points written
    there with their count (the first ``max_corners`` accepted, as without ``out``), with
    no host sync and no allocation once warm (:class:`.harris_counted.DeviceCorners`,
    cached per image size, parameters and buffers); returns ``out``.
    """
    refuse_uncounted(out, "harris_corners")
    device = src.device
    h, w = src.shape
    if out is not None:
        from .harris_counted import select_into  # built on this module's kernels

        return select_into(src, out, max_corners, quality_level, min_distance, block_size, k,
                           ksize, score)
    if h < 3 or w < 3:  # no pixel 1 px inside the image
        return wp.empty((0, 2), dtype=wp.float32, device=device)
    ws = workspace("harris_corners", (h, w), device, lambda: _CornersWorkspace(h, w, device))
    try:
        return _select(ws, src, max_corners, quality_level, min_distance, block_size, k,
                       ksize, score)
    except BaseException:
        # An interrupted call may leave ranks set in the map: start afresh next time.
        drop_workspace("harris_corners", (h, w), device)
        raise


def _select(ws, src, max_corners, quality_level, min_distance, block_size, k, ksize, score):
    device = src.device
    corner_response(src, block_size, ksize, k, score, ws.response)
    ws.row_max_cmd.launch()
    ws.finish_cmd.launch()
    ws.collect_cmd.launch(quality_level=float(quality_level))
    n = min(int(ws.count_back.read(ws.keys.count)[0]), ws.capacity)  # host sync: sizes the sort
    if n == 0:
        return wp.empty((0, 2), dtype=wp.float32, device=device)
    wp.utils.radix_sort_pairs(ws.keys.keys, ws.values, n, 0, 32 + ws.keys.raster_bits)
    ws.resize(n)
    suppress = min_distance >= 1
    # Initial state UNDECIDED, or ACCEPTED without suppression; the conflict counts zeroed.
    ws.rank_cmd.launch(initial_state=UNDECIDED if suppress else ACCEPTED,
                       conflicts=ws.conflicts)

    limit = n if max_corners <= 0 else min(int(max_corners), n)
    points = wp.empty((limit, 2), dtype=wp.float32, device=device)
    select = ws.select_cmd
    select.set(points=points, last_round=0)
    if suppress:
        ws.set_spacing(int(math.ceil(min_distance)), int(round(min_distance)),  # cvRound: half
                       float(min_distance) ** 2)                                # to even
        ws.find()
        first = 1
        while True:
            last = min(first + ws.batch, MAX_ROUNDS) - 1
            for r in range(first, last + 1):
                ws.run_round(r)
            select.launch(last_round=last)
            accepted, still, used = (int(v) for v in ws.result_back.read(ws.result))  # host sync
            if still == 0:
                ws.batch = min(max(used + 1, 2), 32)
                break
            if last == MAX_ROUNDS - 1:
                # Out of counters: start them again (every decision so far stays); round 1
                # must see a nonzero count before it.
                ws.undecided.zero_()
                ws.undecided[0:1].fill_(1)
            first = 1 if last == MAX_ROUNDS - 1 else last + 1
    else:
        select.launch()
        accepted = int(ws.result_back.read(ws.result)[0])  # host sync: the count
    ws.clear_cmd.launch()
    return points[:accepted]
