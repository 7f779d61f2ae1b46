"""FAST-9/16 corners on Warp: score map, 3x3 non-maximum suppression, compaction, sort.

Stable building blocks (the ORB extractor uses them too):

``fast_score(img, y, x, threshold) -> int``
    OpenCV's FAST-9/16 score (``cornerScore<16>`` in ``modules/features2d/src/fast_score.cpp``)
    of pixel (y, x) when it is a corner at ``threshold``, else 0. A pixel is a corner when 9
    contiguous pixels of the 16-pixel Bresenham circle of radius 3 are all darker than
    ``v - threshold`` or all brighter than ``v + threshold`` (strict). The score is the largest
    threshold at which it stays a corner, minus nothing: OpenCV's value, ``>= threshold`` for every
    corner (it can be 0 only when ``threshold == 0``). The caller guarantees
    ``3 <= y < H - 3`` and ``3 <= x < W - 3``.
``compute_fast_scores(img, threshold, border, scores)``
    Kernel over the whole image: ``scores[y, x] = fast_score(...)`` inside, 0 within
    ``max(border, 3)`` px of the edge (those pixels are skipped, as OpenCV skips 3 px).
``is_local_max_3x3(scores, y, x) -> bool``
    OpenCV's non-maximum rule (``FAST_t`` in ``fast.cpp``): the score is strictly greater than
    each of its 8 neighbours (neighbours outside the map count as 0). Ties suppress both
    pixels, and a score of 0 is never a maximum.
"""

from __future__ import annotations

import warp as wp

from ..keypoints import Keypoints

vec16i = wp.types.vector(length=16, dtype=wp.int32)

# The circle of FAST-9/16, in OpenCV's order (offsets16 in fast_score.cpp: (dx, dy) pairs).
CIRCLE_DX = wp.constant(vec16i(0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1))
CIRCLE_DY = wp.constant(vec16i(3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1, 0, 1, 2, 3))

# Keypoint size OpenCV's FAST gives (diameter of a radius-3 circle, rounded).
FAST_KEYPOINT_SIZE = 7.0


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
def fast_corner_score(img: wp.array2d(dtype=wp.uint8), y: int, x: int, threshold: int) -> int:
    """OpenCV's FAST-9/16 score when (y, x) is a corner at ``threshold``, else -1."""
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
def fast_score(img: wp.array2d(dtype=wp.uint8), y: int, x: int, threshold: int) -> int:
    """OpenCV's FAST-9/16 score of (y, x) if it is a corner at ``threshold``, else 0.

    The caller guarantees ``3 <= y < H - 3`` and ``3 <= x < W - 3``.
    """
    return wp.max(fast_corner_score(img, y, x, threshold), 0)


@wp.func
def score_at(scores: wp.array2d(dtype=wp.int32), y: int, x: int) -> int:
    """scores[y, x], 0 outside the map."""
    if y < 0 or x < 0 or y >= scores.shape[0] or x >= scores.shape[1]:
        return 0
    return scores[y, x]


@wp.func
def is_local_max_3x3(scores: wp.array2d(dtype=wp.int32), y: int, x: int) -> bool:
    """OpenCV's FAST non-maximum rule: strictly greater than all 8 neighbours (outside = 0)."""
    s = scores[y, x]
    if s <= 0:
        return False
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            if dy != 0 or dx != 0:
                if score_at(scores, y + dy, x + dx) >= s:
                    return False
    return True


@wp.func
def inside_fast_border(h: int, w: int, y: int, x: int, border: int) -> bool:
    b = wp.max(border, 3)
    return y >= b and x >= b and y < h - b and x < w - b


@wp.func
def sort_key(score: int, y: int, x: int, x_bits: int, y_bits: int) -> wp.int64:
    """Ascending order of the key = descending score, then y, then x (unique per pixel)."""
    return (
        (wp.int64(255 - score) << wp.int64(x_bits + y_bits))
        | (wp.int64(y) << wp.int64(x_bits))
        | wp.int64(x)
    )


@wp.kernel
def compute_fast_scores(
    img: wp.array2d(dtype=wp.uint8),
    threshold: int,
    border: int,
    scores: wp.array2d(dtype=wp.int32),
):
    y, x = wp.tid()
    s = int(0)
    if inside_fast_border(img.shape[0], img.shape[1], y, x, border):
        s = fast_score(img, y, x, threshold)
    scores[y, x] = s


@wp.kernel
def collect_local_maxima(
    scores: wp.array2d(dtype=wp.int32),
    x_bits: int,
    y_bits: int,
    count: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int64),
):
    y, x = wp.tid()
    if is_local_max_3x3(scores, y, x):
        slot = wp.atomic_add(count, 0, 1)
        # The capacity is a proven bound; the guard only keeps a bug from writing out of bounds.
        if slot < keys.shape[0] // 2:
            keys[slot] = sort_key(scores[y, x], y, x, x_bits, y_bits)


