"""Matching for the ORB-SLAM2 front end (:mod:`warpvx.apps.orbslam`): frame to frame on the
device without a host sync, and stereo along the epipolar rows.

Frame to frame (``match`` node): each frame's descriptors are matched both ways to the previous
frame's (nearest row by Hamming distance, :func:`warpvx.knn_match_hamming`) and the mutual best
pairs are kept on the host by :func:`mutual_pairs` -- what ``match_hamming(cross_check=True)``
(cv2.BFMatcher's crossCheck) keeps, without its host sync for the match count. On the device the
rows are padded to a multiple of :data:`ROW_BUCKET` so the matcher's scratch buffers and recorded
launches are reused frame after frame (ORB's keypoint count changes every frame); padding rows
repeat real rows of lower index, so a pad never wins a tie (ties go to the lowest index) and the
kept pairs are exactly the unpadded ones. The batched front end (:mod:`warpvx.apps.orbslam_batch`)
matches all consecutive frames of a batch both ways in one launch instead (:func:`nearest_batch`).
"""

from __future__ import annotations

import numpy as np

#: Device descriptor sets are padded to a multiple of this many rows.
ROW_BUCKET = 256
# Set bits of each byte value: Hamming distances of descriptor bytes by table look-up.
_POPCOUNT = np.unpackbits(np.arange(256, dtype=np.uint8)[:, None], axis=1).sum(1).astype(np.int32)
_BITWISE_COUNT = getattr(np, "bitwise_count", None)


# --------------------------------------------------------------------------- frame to frame


def nearest_both_ways(desc, prev):
    """The ``match`` node on CPU workers: (``desc``, nearest, distance, back) for uint8 [N, 32]
    and [Np, 32] descriptor arrays; see :func:`nearest_both_ways_warp` for the outputs."""
    from .. import knn_match_hamming

    desc, prev = np.ascontiguousarray(desc), np.ascontiguousarray(prev)
    if len(desc) == 0 or len(prev) == 0:
        return desc, np.full(len(desc), -1, np.int32), np.zeros(len(desc), np.int32), \
            np.full(len(prev), -1, np.int32)
    idx, dist = knn_match_hamming(desc, prev, 1, backend="cpu")
    back, _ = knn_match_hamming(prev, desc, 1, backend="cpu")
    return desc, idx[:, 0], dist[:, 0], back[:, 0]


def _pad_rows(desc, rows: int):
    """``desc`` (wp.array uint8 [N, B], contiguous) in a new [rows, B] array whose rows past
    N repeat rows 0, 1, ... (device copies, doubling; zeros when N = 0)."""
    import warp as wp

    if not desc.is_contiguous:
        desc = desc.contiguous()
    n, width = desc.shape
    out = wp.empty((rows, width), dtype=wp.uint8, device=desc.device)
    if n == 0:
        out.zero_()
        return out
    flat = out.flatten()
    wp.copy(flat, desc.flatten(), 0, 0, n * width)
    done = n
    while done < rows:
        k = min(done, rows - done)
        wp.copy(flat, flat, done * width, 0, k * width)
        done += k
    return out


