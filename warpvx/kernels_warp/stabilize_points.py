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

:class:`DeviceCorners` (:mod:`.harris_counted`, which a graph's captured ``harris_corners``
node runs too) gives ``harris_corners``' points exactly (tests/apps/test_stabilize_device.py).
"""

from __future__ import annotations

import warp as wp

from . import find_homography as fh
from ._launch import Recorded
from .harris_counted import DeviceCorners

# No FMA contraction: merge_fresh squares distances as NumPy does, and sample_first inlines
# find_homography's draw_hypothesis, which must round as it does there.
wp.set_module_options({"enable_backward": False, "fuse_fp": False})

BLOCK = 256  # lanes of the one-block compaction kernels
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


class DeviceRansac:
    """:func:`warpvx.find_homography` (Warp) on the first ``count[0]`` of ``src``/``dst``
    (float32 [P, 2] device buffers): the find_homography workspace of P points with its
    sampling launch replaced by :func:`sample_first`; H into ``h_out`` (float64 3x3).

    The same H, bit for bit, as a call on the first ``count`` points: the rows after them
    are never inliers, and every sum adds each lane's points in order, so they change none."""

    def __init__(self, src, dst, count, threshold: float, iters: int, seed: int, h_out):
        device = src.device
        threshold2 = float(threshold) ** 2
        self.ws = fh.Workspace(src, dst, int(iters), threshold2, seed, device)
        self.ws.sample = Recorded(sample_first, int(iters), device, src_pts=self.ws.src_pts,
                                  dst_pts=self.ws.dst_pts, count=count, seed=int(seed),
                                  hypotheses=self.ws.hypotheses)
        self.src, self.dst, self.h_out, self.threshold2, self.seed = src, dst, h_out, threshold2, seed
        self.mask = wp.empty(src.shape[0], dtype=wp.uint8, device=device)

    def launch(self):
        self.ws.run(self.src, self.dst, self.threshold2, self.seed, self.h_out, self.mask)


__all__ = ["DeviceCorners", "DeviceRansac", "keep_tracked", "merge_fresh", "pad_points", "BLOCK"]
