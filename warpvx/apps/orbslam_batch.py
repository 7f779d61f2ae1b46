"""The ORB-SLAM2 front end in batches of frames: extraction and matching of B frames per launch
set on the GPU, the costly state-free tracking work of B frames spread over worker processes.

Tracking (:func:`warpvx.apps.orbslam.track`) is sequential only through cheap state (the
previous frame and keyframe, the scale from the reference's depths, the motion model); its
costly parts depend on the frames alone: the essential matrix between frame t and t-1
(:func:`~warpvx.apps.orbslam.essential_core`, MAGSAC++, ~5 ms on one core) for a monocular
sequence, the stereo matching of frame t (:func:`~warpvx.apps.orbslam_match.stereo_depth`,
~10 ms) for a stereo one. The graph, one batch of B frames per graph frame::

    images [B (x2 stereo), H, W] -> orb_batch (GPU role) -> feats (B (or 2B) keypoints, descriptors)
    feats, last_desc[-1] -> match_batch (GPU role) -> last_desc, nearest rows both ways between
        consecutive frames, one launch for the batch
        (:func:`~warpvx.apps.orbslam_match.nearest_batch_warp`)
    images, feats, nearest, tail[-1] -> pose_batch (CPU) -> tail, ahead: per frame on a
        process pool, the mutual pairs and their filter, then the stereo depths, or (mono, the
        first :data:`~warpvx.apps.orbslam_speculate.COVERED` frames of a run only) the essential
        core to the previous frame and the one to the frame before it as the keyframe (a
        guess: right after a keyframe change)
    state[-1], feats, ahead -> chain (CPU) -> state, poses [B, 4, 4], stats [B, 6]: ``track``
        frame by frame, the filtered matches taken from ``ahead`` and the essential matrix
        too when its inputs are the ones worked out ahead; mono, the later frames' cores are
        speculated on the pool a few frames before the chain needs them, the one ``track``
        will take only (only the chain knows the keyframe:
        :class:`~warpvx.apps.orbslam_speculate.CoreSpeculation` walks ahead as ``track``
        decides, into the next batch as the batch ends); the pool starts the jobs needed
        soonest first: a frame's core before the next batch's frame jobs, those before that
        batch's cores (see :class:`PosePool`)

With ``stream(depth >= 2)`` batch k+1 is extracted and matched on the GPU while batch k is
tracked. The pool is one of processes (``cv2.setNumThreads(1)`` in each), not threads: the
GPU host thread and the graph's CPU nodes then never wait on OpenCV for the GIL. The graph's
executor runs threads only, so the pool runs *inside* the ``pose_batch`` node (its worker
thread waits on the processes with the GIL released); the scheduler places the four nodes and
records their timeline as for any graph.

The chain is the bottleneck. By default (``chain_process``) it runs, with ``pose_batch`` and
the pool, in a process of its own (:mod:`warpvx.apps.orbslam_chain`: the graph's two CPU
nodes there only hand each batch over through shared memory and take the poses back), so
it no longer shares a GIL with the GPU thread and the executor. In process, it shares the
GIL with them and the pool's hand-off threads; NumPy lets the GIL go in every loop over more
than a few hundred elements and must take it back. So that the chain waits less for it (in
either process): the run sets a short
GIL switch interval (:data:`SWITCH_INTERVAL`, :func:`switch_interval`); a batch's jobs carry
their arrays once in shared memory (:class:`~warpvx.apps.orbslam_pool.SharedBlock`), not in
each job's pickle; the pool's handler thread does not spin while results wait (see
:mod:`warpvx.apps.orbslam_pool`, where the pool is).

Poses equal the sequential front end's (:func:`~warpvx.apps.orbslam.track_frames`, same
inputs, same per-frame ``track``; OpenCV's USAC draws from a fixed seed), up to the last bits
of the device matcher's ties, which match the CPU ones (see the tests).
"""

from __future__ import annotations

import contextlib
import functools
import sys
import time

import numpy as np

