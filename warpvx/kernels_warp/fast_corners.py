"""FAST-9/16 corners on Warp: score map, 3x3 non-maximum suppression, compaction, sort.

Per call (NMS): ``score_fast_map`` (uint8 score map; also resets the corner counter),
``collect_maxima`` (strict 3x3 maxima compacted with an atomic counter as sort keys, a
:class:`CornerKeys`), one host sync for the count, ``rank_keys`` (up to :data:`RANK_MAX` keys:
each key's sorted position by counting the smaller ones; more keys take a radix sort) and
``decode_keypoints``. Scratch buffers and recorded launches are reused between calls of one
image size on one device, stream and thread (:func:`workspace`).

``fast_score(img, y, x, threshold) -> int`` is the stable building block the ORB extractor
uses too: OpenCV's FAST-9/16 score (``cornerScore<16>`` in
``modules/features2d/src/fast_score.cpp``) of pixel (y, x) when it is a corner at
``threshold``, else 0. A pixel is a corner when 9 contiguous pixels of the 16-pixel Bresenham
circle of radius 3 are all darker than ``v - threshold`` or all brighter than
``v + threshold`` (strict). The score is the largest threshold at which it stays a corner:
OpenCV's value, ``>= threshold`` for every corner (it can be 0 only when ``threshold == 0``).
The caller guarantees ``3 <= y < H - 3`` and ``3 <= x < W - 3``.

The non-maximum rule is OpenCV's (``FAST_t`` in ``fast.cpp``): a score strictly greater than
each of its 8 neighbours; ties suppress both pixels, and a score of 0 is never a maximum.
"""

from __future__ import annotations


import warp as wp

from .._counted import refuse_uncounted
from ..keypoints import Keypoints
from ._device_sort import CountedSort
from ._launch import HostReadback, Recorded, workspace

# Forward-only kernels: no adjoint code to generate and compile.
wp.set_module_options({"enable_backward": False})

vec16i = wp.types.vector(length=16, dtype=wp.int32)

# The circle of FAST-9/16, in OpenCV's order (offsets16 in fast_score.cpp: (dx, dy) pairs).
CIRCLE_DX = wp.constant(vec16i(0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1))
CIRCLE_DY = wp.constant(vec16i(3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1, 0, 1, 2, 3))

# Keypoint size OpenCV's FAST gives (diameter of a radius-3 circle, rounded).
FAST_KEYPOINT_SIZE = 7.0

RANK_CHUNK = wp.constant(64)
RANK_MAX = 8192
"""With NMS, up to this many corners are sorted by counting (``rank_keys``, n^2 / 64
threads); more go through a radix sort."""
RANK_MAX_CPU = 0  # Warp's CPU device runs one thread at a time: always the radix sort



@wp.func
def has_nine_contiguous(mask: int) -> bool:
    """True when the 16-bit cyclic ``mask`` holds 9 set bits in a row."""
    m = mask | (mask << 16)
    run = m
    for i in range(1, 9):
        run = run & (m >> i)
    return (run & 0xFFFF) != 0


@wp.func
def circle_diffs(img: wp.array2d(dtype=wp.uint8), y: int, x: int) -> vec16i:
    """d[k] = centre - circle pixel k (OpenCV's d[] in cornerScore)."""
    v = int(img[y, x])
    d = vec16i()
    for k in range(16):
        d[k] = v - int(img[y + CIRCLE_DY[k], x + CIRCLE_DX[k]])
    return d


