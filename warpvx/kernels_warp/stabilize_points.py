"""The stabilizer's point set on the device: refresh, detection and RANSAC with no host sync.

The point set lives in a fixed buffer of ``P = max(max_corners, 4)`` float32 (x, y) rows with
its count in a device int32; rows past the count are NaN, which LK reports lost (status 0),
RANSAC never samples (:class:`DeviceRansac` draws from the first ``count`` rows) and never
counts as inliers (a NaN error fails ``<= threshold``): padding rows are never fed to RANSAC
as duplicates. The steps mirror :func:`warpvx.apps.stabilize.refresh_points`:

1. :func:`keep_tracked` (one block): the points LK tracked, in order, to the front of the
   buffer; ``detect[0] = tracked < min_tracked`` (the device decides re-detection);
2. only when ``detect[0]`` (a conditional CUDA-graph node, ``wp.capture_if``):
   :class:`DeviceCorners` (``harris_corners`` with a fixed-size sort and every selection round
   launched, so no host sync) then :func:`merge_fresh` (fresh corners at least
   ``min_distance`` from every tracked point, appended up to ``max_corners``, padded to 4 with
   the host's off-image points);
3. :func:`pad_points`: NaN after the count.

:class:`DeviceCorners` reuses the kernels of :mod:`.harris_corners` and gives its points
exactly (tests/apps/test_stabilize_device.py): the candidates are sorted over the whole
capacity with sentinel keys after the count; the selection rounds run in batches of
:data:`ROUND_BATCH`, each batch in a conditional node on the previous batch's last
"undecided" counter (nested ``wp.capture_if``), up to :data:`~.harris_corners.MAX_ROUNDS`,
looping on the device (``wp.capture_while``) in the rare case they did not decide every
candidate (the counters start again, as ``harris_corners`` does).
"""

from __future__ import annotations

import math

import warp as wp

from . import find_homography as fh
from . import harris_corners as hc
from ._launch import Recorded
from .harris_response import corner_response

# No FMA contraction: merge_fresh squares distances as NumPy does, and sample_first inlines
# find_homography's draw_hypothesis, which must round as it does there.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

BLOCK = 256  # lanes of the one-block compaction kernels
# Selection rounds launched per conditional batch: real frames need a few to a dozen rounds;
# launching all MAX_ROUNDS (each a launch over every pixel's candidate slot) would cost more.
ROUND_BATCH = 8
OFF_IMAGE = wp.constant(wp.float32(-1.0e4))  # refresh_points' padding (x and y, px)


@wp.func
def usable(pts: wp.array2d(dtype=wp.float32), i: int) -> bool:
    return wp.isfinite(pts[i, 0]) and wp.isfinite(pts[i, 1])


@wp.kernel
def keep_tracked(next_pts: wp.array2d(dtype=wp.float32), status: wp.array(dtype=wp.uint8),
                 min_tracked: int, max_corners: int, points: wp.array2d(dtype=wp.float32),
                 tracked: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32),
                 detect: wp.array(dtype=wp.int32)):
    """The finite points with status 1, in order, to ``points[:tracked]`` (one block, a scan
    per chunk); ``count`` = min(tracked, max_corners); ``detect`` = tracked < min_tracked."""
    _blk, lane = wp.tid()
    n = next_pts.shape[0]
    base = int(0)
    start = int(0)
    while start < n:
        i = start + lane
        f = int(0)
        if i < n:
            if status[i] != wp.uint8(0) and usable(next_pts, i):
                f = 1
        t = wp.tile(f)
        s = base + wp.untile(wp.tile_scan_inclusive(t)) - f
        if f == 1:
            points[s, 0] = next_pts[i, 0]
            points[s, 1] = next_pts[i, 1]
        base += wp.tile_extract(wp.tile_sum(t), 0)
        start += wp.block_dim()
    if lane == 0:
        tracked[0] = base
        count[0] = wp.min(base, max_corners)
        detect[0] = int(base < min_tracked)