from ..errors import WarpvxValueError
from ..keypoints import FIELDS, Keypoints
from . import orbslam as o
from .orbslam_match import batch_pairs, mutual_pairs, nearest_batch, nearest_batch_warp, stereo_depth
from .orbslam_chain import ChainProcess, receive_batch, send_batch
from .orbslam_pool import SPARE_CORES, PosePool, default_workers, make_pool
from .orbslam_speculate import (COVERED, CoreSpeculation, _core_ahead, _essential_ahead, _essential_points,
                                _guessed_tracks, _keyframe_cursor, _parallax_ahead, _track_step, _tracks_ahead)


class _Later:
    """``[fn(*job) for fn, job in zip(fns, jobs)]`` (a function per job): on ``pool``'s
    processes when given, submitted now, needed at the run's frame ``start`` (the batch's
    first: the speculated cores of the frames before go first) and waited for by :meth:`get`;
    else in the calling thread, now. ``guesses``: per job, :func:`guess_job`'s arguments or
    None (needed at the job's frame)."""

    def __init__(self, pool, fns, jobs, guesses=(), points=None, start: int = 0):
        #: Per job, the frame's :func:`~warpvx.apps.orbslam.keypoint_xy` (:func:`pose_batch`'s;
        #: the chain's ``track`` takes them as they are).
        self.points = points
        self.start = start
        self._pool = pool
        #: The next batch's (set by its :func:`pose_batch`), and what this batch's chain takes
        #: over from the previous one's speculation (see
        #: :class:`~warpvx.apps.orbslam_speculate.CoreSpeculation`), or None.
        self.next = self.handed = None
        self._values = None if pool is not None else [f(*job) for f, job in zip(fns, jobs)]
        self._pending, self.guesses = None, [None] * len(jobs)
        if pool is None:
            return
        # The jobs' arrays once in a shared block (see orbslam_pool.SharedBlock), unless measuring without.
        block = pool.shared([*jobs, *(g for g in guesses if g is not None)]) if pool.share else None
        refer = block.refer if block is not None else (lambda job: job)
        try:
            self._pending = [pool.submit(f, *refer(job), need=start, block=block) for f, job in zip(fns, jobs)]
            #: Per job, a pending :func:`guess_job` (submitted after all the jobs), or None.
            self.guesses = [None if g is None else pool.submit(guess_job, *refer(g), need=start + k, block=block)
                            for k, g in enumerate(guesses)] or self.guesses
        finally:
            if block is not None:
                block.release()

    def get(self) -> list:
        if self._values is None:
            self._values = [self._pool.wait(t, "ahead") for t in self._pending]
        return self._values

    def done(self) -> int:
        """How many of the jobs, in order, have their values (:meth:`value` would not wait)."""
        if self._values is not None:
            return len(self._values)
        return next((k for k, t in enumerate(self._pending) if not t.ready()), len(self._pending))

    def value(self, k: int):
        """Job ``k``'s value (waited for, uncounted: the chain's speculation asks once it is done)."""
        return self._values[k] if self._values is not None else self._pending[k].get()


#: :func:`track_frames_batched`'s default GIL switch interval, seconds (Python's is 5 ms).
#: NumPy drops the GIL in loops over more than a few hundred elements and must take it back;
#: with other threads runnable (the GPU thread, the pool's hand-off threads, the executor)
#: each re-take waits up to the interval: on the H100 host the chain waited for the GIL ~82%
#: of its wall time. Measured there (mono, B=16, FPS), interleaved, a fresh process per run:
#: 5 ms 226 / 232 / 249, 0.2 ms 247 / 233 / 251
#: (benchmarks/results/orbslam/h100-2026-11-24-s5/switch-interval-ab.md).
SWITCH_INTERVAL = 2e-4


@contextlib.contextmanager
def switch_interval(seconds: float | None):
    """``sys.setswitchinterval(seconds)`` inside the block, the caller's interval restored on
    exit (an error included); None: left as it is. Process-global state: every thread of the
    process switches at this interval meanwhile."""
    if seconds is None:
        yield
        return
    before = sys.getswitchinterval()
    sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