@wp.func
def corner_score_full(img: wp.array2d(dtype=wp.uint8), y: int, x: int, threshold: int) -> int:
    """:func:`fast_corner_score` without the quick rejection."""
    d = circle_diffs(img, y, x)
    dark = int(0)
    bright = int(0)
    for k in range(16):
        if d[k] > threshold:
            dark = dark | (1 << k)
        if d[k] < -threshold:
            bright = bright | (1 << k)
    if not has_nine_contiguous(dark) and not has_nine_contiguous(bright):
        return -1
    # cornerScore<16>: a0 tracks the best dark arc minimum, b0 the best bright arc maximum.
    a0 = threshold
    for k in range(0, 16, 2):
        a = wp.min(wp.min(d[(k + 1) & 15], d[(k + 2) & 15]), d[(k + 3) & 15])
        if a > a0:
            for j in range(4, 9):
                a = wp.min(a, d[(k + j) & 15])
            a0 = wp.max(a0, wp.min(a, d[k]))
            a0 = wp.max(a0, wp.min(a, d[(k + 9) & 15]))
    b0 = -a0
    for k in range(0, 16, 2):
        b = d[(k + 1) & 15]
        for j in range(2, 6):
            b = wp.max(b, d[(k + j) & 15])
        if b < b0:
            for j in range(6, 9):
                b = wp.max(b, d[(k + j) & 15])
            b0 = wp.min(b0, wp.max(b, d[k]))
            b0 = wp.min(b0, wp.max(b, d[(k + 9) & 15]))
    return -b0 - 1


@wp.func
def fast_corner_score(img: wp.array2d(dtype=wp.uint8), y: int, x: int, threshold: int) -> int:
    """OpenCV's FAST-9/16 score when (y, x) is a corner at ``threshold``, else -1."""
    # Any 9 contiguous circle pixels include pixel k or k + 8 for every k (OpenCV's first
    # tests, on pairs (0, 8), (4, 12), then (2, 10), (6, 14)): most pixels are rejected
    # after 5 reads, nearly all after 9.
    v = int(img[y, x])
    lo = v - threshold
    hi = v + threshold
    p0 = int(img[y + 3, x])
    p4 = int(img[y, x + 3])
    p8 = int(img[y - 3, x])
    p12 = int(img[y, x - 3])
    dark = (p0 < lo or p8 < lo) and (p4 < lo or p12 < lo)
    bright = (p0 > hi or p8 > hi) and (p4 > hi or p12 > hi)
    if not dark and not bright:
        return -1
    p2 = int(img[y + 2, x + 2])
    p6 = int(img[y - 2, x + 2])
    p10 = int(img[y - 2, x - 2])
    p14 = int(img[y + 2, x - 2])
    dark = dark and (p2 < lo or p10 < lo) and (p6 < lo or p14 < lo)
    bright = bright and (p2 > hi or p10 > hi) and (p6 > hi or p14 > hi)
    if not dark and not bright:
        return -1
    return corner_score_full(img, y, x, threshold)


@wp.func
def fast_score(img: wp.array2d(dtype=wp.uint8), y: int, x: int, threshold: int) -> int:
    """OpenCV's FAST-9/16 score of (y, x) if it is a corner at ``threshold``, else 0.

    The caller guarantees ``3 <= y < H - 3`` and ``3 <= x < W - 3``.
    """
    return wp.max(fast_corner_score(img, y, x, threshold), 0)


@wp.func
def inside_fast_border(h: int, w: int, y: int, x: int) -> bool:
    """Whether (y, x) lies 3 px inside an h x w image (the circle fits)."""
    return y >= 3 and x >= 3 and y < h - 3 and x < w - 3


@wp.struct
class CornerKeys:
    """Corners compacted as unique sort keys: ``keys[:count[0]]`` (the upper half of ``keys``
    is the radix sort's scratch). A key is ``(255 - score) << (x_bits + y_bits) | y << x_bits
    | x``, so ascending keys are descending scores, then y, then x."""

    keys: wp.array(dtype=wp.int64)
    count: wp.array(dtype=wp.int32)
    x_bits: int
    y_bits: int


