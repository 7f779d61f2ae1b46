"""The stabilizer with the whole frame on the Warp device: one program per frame, replayed.

:func:`warpvx.apps.stabilize.stabilize`'s graph keeps the point set and the 3x3 chain on the
host (5 device->host and 3 host->device copies and a serial round trip per frame). Here every
step runs on the device, in one fixed sequence of launches per frame (:meth:`DevicePlan.program`):

    frame (ring slot s) -> [undistort: remap] -> gray -> pyramid -> LK from slot s-1's pyramid -> park_lost ->
    RANSAC (first ``count`` points) -> keep_tracked -> [if the device's flag says so:
    detect + merge_fresh] -> pad -> follow_motion (H, cut test, T, smoothing, truncation) ->
    warp of slot s - lag -> output slot s

(:mod:`warpvx.kernels_warp.stabilize_points`, :mod:`warpvx.kernels_warp.stabilize_motion`).
Re-detection is decided on the device and run in a conditional node (``wp.capture_if``):
detecting every frame would cost a full-resolution Harris map, a sort over every pixel and
the selection rounds each frame, where re-detection is rare (the bundled hand-held clip: 10 of
46 frames, most in the first 12; the benchmark's shaken photo: once in 70 frames); a cheaper
low-resolution detector would give other points than the graph path. On CUDA each ring slot's
program is captured once as a CUDA graph (``wp.ScopedCapture``) and replayed
(``wp.capture_launch``); where capture is unavailable (no conditional nodes, or inside a
caller's capture) it runs eagerly, and the conditional then reads the flag on the host.

Per frame the host does one copy of the frame into a pinned ring slot, one host->device copy
(upload stream), the graph launch (compute stream) and one device->host copy of the output
image plus its four 3x3 matrices (download stream), each stream waiting on the others'
events: with ``depth`` frames in flight the upload of frame t+1 and the download of frame t-1
overlap the compute of frame t. The device ring holds ``lag + depth + 1`` frames (the centred
window warps frame t - lag at step t). The host's copies run in row bands on a few threads
(:class:`FrameCopier`; NumPy releases the GIL while copying), and :meth:`DevicePlan.run`
starts copying frame t+1 into its pinned slot (:meth:`DevicePlan.stage`) before it waits for
the download of frame t+1-depth, so the copy overlaps that wait and the caller's use of the
output; a caller that decodes can also write straight into the slot
(:meth:`DevicePlan.input_slot`).

Supported: the homography motion with the Harris detector (the defaults; :func:`supports`),
with or without undistortion; other configurations take the graph path. Same frames as the graph path on
``warp-cpu`` (tests/apps/test_stabilize_device.py states the tolerance).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from functools import partial

import numpy as np

from ..errors import WarpvxValueError
from .stabilize import _NO_POINTS, StabilizerConfig, _crop_matrix, _park_lost_kernel, undistort_maps

__all__ = ["DevicePlan", "FrameCopier", "make_chain", "supports", "run_device"]

GRAY_CODE = 6  # cv2.COLOR_BGR2GRAY
LK_ITERS, LK_EPS, LK_MIN_EIG = 30, 0.01, 1e-4  # optical_flow_pyr_lk's defaults (the graph's)
# Host threads copying a frame (one thread copies a 1080p frame, 6 MB, in about 0.8 ms: most
# of a 1000 FPS budget); frames under BAND_BYTES per thread are copied on the calling thread.
COPY_THREADS = 4
BAND_BYTES = 1 << 19
# Matrices follow_motion records per step: H, T, transform, warp and the segment index (in a
# matrix, so one download carries all).
RECORDS = 5


class FrameCopier:
    """Copies of HxWxC arrays in row bands on ``threads`` threads.

    :meth:`start` returns a handle for :meth:`wait`; the destination must not be read, nor
    the source written, before that. NumPy releases the GIL while it copies, so the bands
    run in parallel and beside the calling thread's Python work.
    """

    def __init__(self, threads: int = COPY_THREADS):
        self.threads = threads
        self.pool = ThreadPoolExecutor(threads, thread_name_prefix="warpvx-copy") if threads > 1 else None

    def start(self, dst: np.ndarray, src: np.ndarray) -> list:
        """Begin ``dst[...] = src`` (same shape); a handle for :meth:`wait`."""
        if getattr(src, "shape", None) != dst.shape or getattr(src, "dtype", None) != dst.dtype:
            got = f"{getattr(src, 'dtype', type(src).__name__)} {np.shape(src)}"
            raise WarpvxValueError(f"frame: expected {dst.dtype} {dst.shape}, got {got}")
        bands = min(self.threads, dst.shape[0], max(1, dst.nbytes // BAND_BYTES))
        if self.pool is None or bands <= 1:
            np.copyto(dst, src)
            return []
        edges = np.linspace(0, dst.shape[0], bands + 1).astype(int)
        return [self.pool.submit(np.copyto, dst[a:b], src[a:b]) for a, b in zip(edges, edges[1:])]

    @staticmethod
    def wait(handle: list) -> None:
        for job in handle:
            job.result()

    def copy(self, src: np.ndarray) -> np.ndarray:
        """A new array equal to ``src``."""
        dst = np.empty_like(src)
        self.wait(self.start(dst, src))
        return dst

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True)


def supports(config: StabilizerConfig) -> str | None:
    """Why ``config`` needs the graph path (a short reason), or None when the device path
    runs it."""
    if config.motion != "homography":
        return f"motion {config.motion!r}"
    if config.detector != "harris":
        return f"detector {config.detector!r}"
    return None


def make_chain(config: StabilizerConfig, size, device):
    """The :class:`~warpvx.kernels_warp.stabilize_motion.Chain` constants of ``config`` for
    frames of ``size`` (w, h) on ``device``."""
    import warp as wp

    from ..kernels_warp.stabilize_motion import Chain

    chain = Chain()
    chain.weights = wp.array(config.weights(), dtype=wp.float64, device=device)
    chain.lag, chain.crop = config.lag, float(config.crop)
    chain.crop_matrix = wp.mat33d(*_crop_matrix(size, config.crop).ravel())
    chain.width, chain.height = float(size[0]), float(size[1])
    chain.cut_threshold = float("inf") if config.cut_threshold is None else float(config.cut_threshold)
    return chain


class DevicePlan:
    """Buffers, streams and programs of the device path for frames of ``size`` (w, h).

    ``device``: a Warp device (``"cpu"`` or ``"cuda:N"``); ``depth`` >= 1 frames in flight;
    ``use_graph``: capture each slot's program once and replay it (None: on CUDA; a CPU
    capture replays the same launches, which the tests use to check the captured program);
    ``copy_threads``: host threads of the frame copies (:class:`FrameCopier`; 1: none).
    :meth:`run` consumes feed dicts ({"frame": uint8 HxWx3, "live": uint8 [1]}) and yields,
    per step, a dict of ``stabilized`` (uint8 HxWx3, the frame ``lag`` steps back),
    float64 3x3 ``motion``, ``trajectory``, ``transform``, ``warp`` and the int ``segment``
    (as the graph's outputs).
    """

    def __init__(self, size, config: StabilizerConfig, device, *, depth: int = 3,
                 use_graph: bool | None = None, copy_threads: int = COPY_THREADS):
        import warp as wp

        from ..check import check_int, check_size
        from ..flow import _level_limit
        from ..kernels_warp import stabilize_motion as km
        from ..kernels_warp import stabilize_points as kp
        from ..kernels_warp._launch import CapturedProgram, Recorded

        reason = supports(config)
        if reason is not None:
            raise WarpvxValueError(f"config: the device path does not run {reason}; use the graph")
        self.w, self.h = w, h = check_size(size, "size")
        self.depth = check_int(depth, "depth", min_value=1)
        self.copier = FrameCopier(check_int(copy_threads, "copy_threads", min_value=1))
        self._staged = None  # (step, frame, copy handle) of the frame being staged
        self.device = dev = wp.get_device(device)
        c = self.config = config
        self.lag = c.lag
        self.slots = R = self.lag + self.depth + 1
        win = (c.lk_win, c.lk_win)
        self.lk_levels = min(c.levels - 1, _level_limit((w, h), win, c.levels - 1))
        self.win = win
        P = max(c.max_corners, 4)

        def empty(shape, dtype=wp.uint8):
            return wp.empty(shape, dtype=dtype, device=dev)

        self.frames = [wp.zeros((h, w, 3), dtype=wp.uint8, device=dev) for _ in range(R)]
        self.maps = None  # undistortion: remap maps, and the undistorted frames' ring
        self.sources = self.frames
        if c.camera_matrix is not None:
            self.maps = [wp.array(m, dtype=wp.float32, device=dev) for m in undistort_maps(c, (w, h))]
            self.sources = [wp.zeros((h, w, 3), dtype=wp.uint8, device=dev) for _ in range(R)]
        self.outs = [empty((h, w, 3)) for _ in range(R)]
        self.records = [empty(RECORDS, wp.mat33d) for _ in range(R)]
        self.pyramids = []
        for _ in range(R):
            pyr = [wp.zeros((h, w), dtype=wp.uint8, device=dev)]
            for _lvl in range(1, c.levels):
                ph, pw = pyr[-1].shape
                pyr.append(wp.zeros(((ph + 1) // 2, (pw + 1) // 2), dtype=wp.uint8, device=dev))
            self.pyramids.append(pyr)
        init = np.full((P, 2), np.nan, np.float32)
        init[:4] = _NO_POINTS
        self.points = wp.array(init, dtype=wp.float32, device=dev)
        self.count = wp.array([4], dtype=wp.int32, device=dev)
        self.tracked = empty(1, wp.int32)
        self.detect = empty(1, wp.int32)
        self.live = wp.ones(1, dtype=wp.int32, device=dev)
        self._live_flag = True  # what self.live holds (set on the device only when it changes)
        self.lk_out = (empty((P, 2), wp.float32), empty(P), empty(P, wp.float32))
        self.parked = empty((P, 2), wp.float32)
        self.homography = empty((3, 3), wp.float64)
        weights = c.weights()
        self.history = wp.array(np.full((max(1, len(weights) - 1), 3, 3), np.nan), dtype=wp.mat33d,
                                device=dev)
        self.segments = wp.zeros(self.history.shape[0], dtype=wp.int32, device=dev)
        self.sampling_matrix = empty(1, wp.mat33)

        chain = make_chain(c, (w, h), dev)
        self.park = Recorded(_park_lost_kernel(), P, dev, pts=self.lk_out[0], status=self.lk_out[1],
                             out=self.parked)
        self.ransac = kp.DeviceRansac(self.points, self.parked, self.count, c.ransac_threshold,
                                      c.ransac_iters, 0, self.homography)
        self.keep = Recorded(kp.keep_tracked, [1], dev, block_dim=kp.BLOCK, next_pts=self.lk_out[0],
                             status=self.lk_out[1], min_tracked=c.min_tracked,
                             max_corners=c.max_corners, points=self.points, tracked=self.tracked,
                             count=self.count, detect=self.detect)
        self.corners = kp.DeviceCorners((h, w), dev, c.max_corners, c.quality_level, c.min_distance)
        self.merge = Recorded(kp.merge_fresh, [1], dev, block_dim=kp.BLOCK, fresh=self.corners.points,
                              selected=self.corners.result, tracked=self.tracked,
                              min_dist_sq=float(c.min_distance) ** 2, max_corners=c.max_corners,
                              points=self.points, count=self.count)
        self.pad = Recorded(kp.pad_points, P, dev, count=self.count, points=self.points)
        self.follow = [Recorded(km.follow_motion, 1, dev, homography=self.homography, live=self.live,
                                chain=chain, history=self.history, segments=self.segments, record=rec,
                                sampling_matrix=self.sampling_matrix) for rec in self.records]
        self.warps = [km.warp_by_device_matrix(self.sources[(s - self.lag) % R], self.sampling_matrix,
                                               self.outs[s]) for s in range(R)]

        self.use_graph = dev.is_cuda if use_graph is None else bool(use_graph)
        # mark(stage) is called after each stage of an eager program (profiling: the
        # benchmark records events there); None in normal runs.
        self.mark = None
        self.steps = 0
        self._wp = wp
        self._streams(wp)
        # Slot s's program: eager on slot 0's first step (modules load, scratch is made),
        # captured on first use after that (slots run in order).
        self.programs = [CapturedProgram(partial(self.program, s), dev, self.compute,
                                         enabled=self.use_graph, warm=s > 0) for s in range(R)]
        # The buffers were allocated and filled on the compute stream; the copy streams use
        # them from the first frame on.
        wp.synchronize_device(dev)

    def _streams(self, wp):
        """Pinned host rings and the copy streams (CUDA), or host views of the device rings
        (CPU: the device memory is host memory)."""
        dev, h, w = self.device, self.h, self.w
        self.compute = wp.get_stream(dev) if dev.is_cuda else None
        if dev.is_cpu:
            self.host_in = [f.numpy() for f in self.frames]
            self.host_out = [o.numpy() for o in self.outs]
            self.host_rec = [r.numpy() for r in self.records]
            return
        pinned = {"device": "cpu", "pinned": True}
        self.pin_in = [wp.empty((h, w, 3), dtype=wp.uint8, **pinned) for _ in range(self.depth)]
        self.pin_out = [wp.empty((h, w, 3), dtype=wp.uint8, **pinned) for _ in range(self.depth)]
        self.pin_rec = [wp.empty(RECORDS, dtype=wp.mat33d, **pinned) for _ in range(self.depth)]
        self.host_in = [a.numpy() for a in self.pin_in]
        self.host_out = [a.numpy() for a in self.pin_out]
        self.host_rec = [a.numpy() for a in self.pin_rec]
        self.upload, self.download = wp.Stream(dev), wp.Stream(dev)
        self.uploaded = [wp.Event(dev) for _ in range(self.depth)]
        self.downloaded = [wp.Event(dev) for _ in range(self.depth)]
        self.done = [wp.Event(dev) for _ in range(self.slots)]

    # -- the per-frame program ------------------------------------------------------------

    @property
    def graphs(self) -> list:
        """Each slot's captured graph (None: not captured, or not yet)."""
        return [p.graph for p in self.programs]

    @property
    def capture_error(self) -> str | None:
        """Why a slot's capture failed, when one did (that slot then launches eagerly; each
        slot tries once: a failed capture costs one eager run of the program)."""
        return next((p.error for p in self.programs if p.error), None)

    def program(self, s: int):
        """Every device step of a frame in ring slot ``s``: fixed shapes, no host sync (what a
        captured graph holds)."""
        import warp as wp

        from ..kernels_warp.color_convert import color_convert
        from ..kernels_warp.gaussian_pyramid import gaussian_pyramid
        from ..geometry import _border_value
        from ..kernels_warp.optical_flow_pyr_lk import optical_flow_pyr_lk
        from ..kernels_warp.remap import remap
        from ..modes import BORDER_CONSTANT, INTER_LINEAR

        mark = self.mark or (lambda stage: None)
        pyr, prev = self.pyramids[s], self.pyramids[(s - 1) % self.slots]
        mark("start")
        if self.maps is not None:  # the graph's undistort node: linear, constant border 0
            remap(self.frames[s], *self.maps, INTER_LINEAR, BORDER_CONSTANT, _border_value(0),
                  out=self.sources[s])
        color_convert(self.sources[s], GRAY_CODE, out=pyr[0])
        gaussian_pyramid(pyr[0], len(pyr), out=pyr)
        mark("gray + pyramid")
        levels = self.lk_levels + 1
        optical_flow_pyr_lk(prev[:levels], pyr[:levels], self.points, None, self.win,
                            self.lk_levels, LK_ITERS, LK_EPS, LK_MIN_EIG, out=self.lk_out)
        mark("LK")
        self.park.launch()
        self.ransac.launch()
        mark("park_lost + RANSAC")
        self.keep.launch()
        wp.capture_if(self.detect, on_true=self._refill, gray=pyr[0])
        self.pad.launch()
        mark("refresh (+ detect when flagged)")
        self.follow[s].launch()
        mark("3x3 chain")
        self.warps[s].launch()
        mark("warp")

    def _refill(self, gray):
        self.corners.launch(gray)
        self.merge.launch()

    # -- the frame loop -------------------------------------------------------------------

    def input_slot(self) -> np.ndarray:
        """The host array (uint8 HxWx3) the next step reads its frame from: a pinned ring
        slot on CUDA (once its last upload is done), the device ring slot on Warp's CPU
        device (its memory is host memory). A decoder may write the frame there
        (``cv2.VideoCapture.read(image=plan.input_slot())``) and pass the slot to
        :meth:`submit`, which then copies nothing."""
        t = self.steps
        if self.device.is_cuda:
            if t >= self.depth:
                self._wp.synchronize_event(self.uploaded[t % self.depth])
            return self.host_in[t % self.depth]
        return self.host_in[t % self.slots]

    def stage(self, frame) -> None:
        """Begin copying ``frame`` into :meth:`input_slot` (on the copier's threads) and
        return; the :meth:`submit` of the same array waits for that copy instead of
        copying. ``frame`` must not change until then."""
        self._wait_staged()
        self._staged = (self.steps, frame, self.copier.start(self.input_slot(), frame))

    def _wait_staged(self):
        """The staged frame: (step, frame) once its copy is done, or None."""
        staged, self._staged = self._staged, None
        if staged is None:
            return None
        self.copier.wait(staged[2])
        return staged[:2]

    def _fill(self, t: int, frame) -> None:
        """``frame`` into the host slot of step ``t`` (unless staged there, or the slot)."""
        staged = self._wait_staged()
        if staged is not None and staged[0] == t and staged[1] is frame:
            return
        slot = self.input_slot()
        if frame is not slot:
            self.copier.wait(self.copier.start(slot, frame))

    def submit(self, frame, live: bool):
        """Enqueue step ``self.steps`` (no wait for the device, except for a free pinned
        slot); returns the step's index."""
        t, s, p = self.steps, self.steps % self.slots, self.steps % self.depth
        if bool(live) != self._live_flag:  # padding steps flush the centred window
            self._live_flag = bool(live)
            self.live.fill_(int(self._live_flag))
        if not live:
            self._wait_staged()  # a padding step: nothing to upload
        else:
            self._fill(t, frame)
            if self.device.is_cuda:
                self._upload(t, s, p)
        self.programs[s]()
        if self.device.is_cuda:
            self._download(s, p)
        self.steps += 1
        return t

    def _upload(self, t: int, s: int, p: int):
        """Pinned slot ``p`` (filled) to device slot ``s`` on the upload stream once no step
        still reads it; the compute stream waits for the copy."""
        from ..runtime.native_copy import to_device

        free = t - self.slots + max(self.lag, 1)  # the last step that read device slot s
        if free >= 0:
            self.upload.wait_event(self.done[free % self.slots])
        to_device(self.frames[s], self.pin_in[p], self.upload)
        self.upload.record_event(self.uploaded[p])
        self.compute.wait_event(self.uploaded[p])

    def _download(self, s: int, p: int):
        """Output slot ``s`` (image and matrices) into pinned slot ``p`` on the download
        stream, after the step's compute."""
        wp = self._wp
        self.compute.record_event(self.done[s])
        self.download.wait_event(self.done[s])
        wp.copy(self.pin_out[p], self.outs[s], stream=self.download)
        wp.copy(self.pin_rec[p], self.records[s], stream=self.download)
        self.download.record_event(self.downloaded[p])

    def result(self, t: int, copy: bool = True) -> dict:
        """The outputs of step ``t`` (waits for its download). With ``copy`` False the image
        is a view of the output ring (pinned on CUDA), valid until the next :meth:`submit`."""
        if self.device.is_cuda:
            p = t % self.depth
            self._wp.synchronize_event(self.downloaded[p])
            image, rec = self.host_out[p], self.host_rec[p]
        else:
            image, rec = self.host_out[t % self.slots], self.host_rec[t % self.slots]
        rec = np.array(rec, np.float64).reshape(RECORDS, 3, 3)
        return {"stabilized": self.copier.copy(image) if copy else image, "motion": rec[0],
                "trajectory": rec[1], "transform": rec[2], "warp": rec[3],
                "segment": int(rec[4, 0, 0])}

    def run(self, feed, copy: bool = True):
        """Outputs of every step of ``feed`` in order, ``depth`` steps in flight. The next
        live frame is read from ``feed`` and staged before the oldest step is waited for."""
        pending = deque()
        items = iter(feed)
        item = next(items, None)
        while item is not None:
            pending.append(self.submit(item["frame"], _live(item)))
            item = next(items, None)
            if item is not None and _live(item):
                self.stage(item["frame"])
            if len(pending) >= self.depth:
                yield self.result(pending.popleft(), copy)
        while pending:
            yield self.result(pending.popleft(), copy)


def _live(item) -> bool:
    return bool(np.asarray(item["live"]).reshape(-1)[0])


def run_device(backend: str, config: StabilizerConfig, depth: int, copy: bool = True):
    """``run(feed, size)`` for :func:`warpvx.apps.stabilize._drive`: the device path on
    ``backend`` (``"warp-cpu"`` or ``"cuda"``)."""
    device = "cpu" if backend == "warp-cpu" else backend

    def run(feed, size):
        plan = DevicePlan(size, config, device, depth=depth)
        try:
            yield from plan.run(feed, copy)
        finally:
            plan.copier.close()  # its threads end now, not when the plan is collected

    return run