# --------------------------------------------------------------------------- the nodes


def orb_batch(images, *, config):
    """``images`` uint8 [B', H, W] -> (feats, packed) (CPU): feats a list of B' (Keypoints,
    uint8 [N_i, 32]); packed the same list (see :func:`orb_batch_warp`)."""
    import warpvx

    feats = warpvx.orb(np.asarray(images), **config.orb_args(), backend="cpu")
    return feats, feats


def orb_batch_warp(images, *, config):
    """:func:`orb_batch` on the device (one launch set for the batch); packed is
    :func:`pack_feats`' (what the CPU nodes read)."""
    import warpvx

    feats = warpvx.orb(images, **config.orb_args())
    return feats, pack_feats(feats)


def pack_feats(feats):
    """Device features -> (fields, descriptors, counts): each keypoint field (:data:`FIELDS`
    order) and the descriptors of all the batch's frames joined on the device, and the frames'
    keypoint counts. A CPU node then downloads 7 arrays instead of 7 per frame: each download
    is a stream sync that hands the GIL over, and the tracking chain shares that GIL.
    :func:`unpack_feats` splits them again."""
    from ..kernels_warp.orb_stages import concatenate

    return (tuple(concatenate([getattr(k, f) for k, _ in feats]) for f in FIELDS),
            concatenate([d for _, d in feats]), tuple(int(d.shape[0]) for _, d in feats))


def unpack_feats(packed) -> list:
    """:func:`pack_feats`' value on the host -> the list of (Keypoints, uint8 [N_i, 32]) per
    frame (views); a list (:func:`orb_batch`'s) as it is."""
    if isinstance(packed, list):
        return packed
    fields, desc, counts = packed
    ends = np.cumsum(counts, dtype=np.int64)
    # Cuts of validated keypoints' fields: not validated again (as the runtime moves them).
    return [(Keypoints.__warpvx_unflatten__(None, tuple(a[e - n:e] for a in fields)), desc[e - n:e])
            for n, e in zip(counts, ends)]


def _left(feats, frames):
    """The left images' descriptors (stereo batches put the right images after the left)."""
    return [d for _, d in feats[:frames]]


def match_batch(feats, before, *, frames):
    """The ``frames`` left frames' descriptors after ``before`` (the previous batch's last),
    each matched both ways to the next: :func:`~warpvx.apps.orbslam_match.nearest_batch`'s
    (last descriptors, (nearest, distance, starts))."""
    return nearest_batch(_left(feats, frames), before)


def match_batch_warp(feats, before, *, frames):
    """:func:`match_batch` on the device (no host sync)."""
    return nearest_batch_warp(_left(feats, frames), before)


#: :func:`pose_batch`'s ``tail`` before the first batch: no frame.
NO_TAIL = (np.zeros((0, 2)), np.zeros(0), None, None)