@wp.kernel
def collect_all_corners(
    img: wp.array2d(dtype=wp.uint8),
    threshold: int,
    x_bits: int,
    y_bits: int,
    count: wp.array(dtype=wp.int32),
    keys: wp.array(dtype=wp.int64),
):
    y, x = wp.tid()
    if inside_fast_border(img.shape[0], img.shape[1], y, x, 3):
        s = fast_corner_score(img, y, x, threshold)
        if s >= 0:
            slot = wp.atomic_add(count, 0, 1)
            if slot < keys.shape[0] // 2:
                keys[slot] = sort_key(s, y, x, x_bits, y_bits)


@wp.kernel
def decode_keypoints(
    keys: wp.array(dtype=wp.int64),
    x_bits: int,
    y_bits: int,
    kp_x: wp.array(dtype=wp.float32),
    kp_y: wp.array(dtype=wp.float32),
    kp_response: wp.array(dtype=wp.float32),
    kp_size: wp.array(dtype=wp.float32),
    kp_angle: wp.array(dtype=wp.float32),
    kp_octave: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    key = keys[i]
    x_mask = (wp.int64(1) << wp.int64(x_bits)) - wp.int64(1)
    y_mask = (wp.int64(1) << wp.int64(y_bits)) - wp.int64(1)
    kp_x[i] = float(int(key & x_mask))
    kp_y[i] = float(int((key >> wp.int64(x_bits)) & y_mask))
    kp_response[i] = float(255 - int(key >> wp.int64(x_bits + y_bits)))
    kp_size[i] = FAST_KEYPOINT_SIZE
    kp_angle[i] = -1.0
    kp_octave[i] = 0


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


def fast_corners(src, threshold: int, nonmax: bool, *, out=None) -> Keypoints:
    """FAST-9/16 keypoints of a gray uint8 ``wp.array2d``, sorted by (score desc, y, x).

    Everything runs on ``src.device``; the one host sync reads the corner count (the result's
    length). ``response`` is the OpenCV score also without NMS (cv2 leaves it 0 then).
    """
    device = src.device
    h, w = src.shape
    x_bits, y_bits = _bits(w), _bits(h)
    capacity = max_fast_corners(h, w, nonmax)
    if capacity == 0:
        return Keypoints.empty().to(str(device))
    count = wp.zeros(1, dtype=wp.int32, device=device)
    # radix_sort_pairs wants 2x storage (the upper half is its scratch).
    keys = wp.empty(2 * capacity, dtype=wp.int64, device=device)
    if nonmax:
        scores = wp.empty((h, w), dtype=wp.int32, device=device)
        wp.launch(compute_fast_scores, dim=(h, w), inputs=[src, int(threshold), 3, scores],
                  device=device)
        wp.launch(collect_local_maxima, dim=(h, w), inputs=[scores, x_bits, y_bits],
                  outputs=[count, keys], device=device)
    else:
        wp.launch(collect_all_corners, dim=(h, w), inputs=[src, int(threshold), x_bits, y_bits],
                  outputs=[count, keys], device=device)
    n = min(int(count.numpy()[0]), capacity)  # the host sync: the result's length
    return _sorted_keypoints(keys, n, x_bits, y_bits, device)


def _sorted_keypoints(keys, n: int, x_bits: int, y_bits: int, device) -> Keypoints:
    fields = {
        "x": wp.empty(n, dtype=wp.float32, device=device),
        "y": wp.empty(n, dtype=wp.float32, device=device),
        "response": wp.empty(n, dtype=wp.float32, device=device),
        "size": wp.empty(n, dtype=wp.float32, device=device),
        "angle": wp.empty(n, dtype=wp.float32, device=device),
        "octave": wp.empty(n, dtype=wp.int32, device=device),
    }
    if n == 0:
        return Keypoints(**fields)
    values = wp.empty(2 * n, dtype=wp.int32, device=device)
    # Keys are unique per pixel, so the order is the same run to run whatever the atomics did.
    wp.utils.radix_sort_pairs(keys, values, n, 0, x_bits + y_bits + 8)
    wp.launch(decode_keypoints, dim=n, inputs=[keys, x_bits, y_bits],
              outputs=[fields["x"], fields["y"], fields["response"], fields["size"],
                       fields["angle"], fields["octave"]], device=device)
    return Keypoints(**fields)


__all__ = ["fast_score", "compute_fast_scores", "is_local_max_3x3", "fast_corners",
           "max_fast_corners"]