@wp.func
def corner_count(corners: CornerKeys) -> int:
    """The number of keys stored (the counter, capped at the capacity)."""
    return wp.min(corners.count[0], corners.keys.shape[0] // 2)


@wp.func
def push_corner(corners: CornerKeys, score: int, y: int, x: int):
    """Append the key of a corner (an atomic slot)."""
    slot = wp.atomic_add(corners.count, 0, 1)
    # The capacity is a proven bound; the guard only keeps a bug from writing out of bounds.
    if slot < corners.keys.shape[0] // 2:
        corners.keys[slot] = (
            (wp.int64(255 - score) << wp.int64(corners.x_bits + corners.y_bits))
            | (wp.int64(y) << wp.int64(corners.x_bits))
            | wp.int64(x)
        )


@wp.kernel
def score_fast_map(
    img: wp.array2d(dtype=wp.uint8),
    threshold: int,
    scores: wp.array2d(dtype=wp.uint8),
    corners: CornerKeys,
    rank: wp.array(dtype=wp.int32),
):
    """``scores[y, x] = fast_score`` (at most 254, so uint8) 3 px inside, else 0.

    It also resets the corner counter (thread (0, 0)) and ``rank`` (one entry per thread) for
    the kernels after it on the same stream (saves memset launches).
    """
    y, x = wp.tid()
    if y == 0 and x == 0:
        corners.count[0] = 0
    idx = y * img.shape[1] + x
    if idx < rank.shape[0]:
        rank[idx] = 0
    s = int(0)
    if inside_fast_border(img.shape[0], img.shape[1], y, x):
        s = fast_score(img, y, x, threshold)
    scores[y, x] = wp.uint8(s)


@wp.kernel
def collect_maxima(scores: wp.array2d(dtype=wp.uint8), corners: CornerKeys):
    """Strict 3x3 maxima of the uint8 map as sort keys (OpenCV's non-maximum rule)."""
    y, x = wp.tid()
    s = scores[y, x]
    if s == wp.uint8(0):
        return
    # A nonzero score lies 3 px inside the map, so all 8 neighbours exist.
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if dy != 0 or dx != 0:
                if scores[y + dy, x + dx] >= s:
                    return
    push_corner(corners, int(s), y, x)


@wp.kernel
def collect_all_corners(img: wp.array2d(dtype=wp.uint8), threshold: int, corners: CornerKeys):
    """Every corner 3 px inside as a sort key (no suppression)."""
    y, x = wp.tid()
    if inside_fast_border(img.shape[0], img.shape[1], y, x):
        s = fast_corner_score(img, y, x, threshold)
        if s >= 0:
            push_corner(corners, s, y, x)


@wp.kernel
def rank_keys(corners: CornerKeys, rank: wp.array(dtype=wp.int32)):
    """``rank[i] += `` how many keys of chunk ``c`` are smaller than key ``i``. Threads
    (c, i): a warp's threads read the same key at a time (one broadcast load)."""
    c, i = wp.tid()
    n = corner_count(corners)
    j0 = c * RANK_CHUNK
    if i >= n or j0 >= n:
        return
    key = corners.keys[i]
    r = int(0)
    for j in range(j0, wp.min(j0 + RANK_CHUNK, n)):
        r += wp.where(corners.keys[j] < key, 1, 0)
    if r > 0:
        wp.atomic_add(rank, i, r)


@wp.kernel
def decode_keypoints(
    corners: CornerKeys,
    ranked: int,
    rank: wp.array(dtype=wp.int32),
    fields: wp.array2d(dtype=wp.float32),
    octave: wp.array(dtype=wp.int32),
):
    """Keypoint ``r`` from key ``i``: ``r = i`` when the keys are sorted (``ranked`` 0), else
    ``rank[i]``, the number of smaller keys (keys are unique). ``fields`` rows: x, y,
    response, size, angle."""
    i = wp.tid()
    if i >= corner_count(corners):
        return
    key = corners.keys[i]
    r = i
    if ranked != 0:
        r = rank[i]
    x_bits = wp.int64(corners.x_bits)
    y_bits = wp.int64(corners.y_bits)
    fields[0, r] = float(int(key & ((wp.int64(1) << x_bits) - wp.int64(1))))
    fields[1, r] = float(int((key >> x_bits) & ((wp.int64(1) << y_bits) - wp.int64(1))))
    fields[2, r] = float(255 - int(key >> (x_bits + y_bits)))
    fields[3, r] = FAST_KEYPOINT_SIZE
    fields[4, r] = -1.0
    octave[r] = 0


@wp.kernel
def fill_sentinels(corners: CornerKeys, capacity: int):
    """Keys past the corner count sort after every corner (all key bits set)."""
    i = wp.tid()
    if i >= corners.count[0] and i < capacity:
        bits = corners.x_bits + corners.y_bits + 8
        corners.keys[i] = (wp.int64(1) << wp.int64(bits)) - wp.int64(1)


@wp.kernel
def write_count(corners: CornerKeys, count: wp.array(dtype=wp.int32)):
    """count[0] = the number of corners, clamped to the capacity."""
    count[0] = corner_count(corners)


def _bits(n: int) -> int:
    """Bits needed for coordinates 0..n-1."""
    return max(1, int(n - 1).bit_length())


def max_fast_corners(height: int, width: int, nonmax: bool) -> int:
    """A bound on the corner count: the interior without NMS; strict 3x3 maxima cannot touch,
    so at most one per 2x2 block with NMS."""
    inner_h, inner_w = max(height - 6, 0), max(width - 6, 0)
    if nonmax:
        return ((inner_h + 1) // 2) * ((inner_w + 1) // 2)
    return inner_h * inner_w


def counted_capacity(src, nonmax: bool, **_) -> int:
    """Rows of a graph node's Counted keypoints: :func:`max_fast_corners` of its image
    (:attr:`warpvx.registry.Primitive.counted_rows`)."""
    return max_fast_corners(int(src.shape[0]), int(src.shape[1]), bool(nonmax))


# --- FAST -------------------------------------------------------------------------------------


class _FastWorkspace:
    """Scratch of one image size: score map, corner keys, rank, and the recorded launches."""

    def __init__(self, src, nonmax: bool, capacity: int):
        device = src.device
        h, w = src.shape
        self.corners = CornerKeys()
        # radix_sort_pairs wants 2x storage (the upper half is its scratch).
        self.corners.keys = wp.empty(2 * capacity, dtype=wp.int64, device=device)
        self.corners.count = wp.zeros(1, dtype=wp.int32, device=device)
        self.corners.x_bits, self.corners.y_bits = _bits(w), _bits(h)
        self.values = wp.empty(2 * capacity, dtype=wp.int32, device=device)
        self.readback = HostReadback(1, wp.int32, device)
        # rank[i]: the sorted position of keys[i] when counted (zeroed by score_fast_map).
        self.rank = wp.zeros(capacity if nonmax else 1, dtype=wp.int32, device=device)
        if nonmax:
            self.scores = wp.empty((h, w), dtype=wp.uint8, device=device)
            self.score = Recorded(score_fast_map, (h, w), device, img=src, threshold=0,
                                  scores=self.scores, corners=self.corners, rank=self.rank)
            self.collect = Recorded(collect_maxima, (h, w), device, scores=self.scores,
                                    corners=self.corners)
        else:
            self.collect = Recorded(collect_all_corners, (h, w), device, img=src, threshold=0,
                                    corners=self.corners)
        self.rank_cmd = None  # recorded on first use, sized by the corner count
        self.decode = None


class _IntoPlan:
    """The launches writing every corner of one workspace into a Counted's Keypoints: keys
    padded with sentinels and sorted (:class:`._device_sort.CountedSort`), decoded into
    ``fields`` (then copied into the Keypoints' arrays), the count."""

    def __init__(self, ws, out, capacity: int):
        device = out.count.device
        self.fields = wp.zeros((5, capacity), dtype=wp.float32, device=device)
        self.sentinels = Recorded(fill_sentinels, capacity, device, corners=ws.corners,
                                  capacity=capacity)
        c = ws.corners
        self.sort = CountedSort(c.keys, ws.values, c.count, capacity, c.x_bits + c.y_bits + 8)
        self.decode = Recorded(decode_keypoints, capacity, device, corners=ws.corners, ranked=0,
                               rank=ws.rank, fields=self.fields, octave=out.rows.octave)
        self.count = Recorded(write_count, 1, device, corners=ws.corners, count=out.count)


def fast_corners(src, threshold: int, nonmax: bool, *, out=None) -> Keypoints:
    """FAST-9/16 keypoints of a gray uint8 ``wp.array2d``, sorted by (score desc, y, x).

    Everything runs on ``src.device``; the one host sync reads the corner count (the result's
    length). ``response`` is the OpenCV score also without NMS (cv2 leaves it 0 then).

    ``out``: a :class:`~warpvx._counted.Counted` of Keypoints with
    :func:`max_fast_corners` rows (a graph's fixed buffers): the same keypoints written there
    with their count, with no host sync (sentinel keys after the corners, sorted without
    reading the count: :class:`._device_sort.CountedSort`); returns ``out``.
    """
    refuse_uncounted(out, "fast_corners")
    device = src.device
    h, w = src.shape
    capacity = max_fast_corners(h, w, nonmax)
    if capacity == 0:
        if out is not None:
            out.count.zero_()
            return out
        return Keypoints.empty().to(str(device))
    ws = workspace("fast", (h, w, bool(nonmax)), device,
                   lambda: _FastWorkspace(src, nonmax, capacity))
    # Made before the corners are collected: making it sorts the keys (CountedSort).
    plan = None if out is None else _into_plan(ws, out, capacity)
    if nonmax:
        ws.score.launch(img=src, threshold=int(threshold))
        ws.collect.launch()
    else:
        ws.corners.count.zero_()
        ws.collect.launch(img=src, threshold=int(threshold))
    if plan is not None:
        return _keypoints_into(plan, out)
    n = min(int(ws.readback.read(ws.corners.count)[0]), capacity)  # the host sync: the length
    return _sorted_keypoints(ws, n, device, nonmax)


def _into_plan(ws, out, capacity: int) -> _IntoPlan:
    # Keyed by the workspace's buffers too: the plan sorts them.
    return workspace("fast_into", (capacity, ws.corners.keys.ptr, out.count.ptr) + tuple(
        a.ptr for a in out.rows.__warpvx_flatten__()[0]), out.count.device,
        lambda: _IntoPlan(ws, out, capacity))


def _keypoints_into(plan: _IntoPlan, out):
    kps = out.rows
    plan.sentinels.launch()
    plan.sort.launch()
    plan.decode.launch()
    for i, field in enumerate((kps.x, kps.y, kps.response, kps.size, kps.angle)):
        wp.copy(field, plan.fields[i])
    plan.count.launch()
    return out


def _sorted_keypoints(ws, n: int, device, nonmax: bool) -> Keypoints:
    if n == 0:
        return Keypoints(*[wp.empty(0, dtype=wp.float32, device=device) for _ in range(5)],
                         wp.empty(0, dtype=wp.int32, device=device))
    # One allocation for the float fields (rows viewed as arrays), one for the octaves.
    fields = wp.empty((5, n), dtype=wp.float32, device=device)
    octave = wp.empty(n, dtype=wp.int32, device=device)
    kps = Keypoints(fields[0], fields[1], fields[2], fields[3], fields[4], octave)
    # Keys are unique per pixel, so the order is the same run to run whatever the atomics did.
    size = max(256, 1 << (n - 1).bit_length())  # launch size: rarely changes between calls
    ranked = nonmax and n <= (RANK_MAX_CPU if device.is_cpu else RANK_MAX)
    if ranked:
        dim = (-(-size // RANK_CHUNK), size)
        if ws.rank_cmd is None:
            ws.rank_cmd = Recorded(rank_keys, dim, device, corners=ws.corners, rank=ws.rank)
            ws.rank_size = size
        elif size != ws.rank_size:
            ws.rank_cmd.set_dim(dim)
            ws.rank_size = size
        ws.rank_cmd.launch()
    else:
        c = ws.corners
        wp.utils.radix_sort_pairs(c.keys, ws.values, n, 0, c.x_bits + c.y_bits + 8)
    if ws.decode is None:
        ws.decode = Recorded(decode_keypoints, size, device, corners=ws.corners,
                             ranked=int(ranked), rank=ws.rank, fields=fields, octave=octave)
        ws.decode_size = size
    elif size != ws.decode_size:
        ws.decode.set_dim(size)
        ws.decode_size = size
    ws.decode.launch(ranked=int(ranked), fields=fields, octave=octave)
    return kps


__all__ = ["counted_capacity", "fast_score", "fast_corners", "max_fast_corners"]