def pose_batch(images, feats, nearest, tail, *, K, config, baseline, frames, pool):
    """The state-free tracking work of a batch (CPU, fanned out to ``pool``): per frame the
    mutual pairs to the previous frame and, for a stereo camera, each keypoint's stereo depth;
    else the essential core of the filtered matches to the previous frame (:func:`frame_job`)
    and, on a pool with ``ahead`` and ``keyframe_motion`` on, the one to the frame before it
    as the keyframe (:func:`guess_job`, after the batch's frame jobs: the chain waits for
    those first). Speculating so (on a pool with ``ahead``, mono, ``keyframe_motion`` on),
    only a run's first :data:`~warpvx.apps.orbslam_speculate.COVERED` frames get both
    cores, not knowing which one ``track`` takes (the keyframes are the chain's state); the
    other frames' jobs leave the core out and the chain's speculation
    (:class:`~warpvx.apps.orbslam_speculate.CoreSpeculation`) starts the one it will take (as the
    previous batch's chain nears its end, for a batch's first frames). Each is one job:
    the calling thread only slices the batch, so the pose work holds the GIL of the process
    that runs the tracking for none of it.

    Parameters
    ----------
    images : uint8 [B', H, W]
        The batch (stereo: B left images, then B right ones).
    feats : list of B' (Keypoints, uint8 [N, 32]), or :func:`pack_feats`' value
    nearest : (nearest, distance, starts)
        :func:`match_batch`'s second output.
    tail : tuple (float64 [N, 2] points, float64 [N] angles, before, ahead)
        The previous batch's last frame and ``before``, its (nearest, points, angles) of the
        frame before it (None: none), and the previous batch's ``ahead`` (None: none; its
        ``next`` becomes this one's); :data:`NO_TAIL` before the first batch.

    Returns
    -------
    tail : the last frame's (points, angles, before), and ``ahead``
    ahead : the pool's results, still running: :func:`ahead_frames` waits for them; its
        ``guesses``: per frame the pending :func:`guess_job` or None.
    """
    feats = unpack_feats(feats)
    prev_pts, prev_angles, before, previous = tail
    # After a batch, the chain's speculation starts this one's first cores as it ends that one
    # (CoreSpeculation): none covered here.
    covering = COVERED if previous is None else 0
    fx = float(K[0, 0])
    # The guesses only pay on a pool (without one the chain computes what it needs).
    guessing = pool is not None and pool.ahead and baseline is None and config.keyframe_motion
    jobs, fns, guesses, points = [], [], [], [None] * frames
    for f, (kps, desc) in enumerate(feats[:frames], 1):
        pts, angles = points[f - 1] = o.keypoint_xy(kps)
        stereo = None
        if baseline is not None:
            kr, dr = feats[frames + f - 1]
            stereo = (kps, desc, kr, dr, images[f - 1], images[frames + f - 1], fx, baseline)
        near = batch_pairs(*nearest, f)
        covered = not guessing or f <= covering
        jobs.append((near, pts, angles, prev_pts, prev_angles, K, config, stereo) if covered else
                    (near, pts, angles, prev_pts, prev_angles, config, before))
        fns.append(frame_job if covered else pairs_job)
        guesses.append(None if before is None or not guessing or not covered else (
            before, near, pts, angles, prev_pts, prev_angles, K, config))
        before = (near, prev_pts, prev_angles)
        prev_pts, prev_angles = pts, angles
    ahead = _Later(pool, fns, jobs, guesses if guessing else (), points,
                   start=0 if previous is None else previous.start + frames)
    if previous is not None:
        previous.next = ahead
    return (prev_pts, prev_angles, before, ahead), ahead


def _good(nearest, pts, angles, prev_pts, prev_angles, config):
    """(pairs int32 [M, 2], distances int32 [M], good int [G, 2]): the mutual pairs of
    :func:`~warpvx.apps.orbslam_match.batch_pairs`' ``nearest`` and those ``track``'s match
    filter keeps."""
    p, d = mutual_pairs(*nearest, len(pts), len(prev_pts))
    return p, d, o.filter_matches(p, d, angles, prev_angles, config) if len(pts) else p[:0]


def frame_job(nearest, pts, angles, prev_pts, prev_angles, K, config, stereo):
    """One frame's state-free work (on a pool process): (pairs int32 [M, 2], distances int32
    [M], extra, good int [G, 2]: the pairs ``track``'s match filter keeps, handed to it).
    ``nearest``: :func:`~warpvx.apps.orbslam_match.batch_pairs`' (nearest,
    distance, back); ``stereo``: None (monocular), or (left keypoints, left descriptors, right
    keypoints, right descriptors, left image, right image, fx, baseline). ``extra``: stereo,
    the depth float32 [N] of each keypoint (:func:`stereo_depth`); monocular, (p1, p2,
    :func:`~warpvx.apps.orbslam.essential_core`'s result) for the filtered matches to the
    previous frame, what ``track`` hands to it when that frame is the reference, or None when
    ``track`` will not need one."""
    p, d, good = _good(nearest, pts, angles, prev_pts, prev_angles, config)
    if stereo is not None:
        kl, dl, kr, dr, left, right, fx, baseline = stereo
        return p, d, stereo_depth(kl, dl, kr, dr, left, right, fx=fx, baseline=baseline,
                                  scale_factor=config.scale_factor, max_distance=config.stereo_max_distance), good
    return p, d, _core_ahead(prev_pts, pts, good, K, config), good