@wp.kernel
def merge_fresh(fresh: wp.array2d(dtype=wp.float32), selected: wp.array(dtype=wp.int32),
                tracked: wp.array(dtype=wp.int32), min_dist_sq: float, max_corners: int,
                points: wp.array2d(dtype=wp.float32), count: wp.array(dtype=wp.int32)):
    """Append ``fresh[:selected[0]]`` (strongest first) lying at least sqrt(``min_dist_sq``)
    from each of the ``tracked[0]`` kept points (float32 squared distances, as NumPy's), up to
    ``max_corners`` points in all; pad to 4 with off-image points (one block)."""
    _blk, lane = wp.tid()
    n_fresh = selected[0]
    n_kept = tracked[0]
    base = n_kept
    start = int(0)
    while start < n_fresh:
        j = start + lane
        f = int(0)
        if j < n_fresh:
            f = int(1)
            for k in range(n_kept):
                dx = fresh[j, 0] - points[k, 0]
                dy = fresh[j, 1] - points[k, 1]
                if dx * dx + dy * dy < min_dist_sq:
                    f = 0
        t = wp.tile(f)
        s = base + wp.untile(wp.tile_scan_inclusive(t)) - f
        if f == 1 and s < max_corners:
            points[s, 0] = fresh[j, 0]
            points[s, 1] = fresh[j, 1]
        base += wp.tile_extract(wp.tile_sum(t), 0)
        start += wp.block_dim()
    if lane == 0:
        total = wp.min(base, max_corners)
        for i in range(total, 4):
            points[i, 0] = OFF_IMAGE
            points[i, 1] = OFF_IMAGE
        count[0] = wp.max(total, 4)


@wp.kernel
def pad_points(count: wp.array(dtype=wp.int32), points: wp.array2d(dtype=wp.float32)):
    """NaN in the rows past ``count[0]``."""
    i = wp.tid()
    if i >= count[0]:
        points[i, 0] = wp.float32(wp.nan)
        points[i, 1] = wp.float32(wp.nan)


@wp.kernel
def sample_first(src_pts: wp.array(dtype=wp.vec2d), dst_pts: wp.array(dtype=wp.vec2d),
                 count: wp.array(dtype=wp.int32), seed: int,
                 hypotheses: wp.array(dtype=wp.mat33d)):
    """``sample_hypotheses`` over the first ``count[0]`` points: the samples
    :func:`warpvx.find_homography` draws from those points alone; zeros (no model) under 4
    points (possible only with ``min_tracked`` < 4), where the 4 distinct indices of a
    sample do not exist."""
    h = wp.tid()
    n = count[0]
    model = wp.mat33d()
    if n >= 4:
        model = fh.draw_hypothesis(src_pts, dst_pts, n, seed, h)
    hypotheses[h] = model


@wp.kernel
def fill_sentinels(keys: hc.CandidateKeys, capacity: int):
    """Keys past the candidate count sort after every candidate (all key bits set)."""
    i = wp.tid()
    if i >= keys.count[0] and i < capacity:
        keys.keys[i] = (wp.int64(1) << wp.int64(32 + keys.raster_bits)) - wp.int64(1)


class DeviceRansac:
    """:func:`warpvx.find_homography` (Warp) on the first ``count[0]`` of ``src``/``dst``
    (float32 [P, 2] device buffers): the find_homography workspace of P points with its
    sampling launch replaced by :func:`sample_first`; H into ``h_out`` (float64 3x3).

    The same H, bit for bit, as a call on the first ``count`` points: the rows after them
    are never inliers, and every sum adds each lane's points in order, so they change none."""

    def __init__(self, src, dst, count, threshold: float, iters: int, seed: int, h_out):
        device = src.device
        threshold2 = float(threshold) ** 2
        self.ws = fh._Workspace(src, dst, int(iters), threshold2, seed, device)
        old = self.ws.sample
        sample = Recorded(sample_first, int(iters), device, src_pts=self.ws.src_pts,
                          dst_pts=self.ws.dst_pts, count=count, seed=int(seed),
                          hypotheses=old.args["hypotheses"])
        self.ws.ransac[self.ws.ransac.index(old)] = self.ws.sample = sample
        self.src, self.dst, self.h_out, self.threshold2, self.seed = src, dst, h_out, threshold2, seed
        self.mask = wp.empty(src.shape[0], dtype=wp.uint8, device=device)

    def launch(self):
        self.ws.run(self.src, self.dst, self.threshold2, self.seed, self.h_out, self.mask)