def nearest_both_ways_warp(desc, prev):
    """The ``match`` node on the device (wp.arrays in, on the node's stream; no host sync).

    Parameters
    ----------
    desc : wp.array uint8 [N, 32]
        This frame's descriptors.
    prev : wp.array uint8 [Cp, 32]
        The previous frame's padded descriptors (this node's first output a frame ago).

    Returns
    -------
    padded : uint8 [C, 32]
        ``desc`` padded to C = a multiple of :data:`ROW_BUCKET` (>= N).
    nearest, distance : int32 [C]
        Each row's nearest row of ``prev`` and its Hamming distance (-1 / 0 when ``prev`` is
        empty).
    back : int32 [Cp]
        Each row of ``prev``'s nearest row of ``padded``.
    """
    import warp as wp

    # The primitive's scratch state: both sets packed into words once, then the nearest rows
    # forward and (cross_check) backward (two knn_match_hamming calls packed each set twice).
    from ..kernels_warp.match_hamming import _workspace

    rows = max(ROW_BUCKET, -(-desc.shape[0] // ROW_BUCKET) * ROW_BUCKET)
    padded = _pad_rows(desc, rows)
    device = desc.device
    idx = wp.empty(rows, dtype=wp.int32, device=device)
    dist = wp.zeros(rows, dtype=wp.int32, device=device)
    back = wp.empty(prev.shape[0], dtype=wp.int32, device=device)
    if prev.shape[0] == 0:
        idx.fill_(-1)
        return padded, idx, dist, back
    ws = _workspace(padded, prev)
    forward = ws.nearest(padded, prev, cross_check=True)
    # The workspace's buffers are reused by the next call of these sizes: copy the results out.
    wp.copy(idx, forward.best_idx)
    wp.copy(dist, forward.best_dist)
    wp.copy(back, ws.backward.out.best_idx)
    return padded, idx, dist, back


def nearest_batch(descs, prev):
    """The ``match`` node over a batch of consecutive frames: each frame's nearest rows in the
    frame before and after it, for ``descs`` a list of B uint8 [N_i, 32] descriptor arrays
    after ``prev`` (the frame before the batch, uint8 [N_0, 32]). CPU: NumPy arrays in and
    out; :func:`nearest_batch_warp` on the device.

    Returns
    -------
    last : uint8 [N_B, 32]
        The batch's last descriptors (the next batch's ``prev``).
    (nearest, distance, starts) : int32 [2, T], int32 [2, T], int32 [B + 2]
        Frames 0 (``prev``) to B one after the other, frame f on rows ``starts[f]:starts[f + 1]``
        (T = ``starts[-1]``); row 0 of ``nearest``/``distance``: each row's nearest row (local
        index) of the frame before and its Hamming distance, row 1: of the frame after (-1 /
        0 where there is none). :func:`batch_pairs` slices them per frame.
    """
    frames = [np.ascontiguousarray(prev)] + [np.ascontiguousarray(d) for d in descs]
    starts = np.cumsum([0] + [len(d) for d in frames]).astype(np.int32)
    nearest = np.full((2, starts[-1]), -1, np.int32)
    distance = np.zeros((2, starts[-1]), np.int32)
    for f in range(1, len(frames)):
        _, idx, dist, back = nearest_both_ways(frames[f], frames[f - 1])
        nearest[0, starts[f]:starts[f + 1]], distance[0, starts[f]:starts[f + 1]] = idx, dist
        nearest[1, starts[f - 1]:starts[f]] = back
    return frames[-1], (nearest, distance, starts)


def nearest_batch_warp(descs, prev):
    """:func:`nearest_batch` on the device (wp.arrays; no host sync): the frames' descriptors
    gathered into one array (one copy for the batch when they are consecutive rows of one
    buffer, as ``warpvx.orb`` returns a batch's), then one launch
    (:func:`warpvx.kernels_warp.match_chain.nearest_chain`) for all pairs both ways."""
    import warp as wp

    from ..kernels_warp._launch import view
    from ..kernels_warp.match_chain import nearest_chain

    device = prev.device
    counts = [prev.shape[0]] + [d.shape[0] for d in descs]
    starts = np.cumsum([0] + counts).astype(np.int32)
    rows = int(starts[-1])
    gathered = wp.empty((rows, 32), dtype=wp.uint8, device=device)
    pieces = [(prev, counts[0])]
    nonempty = [d for d in descs if d.shape[0]]
    if nonempty and all(b.ptr == a.ptr + a.shape[0] * 32 for a, b in zip(nonempty, nonempty[1:])):
        # One buffer, frame after frame: one copy of all its rows.
        pieces.append((view(nonempty[0], wp.uint8, (rows - counts[0], 32), (32, 1)), rows - counts[0]))
    else:
        pieces += [(d, d.shape[0]) for d in descs]
    at = 0
    for src, n in pieces:
        if n:
            wp.copy(gathered.flatten(), src.contiguous().flatten(), at * 32, 0, n * 32)
        at += n
    starts = wp.array(starts, dtype=wp.int32, device=device)
    return descs[-1], (*nearest_chain(gathered, starts), starts)


def batch_pairs(nearest, distance, starts, f: int) -> tuple:
    """(nearest, distance, back) of frame ``f`` (>= 1) of :func:`nearest_batch`'s outputs
    (host arrays): its rows' nearest rows in frame f - 1 and frame f - 1's rows' nearest in
    it, the inputs of :func:`mutual_pairs`."""
    a, b, c = int(starts[f - 1]), int(starts[f]), int(starts[f + 1])
    return nearest[0, b:c], distance[0, b:c], nearest[1, a:b]


def add_match_node(g, desc, *, target=None):
    """Add the ``match`` node to graph ``g`` for the descriptors ``desc`` (a data object of
    uint8 [N, 32]): it matches them to the previous frame's both ways (the padded
    descriptors go through a delay). Returns the data objects (nearest, distance, back) that
    :func:`mutual_pairs` turns into pairs; ``target`` pins the node (``"gpu"``)."""
    padded = g.virtual("desc_padded")
    # Before the first frame: zero rows (never paired: the tracker has no previous frame).
    previous = g.delay(padded, init=np.zeros((ROW_BUCKET, 32), np.uint8))[-1]
    _, *nearest = g.user(nearest_both_ways, [desc, previous], [padded, "nearest", "distance", "back"],
                         warp_fn=nearest_both_ways_warp, name="match", target=target)
    return nearest


def mutual_pairs(nearest, distance, back, n: int, n_prev: int) -> tuple:
    """The mutual best pairs of the ``match`` node's outputs (host arrays, see
    :func:`nearest_both_ways_warp`) for ``n`` real rows of this frame and ``n_prev`` of the
    previous one: (int32 [M, 2] (this, previous) pairs by increasing index, int32 [M]
    distances), as ``match_hamming(desc, prev_desc, cross_check=True)`` returns them."""
    if n == 0 or n_prev == 0:
        return np.zeros((0, 2), np.int32), np.zeros(0, np.int32)
    q = np.arange(n)
    t = np.asarray(nearest).reshape(-1)[:n]
    keep = (t >= 0) & (t < n_prev)
    keep[keep] = np.asarray(back).reshape(-1)[t[keep]] == q[keep]
    pairs = np.stack([q[keep], t[keep]], 1).astype(np.int32)
    return pairs, np.asarray(distance).reshape(-1)[:n][keep].astype(np.int32)


# --------------------------------------------------------------------------- stereo


def hamming_pairs(desc_a, desc_b) -> np.ndarray:
    """int [M]: Hamming distances of row pairs of two uint8 [M, 32] descriptor arrays."""
    x = np.ascontiguousarray(desc_a) ^ np.ascontiguousarray(desc_b)
    if _BITWISE_COUNT is not None:  # NumPy >= 2: popcount of 64-bit words
        return _BITWISE_COUNT(x.view(np.uint64)).sum(1, dtype=np.int32)
    return _POPCOUNT[x].sum(1)


def _candidates(yl, ol, yr, orr, band):
    """(left, right) index pairs whose octaves differ by at most one and whose rows are within
    ``band[right octave]`` (+ a margin; the caller applies the exact test): a row-band join
    per right octave, right keypoints sorted by row, no N x M table."""
    lis, ris = [], []
    for octave in np.unique(orr):
        right = np.flatnonzero(orr == octave)
        right = right[np.argsort(yr[right], kind="stable")]
        left = np.flatnonzero(np.abs(ol - octave) <= 1)
        reach = band[octave] + 1e-3
        lo = np.searchsorted(yr[right], yl[left] - reach)
        counts = np.searchsorted(yr[right], yl[left] + reach, side="right") - lo
        lis.append(np.repeat(left, counts))
        ris.append(right[np.arange(counts.sum()) + np.repeat(lo - (np.cumsum(counts) - counts), counts)])
    return np.concatenate(lis), np.concatenate(ris)


def _sad_refine(left, right, xl, yl, ur, w=5, L=5):
    """ORB-SLAM2's sub-pixel refinement of stereo matches on the level-0 images (uint8 HxW):
    the SAD of the (2w+1)^2 left patch (centre value subtracted) against the right one shifted
    over -L..L px around column ``round(ur)``, a parabola through the best three.

    Returns (``inside`` bool [M]: patches within the edge-padded images; then for those:
    refined right column float64, ``ok`` bool (interior minimum, vertex within 1 px), best SAD).
    """
    pad = w + L + 1
    lp = np.pad(left, pad, mode="edge")
    rp = np.pad(right, pad, mode="edge")
    cx = np.rint(xl).astype(np.int64) + pad
    cy = np.rint(yl).astype(np.int64) + pad
    cr = np.rint(ur).astype(np.int64) + pad
    h, wd = rp.shape
    inside = (cr - w - L >= 0) & (cr + w + L < wd) & (cy - w >= 0) & (cy + w < h)
    cx, cy, cr, ur = cx[inside], cy[inside], cr[inside], ur[inside]
    off = np.arange(-w, w + 1)
    rows = (cy[:, None] + off)[:, :, None]
    pl = lp[rows, (cx[:, None] + off)[:, None, :]].astype(np.int16)
    pl -= pl[:, w:w + 1, w:w + 1]  # ORB-SLAM2 subtracts the centre value (illumination)
    # One strip of 2(w+L)+1 right columns per match; the 2L+1 shifted patches are views of it.
    strip = rp[rows, (cr[:, None] + np.arange(-w - L, w + L + 1))[:, None, :]].astype(np.int16)
    # SAD per shift k: |pl - (strip window k - its centre)|, one (M, rows, cols) pass each.
    centre = strip[:, w, w:w + 2 * L + 1]
    sad = np.empty((len(cx), 2 * L + 1))
    for k in range(2 * L + 1):
        diff = pl + centre[:, k, None, None] - strip[:, :, k:k + 2 * w + 1]
        sad[:, k] = np.abs(diff).sum(axis=(1, 2), dtype=np.int32)
    k = np.argmin(sad, axis=1)
    i = np.arange(len(k))
    kc = np.clip(k, 1, 2 * L - 1)
    d1, d2, d3 = sad[i, kc - 1], sad[i, kc], sad[i, kc + 1]
    denom = 2.0 * (d1 + d3 - 2.0 * d2)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(denom != 0, (d1 - d3) / denom, 0.0)
    ok = (k > 0) & (k < 2 * L) & (np.abs(delta) <= 1.0)
    return inside, np.rint(ur) + (k - L) + delta, ok, sad[i, k]


def stereo_depth(kps_left, desc_left, kps_right, desc_right, left, right, *, fx, baseline,
                 scale_factor=1.2, max_distance=75) -> np.ndarray:
    """Depth (m) of each left keypoint from ORB matches along the epipolar rows, float32 [N]
    (NaN where unmatched), after ORB-SLAM2's ``Frame::ComputeStereoMatches``:

    a right keypoint is a candidate when its row is within 2 s of the left one (s = the right
    keypoint's octave scale ``scale_factor`` ** octave), its octave within one of the left
    one's, and its disparity in [0, fx]; the best Hamming distance wins if under
    ``max_distance`` (ORB-SLAM2: (TH_HIGH + TH_LOW) / 2 = 75); the column is
    refined by the SAD of 11x11 patches over +-5 px and a parabola through the three best
    (dropped when the vertex moves more than 1 px); depth = fx baseline / disparity; matches
    whose SAD exceeds 1.5 x 1.4 x the median are dropped. Patches are taken on the level-0
    images (ORB-SLAM2 uses the keypoint's pyramid level).
    """
    n = len(kps_left)
    depth = np.full(n, np.nan, np.float32)
    if n == 0 or len(kps_right) == 0:
        return depth
    xl, yl, ol = (np.asarray(a) for a in (kps_left.x, kps_left.y, kps_left.octave))
    xr, yr, orr = (np.asarray(a) for a in (kps_right.x, kps_right.y, kps_right.octave))
    band = 2.0 * scale_factor ** np.arange(max(int(orr.max()), 0) + 1)
    li, ri = _candidates(yl, ol, yr, orr, band)
    disp = xl[li] - xr[ri]
    ok = (np.abs(yl[li] - yr[ri]) <= band[orr[ri]]) & (disp >= 0) & (disp <= fx)
    li, ri = li[ok], ri[ok]
    dist = hamming_pairs(np.asarray(desc_left)[li], np.asarray(desc_right)[ri])
    # Best per left keypoint: the smallest distance, then the lowest right index (one key).
    width = len(xr) + 1
    best = np.full(n, np.iinfo(np.int64).max)
    np.minimum.at(best, li, dist.astype(np.int64) * width + ri)
    good = np.flatnonzero(best < max_distance * width)
    best_r = best[good] % width
    if len(good) == 0:
        return depth
    inside, ur_refined, keep, best_sad = _sad_refine(left, right, xl[good], yl[good],
                                                     xr[best_r].astype(np.float64))
    good = good[inside]
    disparity = xl[good] - ur_refined
    keep &= disparity > 0
    if keep.any():
        keep &= best_sad <= 1.5 * 1.4 * np.median(best_sad[keep])
    depth[good[keep]] = (fx * baseline / disparity[keep]).astype(np.float32)
    return depth


__all__ = ["ROW_BUCKET", "add_match_node", "nearest_both_ways", "nearest_both_ways_warp", "nearest_batch",
           "nearest_batch_warp", "batch_pairs", "mutual_pairs",
           "hamming_pairs", "stereo_depth"]