def pairs_job(nearest, pts, angles, prev_pts, prev_angles, config, before):
    """Monocular (on a pool process): :func:`frame_job`'s value without the core (the chain's
    :class:`~warpvx.apps.orbslam_speculate.CoreSpeculation` starts the one ``track``
    takes), and (two, points, two's points) for that speculation, so that it need not work
    them out in the chain's thread: ``two``, :func:`guess_job`'s second value (the tracks with
    the frame before the previous one as the keyframe, common), or None (``before`` None: no
    such frame); ``points``, :func:`_essential_points`' (p1, p2) of the matches to the previous
    frame; ``two's points``, those of the pairs to that keyframe. Arguments as
    :func:`guess_job`'s."""
    p, d, good = _good(nearest, pts, angles, prev_pts, prev_angles, config)
    two = two_points = None
    if before is not None:
        kf_pts, kf_good, two = _two_back(before, pts, good, prev_pts, prev_angles, config)
        two_points = _essential_points(kf_pts, pts, kf_good, config)
    return p, d, None, good, (two, _essential_points(prev_pts, pts, good, config), two_points)


def guess_job(before, nearest, pts, angles, prev_pts, prev_angles, K, config):
    """Monocular (on a pool process): (ahead, (kf_index, tracks)) for the frame before the
    previous one as the keyframe. ``ahead``: (p1, p2, essential core) for the motion ``track``
    takes from it, or None (``track`` would not ask for one). That is the core it asks for
    right after a keyframe change, and keyframes two frames apart are common (the inliers drop
    there). ``kf_index`` int [N']: the previous frame's keyframe keypoints, tracked from it;
    ``tracks``: :func:`~warpvx.apps.orbslam.keyframe_pairs`' result for this frame from them.
    ``before``: the previous frame's (nearest, points, angles of that frame); the rest as
    :func:`frame_job`'s."""
    good = _good(nearest, pts, angles, prev_pts, prev_angles, config)[2]
    kf_pts, kf_good, tracks = _two_back(before, pts, good, prev_pts, prev_angles, config)
    return _core_ahead(kf_pts, pts, kf_good, K, config), tracks


def _two_back(before, pts, good, prev_pts, prev_angles, config):
    """(keyframe points, its pairs or None, (kf_index, tracks)) for :func:`guess_job` (see
    there), ``good`` this frame's filtered matches."""
    near, kf_pts, kf_angles = before
    prev_good = _good(near, prev_pts, prev_angles, kf_pts, kf_angles, config)[2]
    cursor = _track_step(kf_pts, _keyframe_cursor(kf_pts), prev_pts, prev_good, config)[1]
    kf_good, _, tracked = _track_step(kf_pts, cursor, pts, good, config)
    return kf_pts, kf_good, (cursor[1], (tracked, kf_good))


def ahead_frames(ahead) -> list:
    """:func:`pose_batch`'s ``ahead`` per frame, once the pool's work is done: (pairs,
    distances, extra, good) as :func:`frame_job` returns them (:func:`pairs_job`: and what
    the chain's speculation takes)."""
    return ahead.get()