class DeviceCorners:
    """``harris_corners(gray, max_corners, quality_level, min_distance, block_size, k)`` on
    gray images of ``shape`` (h, w) with no host sync: strongest-first float32 points into
    ``points`` ([max_corners, 2]) and their number into ``result[0]`` (int32 [3], as
    ``write_selected``)."""

    def __init__(self, shape, device, max_corners: int, quality_level: float,
                 min_distance: float, block_size: int = 3, k: float = 0.04):
        h, w = shape
        # A workspace of its own (not the cache's, shared by harris_corners calls and other
        # plans): its launches are sized for the whole capacity once and write into
        # ``self.points``.
        self.ws = ws = hc._CornersWorkspace(h, w, device)
        ws.resize(ws.capacity)
        self.block_size, self.k = int(block_size), float(k)
        self.quality_level = float(quality_level)
        self.points = wp.empty((max_corners, 2), dtype=wp.float32, device=device)
        self.suppress = min_distance >= 1
        self.sentinels = Recorded(fill_sentinels, ws.capacity, device, keys=ws.keys,
                                  capacity=ws.capacity)
        ws.select_cmd.set(points=self.points, last_round=hc.MAX_ROUNDS - 1 if self.suppress else 0)
        if self.suppress:
            ws.set_spacing(int(math.ceil(min_distance)), int(round(min_distance)),
                           float(min_distance) ** 2)
        self.result = ws.result
        # The condition of the device loop: candidates left undecided after all the rounds.
        self.undecided_left = ws.result[1:2]

    def _rounds(self, first: int = 1):
        """Rounds ``first`` .. in batches of :data:`ROUND_BATCH`, each batch after the first
        only when the previous one left candidates undecided (a nested conditional on its
        last counter)."""
        last = min(first + ROUND_BATCH, hc.MAX_ROUNDS) - 1
        for r in range(first, last + 1):
            self.ws.run_round(r)
        if last < hc.MAX_ROUNDS - 1:
            wp.capture_if(self.ws.undecided[last:last + 1], on_true=self._rounds, first=last + 1)

    def _restart(self):
        # Out of round counters: start them again (every decision so far stays), as
        # harris_corners does.
        self.ws.undecided.zero_()
        self.ws.undecided[0:1].fill_(1)
        self._rounds()
        self.ws.select_cmd.launch()

    def launch(self, gray):
        """Detect in ``gray`` (uint8 HxW ``wp.array`` of the constructed shape)."""
        ws = self.ws
        corner_response(gray, self.block_size, 3, self.k, "harris", ws.response)
        ws.row_max_cmd.launch()
        ws.finish_cmd.launch()
        ws.collect_cmd.launch(quality_level=self.quality_level)
        self.sentinels.launch()
        wp.utils.radix_sort_pairs(ws.keys.keys, ws.values, ws.capacity, 0, 32 + ws.keys.raster_bits)
        ws.rank_cmd.launch(initial_state=hc.UNDECIDED if self.suppress else hc.ACCEPTED,
                           conflicts=ws.conflicts)
        if self.suppress:
            ws.find()
            self._rounds()
            ws.select_cmd.launch()
            wp.capture_while(self.undecided_left, self._restart)
        else:
            ws.select_cmd.launch()
        ws.clear_cmd.launch()


__all__ = ["DeviceCorners", "DeviceRansac", "keep_tracked", "merge_fresh", "pad_points", "BLOCK"]
