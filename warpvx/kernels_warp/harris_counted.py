"""goodFeaturesToTrack on Warp with no host sync: the corners into a graph's Counted buffers.

:func:`.harris_corners.harris_corners` reads two counts back to the host (to size the sort,
and to learn whether the selection rounds decided every candidate). Given ``out=`` (a
:class:`~warpvx._counted.Counted`: fixed rows and a device count, what a graph allocates to
capture the node) it runs :class:`DeviceCorners` instead, on the same kernels: the sort does
not read the count (:class:`._device_sort.CountedSort`, sentinel keys after the candidates)
and the rounds run in conditional batches decided on the device. The points are those of the
host-synchronised path exactly (tests/kernels/test_harris_corners.py,
tests/apps/test_stabilize_device.py). The stabilizer's device engine uses it too.
"""

from __future__ import annotations

import math

import warp as wp

from . import harris_corners as hc
from ._device_sort import CountedSort
from ._launch import Recorded, workspace
from .harris_response import corner_response

wp.set_module_options({"enable_backward": False})

# Selection rounds launched per conditional batch: real frames need a few to a dozen rounds;
# launching all MAX_ROUNDS (each a launch over every candidate slot) costs more.
ROUND_BATCH = 8


@wp.kernel
def fill_sentinels(keys: hc.CandidateKeys, capacity: int, small: int, stride: int):
    """Keys past the candidate count sort after every candidate (all key bits set), up to
    ``small`` when the count fits there (the sort reads no further), else up to ``capacity``.
    Thread ``t`` of ``stride`` writes keys ``count + t``, ``count + t + stride``, ..."""
    n = keys.count[0]
    end = wp.where(n <= small, small, capacity)
    sentinel = (wp.int64(1) << wp.int64(32 + keys.raster_bits)) - wp.int64(1)
    for i in range(n + wp.tid(), end, stride):
        keys.keys[i] = sentinel


@wp.kernel
def copy_count(result: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    """count[0] = result[0] (the points written, at most their buffer's rows)."""
    count[0] = result[0]


class DeviceCorners:
    """``harris_corners(gray, max_corners, quality_level, min_distance, block_size, k, ksize,
    score)`` on gray images of ``shape`` (h, w) with no host sync: strongest-first float32
    points into ``points`` ([max_corners, 2]; made when not given) and their number into
    ``result[0]`` (int32 [3], as ``write_selected``; at most ``max_corners``).

    The candidates are sorted with sentinel keys after the count, over the first
    :data:`._device_sort.SMALL` keys when they hold them, else the whole capacity
    (:class:`._device_sort.CountedSort`); the selection rounds run in batches of
    :data:`ROUND_BATCH`, each batch in a conditional node on the previous batch's last
    "undecided" counter (nested ``wp.capture_if``), up to
    :data:`~.harris_corners.MAX_ROUNDS`, looping on the device (``wp.capture_while``) in the
    rare case they did not decide every candidate (the counters start again, as
    :func:`~.harris_corners.harris_corners` does). Outside a capture the conditions are read
    on the host.
    """

    def __init__(self, shape, device, max_corners: int, quality_level: float,
                 min_distance: float, block_size: int = 3, k: float = 0.04, *, ksize: int = 3,
                 score: str = "harris", points=None):
        h, w = shape
        # A workspace of its own (not the cache's, shared by harris_corners calls and other
        # plans): its launches are sized for the whole capacity once and write into
        # ``self.points``.
        self.ws = ws = hc._CornersWorkspace(h, w, device)
        ws.resize(ws.capacity)
        self.block_size, self.k = int(block_size), float(k)
        self.ksize, self.score = int(ksize), score
        self.quality_level = float(quality_level)
        self.points = wp.empty((max_corners, 2), dtype=wp.float32, device=device) \
            if points is None else points
        self.suppress = min_distance >= 1
        self.sort = CountedSort(ws.keys.keys, ws.values, ws.keys.count, ws.capacity,
                                32 + ws.keys.raster_bits)
        # Not a thread per key: writing the whole capacity (~8 MB at 1280x720) when the sort
        # reads its first SMALL keys cost ~7 us of device time on an H100.
        self.sentinels = Recorded(fill_sentinels, ws.threads, device, keys=ws.keys,
                                  capacity=ws.capacity, small=self.sort.small,
                                  stride=ws.threads)
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
        corner_response(gray, self.block_size, self.ksize, self.k, self.score, ws.response)
        ws.row_max_cmd.launch()
        ws.finish_cmd.launch()
        ws.collect_cmd.launch(quality_level=self.quality_level)
        self.sentinels.launch()
        self.sort.launch()
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


def select_into(src, out, max_corners, quality_level, min_distance, block_size, k, ksize,
                score):
    """``harris_corners``' points of gray uint8 ``src`` into Counted ``out`` (float32
    [max_corners, 2] rows, int32 [1] count); a :class:`DeviceCorners` per image size,
    parameters and buffers (cached). Returns ``out``."""
    device = src.device
    h, w = src.shape
    if h < 3 or w < 3:  # no pixel 1 px inside the image
        out.count.zero_()
        return out
    params = (int(max_corners), float(quality_level), float(min_distance), int(block_size),
              float(k))
    key = (h, w, params, int(ksize), score, out.rows.ptr, out.count.ptr)
    det = workspace("harris_corners_device", key, device, lambda: _DeviceSelect(
        DeviceCorners((h, w), device, *params, ksize=ksize, score=score, points=out.rows),
        out.count))
    det.corners.launch(src)
    det.copy_count.launch()
    return out


class _DeviceSelect:
    """A :class:`DeviceCorners` writing a Counted's rows, and the launch copying its count."""

    def __init__(self, corners: DeviceCorners, count):
        self.corners = corners
        self.copy_count = Recorded(copy_count, 1, count.device, result=corners.result,
                                   count=count)


__all__ = ["DeviceCorners", "ROUND_BATCH", "select_into"]