def chain(state, feats, ahead, *, K, config, baseline, frames, pool=None):
    """Track the batch's frames in order (:func:`~warpvx.apps.orbslam.track`, cheap with the
    work done ahead; monocular, the cores ``track`` takes speculated on ``pool``, see
    :class:`~warpvx.apps.orbslam_speculate.CoreSpeculation`, and ``ahead``'s guesses: one
    used when the keyframe is two frames back, dropped unstarted once it cannot be): (state,
    poses float64 [B, 4, 4], stats float64 [B, 6])."""
    feats = unpack_feats(feats)  # (packed, or a list)
    poses, stats = [], []
    per_frame = ahead_frames(ahead)
    guesses = ahead.guesses if pool is not None else [None] * frames
    points = ahead.points
    if baseline is None:
        pts = [xy for xy, _ in points]
        spec = CoreSpeculation(ahead, pool, K, config)
    for f, ((kps, desc), (pairs, dist, extra, kept, *_)) in enumerate(zip(feats[:frames], per_frame)):
        if baseline is not None:
            state, pose, st = o.track(state, kps, desc, pairs, dist, extra, K=K, config=config, good=kept,
                                      points=points[f])
        else:
            now = None if state.keyframe is None else state.keyframe.index
            spec.ahead(f, state)
            # The guesses for the keyframe two frames back: this frame's needed only if it is
            # so; the next frame's only if the previous frame is the keyframe.
            guess = guesses[f] if now is not None and now == state.frames - 2 else None
            for u, need in ((f, guess is not None), (f + 1, now is not None and now == state.frames - 1)):
                if u < frames and guesses[u] is not None and not need:
                    guesses[u].cancel()
            # The points of the core to the previous frame worked out ahead (the pool took them
            # from the previous batch's points at f = 0: not these very arrays, computed again).
            previous = None if f == 0 or extra is None else (pts[f - 1], pts[f], kept, *extra[:2])
            state, pose, st = o.track(state, kps, desc, pairs, dist, K=K, config=config, good=kept, points=points[f],
                                      essential=_essential_ahead(extra, spec.core(f), pool=pool, guess=guess),
                                      tracks=_tracks_ahead(pts[f], kept, spec.tracked(f),
                                                           _guessed_tracks(guesses[f], pts, f)),
                                      parallax=_parallax_ahead(spec.known(f), previous))
        poses.append(pose)
        stats.append(st)
    if baseline is None:
        spec.hand_over()
    return state, np.asarray(poses), np.asarray(stats)


# --------------------------------------------------------------------------- the graph


def add_extract_match(g, images, batch: int, config: o.TrackerConfig, *, target=None):
    """Add ``orb_batch`` and ``match_batch`` to graph ``g`` for ``images`` (a data object of
    uint8 [B', H, W], the first ``batch`` the left frames); returns the data objects (feats,
    packed, nearest): CPU nodes read packed (:func:`unpack_feats`), the device one feats. ``target="gpu"`` makes both GPU-only nodes (calibration then never times a
    batch's extraction on the CPU); None: both implementations, placed by the scheduler."""
    cpu = target is None
    feats, packed = g.user(functools.partial(orb_batch, config=config) if cpu else None, [images],
                           ["feats", "packed"],
                   warp_fn=functools.partial(orb_batch_warp, config=config), name="orb_batch",
                   target=target)
    last_desc = g.virtual("last_desc")
    # Before the first batch: no rows (pose_batch pairs nothing with them: its tail is empty).
    before = g.delay(last_desc, init=np.zeros((0, 32), np.uint8))[-1]
    _, nearest = g.user(functools.partial(match_batch, frames=batch) if cpu else None, [feats, before],
                        [last_desc, "nearest"], warp_fn=functools.partial(match_batch_warp, frames=batch),
                        name="match_batch", target=target)
    return feats, packed, nearest


def build_batch_graph(camera: o.Camera, batch: int, config: o.TrackerConfig = o.TrackerConfig(), *,
                      backend="cpu", pool=None):
    """The batched front-end graph for ``batch`` gray uint8 frames of ``camera.size`` per
    graph frame: input ``images`` uint8 [B, H, W] (stereo [2B, H, W]: the left images, then the
    right ones); outputs ``poses`` float64 [B, 4, 4] (camera to world) and ``stats`` float64
    [B, 6] (see :func:`~warpvx.apps.orbslam.track`). ``pool``: :func:`make_pool`'s, or None
    (pose work in the node's thread); a :class:`~warpvx.apps.orbslam_chain.ChainProcess`: the
    pose work and the chain there, ``pose_batch`` and ``chain`` only hand batches over and
    take the poses back (:func:`~warpvx.apps.orbslam_chain.send_batch`,
    :func:`~warpvx.apps.orbslam_chain.receive_batch`). ``backend`` as in
    :func:`~warpvx.apps.orbslam.build_graph`. Needs ``cross_check`` and no ``ratio`` (the
    defaults: the match node's mutual pairs)."""
    from ..check import check_choice, check_int
    from ..graph import Graph

    check_choice(backend, "backend", o.BACKENDS)
    batch = check_int(batch, "batch", min_value=1)
    if not config.cross_check or config.ratio is not None:
        raise WarpvxValueError("config: the batched front end matches with cross_check and no ratio "
                               "(run the sequential one, batch 1, for a ratio test)")
    w, h = camera.size
    pin = None if backend == "cpu" else "gpu"
    K = np.ascontiguousarray(camera.K, np.float64)
    common = dict(K=K, config=config, baseline=camera.baseline,
                  frames=batch)
    g = Graph("orbslam_batch")
    images = g.input("images", shape=(batch * (2 if camera.stereo else 1), h, w), dtype=np.uint8)
    _, packed, nearest = add_extract_match(g, images, batch, config, target=pin)
    if isinstance(pool, ChainProcess):
        # The tracking in the chain process: the nodes hand batches over and take poses back.
        sent = g.virtual("sent")
        _, ticket = g.user(functools.partial(send_batch, proc=pool, **common),
                           [images, packed, nearest, g.delay(sent, init=0)[-1]], [sent, "ticket"], name="pose_batch")
        poses, stats = g.user(functools.partial(receive_batch, proc=pool), [ticket], ["poses", "stats"], name="chain")
        g.output("poses", poses)
        g.output("stats", stats)
        return g
    tail = g.virtual("tail")
    last = g.delay(tail, init=NO_TAIL)[-1]
    _, ahead = g.user(functools.partial(pose_batch, pool=pool, **common), [images, packed, nearest, last],
                      [tail, "ahead"], name="pose_batch")
    state = g.virtual("state")
    previous = g.delay(state, init=o.TrackState())[-1]
    _, poses, stats = g.user(functools.partial(chain, pool=pool, **common), [previous, packed, ahead],
                             [state, "poses", "stats"], name="chain")
    g.output("poses", poses)
    g.output("stats", stats)
    return g


def _batches(frames, batch: int, stereo: bool):
    """Stack ``frames`` (input dicts) into graph inputs of ``batch`` frames; the last batch is
    filled up by repeating its last frame. Yields (inputs, number of real frames)."""
    chunk = []

    def stacked(items):
        images = [f["image"] for f in items] + ([f["right"] for f in items] if stereo else [])
        return {"images": np.stack(images)}

    for f in frames:
        chunk.append(f)
        if len(chunk) == batch:
            yield stacked(chunk), batch
            chunk = []
    if chunk:
        yield stacked(chunk + chunk[-1:] * (batch - len(chunk))), len(chunk)


#: Verified graphs an open pool keeps (:func:`track_frames_batched`; each holds a batch's samples).
KEEP_GRAPHS = 4


def track_frames_batched(frames, camera: o.Camera, config: o.TrackerConfig = o.TrackerConfig(), *,
                         batch: int = 16, workers: int | None = None, pool=None, backend="cpu",
                         depth: int = 2, on_finish=None, gil_switch_s: float | None = SWITCH_INTERVAL,
                         chain_process: bool = True, nice: int = 0):
    """:func:`~warpvx.apps.orbslam.track_frames` in batches of ``batch`` frames
    (:func:`build_batch_graph`), with ``workers`` processes for the pose work (default: see
    :func:`make_pool`; 0: none; ``nice``: their niceness increment, see :func:`make_pool`),
    or an open ``pool`` (:func:`make_pool`'s, kept open; ``nice`` then 0: the pool's were
    set there). The tracking chain (and the pose work) in a process of its own when ``chain_process`` (the
    default, on POSIX; see :mod:`warpvx.apps.orbslam_chain`), else in this one; an open
    ``pool`` decides by its kind (a :class:`~warpvx.apps.orbslam_chain.ChainProcess`: there). A
    generator of :class:`~warpvx.apps.orbslam.TrackedFrame` in order; a
    frame's ``ms`` is its batch's interval divided by the batch's frames. ``depth`` batches in
    flight; ``on_finish(plan)`` as in ``track_frames``. An open ``pool`` keeps a run's verified
    graph (its ``graphs``) once the run is through: the next run with the same camera, batch,
    config and backend neither builds nor verifies one (it is reset; its inputs are checked
    by the stream, as always).

    ``gil_switch_s``: the GIL switch interval (seconds, > 0) while the generator runs, from
    its first frame until it is exhausted or closed (default :data:`SWITCH_INTERVAL`; None:
    the caller's). It is process-global: the caller's threads, and the caller's own code
    between two frames, run with it too; the caller's interval is restored on exit, an
    error's included (see :func:`switch_interval`)."""
    from ..check import check_bool, check_float, check_int

    batch = check_int(batch, "batch", min_value=1)
    chain_process = check_bool(chain_process, "chain_process")
    nice = check_int(nice, "nice", min_value=0, max_value=19)
    if nice and pool is not None:
        raise WarpvxValueError("nice: sets the priority of the pose processes this call opens; "
                               "the open pool's were set by make_pool(nice=...)")
    if gil_switch_s is not None:
        gil_switch_s = check_float(gil_switch_s, "gil_switch_s", min_value=0.0, strict_min=True)
    batches = _batches(frames, batch, camera.stereo)
    first = next(batches, None)
    if first is None:
        raise WarpvxValueError("frames: the sequence has no frames")
    with switch_interval(gil_switch_s):
        own = pool is None
        if own:
            pool = make_pool(workers, chain_process=chain_process, nice=nice)
        try:
            # An open pool's graph of an earlier run with these settings, verified: taken (a run
            # beside this one builds its own), reset, and given back once this run is through.
            kept = {} if own else getattr(pool, "graphs", {})
            key = (camera.K.tobytes(), camera.size, camera.baseline, batch, config, backend)
            g = kept.pop(key, None)
            if g is None:
                g = build_batch_graph(camera, batch, config, backend=backend, pool=pool)
                # A chain process answers the verification's batches dry, and starts the real
                # work of the first one meanwhile: the stream's first takes it (ChainProcess.dry_run).
                with pool.dry_run(prime=True) if isinstance(pool, ChainProcess) else contextlib.nullcontext():
                    g.verify(first[0], gpu=None if backend == "cpu" else backend)
            else:
                g.reset()
            plan = o.schedule(g, backend)
            counts = [first[1]]

            def feed():
                yield first[0]
                for inputs, n in batches:
                    counts.append(n)
                    yield inputs

            k, t = 0, time.perf_counter()
            with g:
                for i, out in enumerate(g.stream(feed(), depth=depth)):
                    now = time.perf_counter()
                    n = counts[i]
                    for pose, st in zip(out["poses"][:n], out["stats"][:n]):
                        yield o.TrackedFrame(k, pose, dict(zip(o.STATS, st.tolist())), 1e3 * (now - t) / n)
                        k += 1
                    t = now
                if on_finish is not None:
                    on_finish(plan)
            kept[key] = g
            while len(kept) > KEEP_GRAPHS:
                del kept[next(iter(kept))]  # the least recently run
        finally:
            if own and pool is not None:
                pool.shutdown(cancel_futures=True)


__all__ = ["PosePool", "ChainProcess", "make_pool", "default_workers", "SPARE_CORES", "pack_feats", "unpack_feats",
           "ahead_frames", "orb_batch", "match_batch", "pose_batch", "chain", "add_extract_match", "build_batch_graph",
           "track_frames_batched", "switch_interval", "SWITCH_INTERVAL"]
