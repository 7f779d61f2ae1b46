"""The monocular tracking chain's look-ahead in the batched ORB-SLAM2 front end
(:mod:`warpvx.apps.orbslam_batch`): what ``track`` will ask for, worked out or started on the
pose pool before the chain reaches a frame, and the stand-ins through which ``track`` takes
it (:func:`_essential_ahead`, :func:`_tracks_ahead`, :func:`_parallax_ahead`): each returns
what was worked out ahead only for the very inputs it was worked out for, and computes
anything else, so the poses are the sequential tracker's whatever was speculated.

:class:`CoreSpeculation` walks the batch ahead of the chain as ``track`` decides (the
keyframe's tracks, the parallax comparison, the keyframe decision) and starts the one
essential core each frame will take. Split from :mod:`~warpvx.apps.orbslam_batch`, which
imports these names.
"""

from __future__ import annotations

import dataclasses
import itertools
import time

import numpy as np

from . import orbslam as o
from .orbslam_pool import PoolTask, check_look_ahead


def _keyframe_cursor(kf_pts):
    """:func:`_track_step`'s cursor at a keyframe with points ``kf_pts``."""
    return kf_pts, np.arange(len(kf_pts)), True


def _track_step(kf_pts, cursor, pts, good, config):
    """One frame along the keyframe's tracks, as ``track`` takes it when the keyframe stays:
    ``cursor`` = (previous frame's points, its keypoints' keyframe keypoint (-1 none), whether
    it is the keyframe); ``pts``, ``good``: this frame's points and filtered matches to the
    previous frame. Returns (pairs int [M, 2] to the keyframe when ``track`` takes the motion
    from it, else None (:func:`~warpvx.apps.orbslam.keyframe_pairs`); this frame's cursor;
    the tracked keyframe keypoint int [G] of each pair of ``good``)."""
    tracked, kf_good = o.keyframe_pairs(kf_pts, *cursor, pts, good, config)
    return kf_good, _cursor(pts, good, tracked), tracked


def _cursor(pts, good, tracked):
    """:func:`_track_step`'s cursor after a frame (not the keyframe) with points ``pts``,
    whose filtered matches ``good`` track keyframe keypoints ``tracked``."""
    kf_index = np.full(len(pts), -1)
    kf_index[good[:, 0]] = tracked
    return pts, kf_index, False


def _essential_points(ref_pts, pts, pairs, config):
    """(p1, p2) for ``pairs`` (this frame's index, the reference's): what ``track`` hands to
    :func:`~warpvx.apps.orbslam.essential_core` for that reference, or None when it will not
    call it (none, too few pairs, too little parallax)."""
    if pairs is None or len(pairs) < 8:
        return None
    p1, p2, moved = o.parallax_points(ref_pts, pts, pairs, config)
    return (p1, p2) if moved else None


def _core_ahead(ref_pts, pts, pairs, K, config):
    """(p1, p2, essential core) of :func:`_essential_points`, or None."""
    points = _essential_points(ref_pts, pts, pairs, config)
    return None if points is None else (*points, o.essential_core(*points, K, config))


def _essential_ahead(*cores, pool=None, guess=None):
    """An ``essential`` for :func:`~warpvx.apps.orbslam.track`: a core = (p1, p2, result)
    worked out ahead (the result may be a :class:`PoolTask`, waited for on ``pool``) is
    returned for those very points, as is ``guess``'s (a pending ``guess_job``, see
    :mod:`~warpvx.apps.orbslam_batch`: waited for only when no core matches); anything else
    is computed (a speculation's miss: counted on ``pool`` as ``started["on the spot"]``, its
    time as ``waited_s["on the spot"]``)."""

    def guessed():
        # (Cancelled: the chain ruled it out; track then asks for another keyframe's core.)
        yield None if guess is None or guess.cancelled else pool.wait(guess, "keyframe")[0]

    def essential(p1, p2, K, config):
        for core in itertools.chain(cores, guessed()):
            if core is not None and _same(p1, core[0]) and _same(p2, core[1]):
                return pool.wait(core[2], "keyframe") if isinstance(core[2], PoolTask) else core[2]
        t = time.perf_counter()
        try:
            return o.essential_core(p1, p2, K, config)
        finally:
            if pool is not None:
                pool.waited_s["on the spot"] += time.perf_counter() - t
                pool.started["on the spot"] += 1

    return essential


def _same(a, b) -> bool:
    """``np.array_equal`` of two float arrays, without its argument handling (the chain
    compares a frame's points with each core worked out ahead; often the very arrays)."""
    return a is b or (a.shape == b.shape and bool((a == b).all()))


def _parallax_ahead(*known):
    """A ``parallax`` for :func:`~warpvx.apps.orbslam.track`: for each of ``known`` = (reference
    points, this frame's points, pairs, p1, p2), :func:`~warpvx.apps.orbslam.parallax_points`'
    result worked out ahead for those very arrays (moved: the cores are worked out only then),
    the points of a core; anything else (None entries skipped) is computed."""

    def parallax(ref_pts, cur_pts, pairs, config):
        for k in known:
            if k is not None and ref_pts is k[0] and cur_pts is k[1] and pairs is k[2]:
                return k[3], k[4], True
        return o.parallax_points(ref_pts, cur_pts, pairs, config)

    return parallax


def _tracks_ahead(cur_pts, good, *known):
    """A ``tracks`` for :func:`~warpvx.apps.orbslam.track` at a frame with points ``cur_pts``
    and filtered matches ``good`` (the very arrays track gets): for each of ``known`` = (keyframe
    points, previous frame's points, its keyframe keypoints, whether it is the keyframe,
    result), the :func:`~warpvx.apps.orbslam.keyframe_pairs` result worked out ahead when
    ``track`` asks with those inputs (the same frames' arrays, the keypoints equal: none lost
    since); anything else (None entries skipped) is computed."""

    def tracks(kf_pts, prev_pts, prev_kf_index, prev_is_kf, pts, pairs, config):
        if pts is cur_pts and pairs is good:
            for k in known:
                if (k is not None and kf_pts is k[0] and prev_pts is k[1] and prev_is_kf == k[3]
                        and _same(prev_kf_index, k[2])):
                    return k[4]
        return o.keyframe_pairs(kf_pts, prev_pts, prev_kf_index, prev_is_kf, pts, pairs, config)

    return tracks


def _guessed_tracks(guess, pts, f):
    """:func:`_tracks_ahead`'s entry for frame ``f`` from its ``guess_job`` (the frame two
    back as the keyframe) when that has finished (never waited for: the chain computes them
    sooner), else None; ``pts``: the batch's points per frame."""
    if f < 2 or guess is None or not guess.ready():
        return None
    kf_index, result = guess.get()[1]
    return pts[f - 2], pts[f - 1], kf_index, False, result


def _essential_job(p1, p2, K, config):
    """:func:`~warpvx.apps.orbslam.essential_core` on a pool process (looked up there)."""
    return o.essential_core(p1, p2, K, config)


#: Frames ahead of the chain whose cores :class:`CoreSpeculation` keeps started, at least
#: (:func:`look_ahead`): ~ a core's latency (one process: ~14 ms on the H100 host) over the
#: chain's time per frame (~3 ms there in session 7).
SPECULATE_AHEAD = 6
#: :func:`look_ahead`'s most frames by default: a batch's (the walk past it waits for the next
#: batch's frame jobs).
MAX_LOOK_AHEAD = 16


def look_ahead(pool) -> int:
    """Frames ahead of the chain whose cores :class:`CoreSpeculation` keeps started on
    ``pool``: its ``look_ahead`` when set, else one per process but one (that one left to the
    next batch's frame jobs, which the walk into that batch waits for), between
    :data:`SPECULATE_AHEAD` and :data:`MAX_LOOK_AHEAD`. The chain waits for a core when the
    look-ahead is shorter than the core's latency over the chain's own time per frame: on
    the H100 host ~14 ms over ~1.4 ms (session 8, 6 frames: 14 ms waited per batch of 16)."""
    if pool.look_ahead is not None:
        return check_look_ahead(pool.look_ahead)  # (an attribute: may have been set since)
    return min(MAX_LOOK_AHEAD, max(SPECULATE_AHEAD, pool.workers - 1))

#: A run's first frames whose cores ``pose_batch`` works out for both references ``track``
#: may take (its ``frame_job`` and ``guess_job``, :mod:`~warpvx.apps.orbslam_batch`): no chain
#: before them starts their cores ahead, and the first chain could start them only a core's
#: latency before it needs the first.
COVERED = SPECULATE_AHEAD
#: The inlier fraction of a core :class:`CoreSpeculation` assumes before it has seen one.
INLIER_FRACTION = 0.5


def _job(per_frame):
    """A frame job's value -> what its ``pairs_job`` worked out for the walk (tracks with the
    keyframe two frames back, points to the previous frame, points to that keyframe), or None
    (a ``frame_job``'s)."""
    return per_frame[4] if len(per_frame) > 4 else None


@dataclasses.dataclass
class _Walked:
    """One frame of :class:`CoreSpeculation`'s walk: the keyframe it assumes (points, index),
    the cursor before the frame and after it (see :func:`_track_step`), keyframe_pairs'
    result, the parallax look-up (reference points, points, pairs, p1, p2; None: no core),
    the core (p1, p2, PoolTask or value; None: none, or the frame's guess_job has it),
    the pairs' count, and the keyframe decision taken."""

    kf_pts: np.ndarray
    kf_index: int
    cursor: tuple
    after: tuple
    result: tuple
    known: tuple | None
    core: tuple | None
    guess: object
    n: int
    is_kf: bool | None = None


class CoreSpeculation:
    """Monocular: the essential core ``track`` will take for each frame (to the previous
    frame or to the keyframe), started on ``pool`` (needed at that frame) :func:`look_ahead` frames
    before the chain reaches the frame, and only that one.

    Which reference ``track`` takes depends on the keyframe, the chain's state. The
    speculation walks the batch's frames ahead of the chain as ``track`` does, on the cheap
    parts: the keyframe's tracks composed from the frames' filtered matches, the parallax
    comparison (:func:`~warpvx.apps.orbslam.keyframe_pairs`), the points of the chosen
    reference's core, and the keyframe decision: ``track``'s own rule on the core's inlier
    count once the pool has it, else on the pairs' count times the inlier fraction last seen
    for that reference (a keyframe comes where the inliers drop under ``keyframe_ratio`` of
    those after the last keyframe: on the rendered sequences, a drop to ~45% against ~100%
    otherwise). At each frame the walk is checked again against the chain's state and the
    cores that came in: from the first decision that differs it walks on anew, and what it no longer reaches
    is cancelled if not started. A frame lost (or a scale jump: the depths are the chain's)
    stops it until the chain has tracked past. Near the batch's end it walks on into the next
    batch, each frame once its frame job (and those before it) is done, and :meth:`hand_over` gives that batch's
    speculation what it started; the cores of a run's first :data:`COVERED` frames are
    ``pose_batch``'s (both references). One the chain still lacks it computes on the spot
    (:func:`_essential_ahead`, counted in ``pool.started["on the spot"]``).

    ``ahead``: the batch's :func:`~warpvx.apps.orbslam_batch.pose_batch` result, done (per
    frame: points float64 [N, 2], filtered matches int [G, 2] to the previous frame, the frame
    job's (p1, p2, core) or None, the pending ``guess_job`` or None)."""

    def __init__(self, ahead, pool, K, config):
        per_frame = ahead.get()
        pts, good = [xy for xy, _ in ahead.points], [a[3] for a in per_frame]
        extra = [a[2] for a in per_frame]
        #: Per frame, pairs_job's (tracks with the keyframe two frames back, points to the
        #: previous frame, points to that keyframe), or None (a frame job's).
        self._jobs = [_job(a) for a in per_frame]
        self._args = (pts, good, extra, list(ahead.guesses), pool, K, config)
        self._on = pool is not None and config.keyframe_motion
        self._depth = look_ahead(pool) if self._on else 0
        self._ahead, self._frames, self._next = ahead, len(pts), None
        self._walked, self._started = {}, {}  # frame -> _Walked; frame -> [(p1, p2, PoolTask)]
        # The inlier fraction last seen by reference (keyframe or not): the previous frame's
        # matches hold more outliers than the keyframe's tracks (0.35 against 0.55, slow motion).
        self._frac = {False: INLIER_FRACTION, True: INLIER_FRACTION}
        for e in extra:
            if e is not None and e[2] is not None:
                self._frac[False] = len(e[2][2]) / len(e[0])
        if ahead.handed is not None:  # the previous batch's chain walked into this one
            self._walked, self._started, self._frac = ahead.handed
            ahead.handed = None

    def ahead(self, f, state):
        """Walked up to frame ``f`` + :func:`look_ahead`; ``state``: the chain's before
        frame ``f``."""
        if not self._on:
            return
        kf, prev = state.keyframe, state.previous
        if kf is None or prev is None or state.lost:
            self._drop(f)  # (a re-initialisation: the lost frame may become the keyframe)
            self._prune(f)
            return
        sim = (kf.pts, kf.index, (prev.pts, prev.kf_index, kf.index == prev.index), state.keyframe_inliers)
        step = self._walked.get(f)
        if step is not None and not (step.cursor[2] == sim[2][2] and _same(step.cursor[0], prev.pts)
                                     and _same(step.cursor[1], prev.kf_index)):
            self._drop(f)
        u, g, end = f, state.frames, self._end(f + 1 + self._depth)
        while u in self._walked or u < end:
            step = self._walked.get(u)
            if step is not None and step.kf_index != sim[1]:
                self._drop(u)  # (an earlier decision changed: walked anew)
                continue
            if step is None:
                step = self._walked[u] = self._walk(u, sim, g)
                if step is None:
                    del self._walked[u]
                    break
            decided = self._decide(step, sim, g)
            if decided is None:  # lost: the walk stops there
                self._drop(u + 1)
                break
            sim, is_kf = decided
            if step.is_kf is not None and is_kf != step.is_kf:
                self._drop(u + 1)  # (a core came in: the decision on its inliers differs)
            step.is_kf = is_kf
            sim = (self._args[0][u], g, _keyframe_cursor(self._args[0][u]), 0) if is_kf else \
                (*sim[:2], step.after, sim[3])
            u, g = u + 1, g + 1
        self._prune(f)

    def _end(self, end):
        """``end``, or as far as the frames known: this batch's, then the next batch's (when
        the walk reaches past this one) whose frame jobs are done, each as soon as it and those
        before it are (the chain then starts the next batch's first cores while it tracks this
        one; :meth:`hand_over`)."""
        nxt, pts = self._ahead.next, self._args[0]
        if end > len(pts) and nxt is not None:
            good, extra, guesses = self._args[1:4]
            for k in range(len(pts) - self._frames, min(nxt.done(), end - self._frames)):
                per_frame = nxt.value(k)
                pts.append(nxt.points[k][0])
                good.append(per_frame[3])
                extra.append(per_frame[2])
                self._jobs.append(_job(per_frame))
                guesses.append(nxt.guesses[k])
                self._next = nxt
        return min(end, len(pts))

    def hand_over(self):
        """At the batch's end: the walk into the next batch (its steps and cores) to that
        batch's speculation; the rest cancelled if not started."""
        n, nxt = self._frames, self._next
        if nxt is not None:
            nxt.handed = ({u - n: s for u, s in self._walked.items() if u >= n},
                          {u - n: c for u, c in self._started.items() if u >= n}, self._frac)
            self._started = {u: c for u, c in self._started.items() if u < n}
        self._walked.clear()
        self._prune(n)

    def _walk(self, u, sim, g):
        """Frame ``u``'s step from ``sim`` (keyframe points, index, cursor, inliers after it),
        ``g`` its index in the run; None where ``track`` leaves the cheap path."""
        pts, good, extra, guesses, pool, K, config = self._args
        kf_pts, kf_index, cursor, _ = sim
        job = self._jobs[u]  # (pairs_job's: what it worked out for this step, taken as is)
        two = job is not None and job[0] is not None and kf_index == g - 2 and not cursor[2] \
            and _same(cursor[1], job[0][0])
        if two:
            (tracked, kf_good), after = job[0][1], _cursor(pts[u], good[u], job[0][1][0])
        else:
            kf_good, after, tracked = _track_step(kf_pts, cursor, pts[u], good[u], config)
        if kf_good is not None:
            ref_pts, pairs = kf_pts, kf_good
        elif len(good[u]) < config.min_matches and not cursor[2]:
            return None  # (track matches to the keyframe's descriptors)
        else:
            ref_pts, pairs = cursor[0], good[u]
        if len(pairs) < 8:
            return None
        if job is not None and (two or kf_good is None):
            points = job[2] if two and kf_good is not None else job[1]
        else:
            points = _essential_points(ref_pts, pts[u], pairs, config)
        core = guess = None
        if points is not None:
            if kf_good is not None and kf_index == g - 2 and guesses[u] is not None:
                guess = guesses[u]  # (its guess_job works it out)
            elif extra[u] is not None and _same(extra[u][0], points[0]) and _same(extra[u][1], points[1]):
                core = extra[u]
            else:
                core = next((c for c in self._started.get(u, ()) if _same(c[0], points[0])
                             and _same(c[1], points[1])), None)
                if core is None:
                    core = (*points, pool.submit(_essential_job, *points, K, config, need=g))
                    self._started.setdefault(u, []).append(core)
        known = None if points is None else (ref_pts, pts[u], pairs, *points)
        return _Walked(kf_pts, kf_index, cursor, after, (tracked, kf_good), known, core, guess, len(pairs))

    def _inliers(self, step):
        """The step's inlier count as ``track`` will have it: the core's when in (None: lost),
        else estimated."""
        if step.known is None:
            return step.n  # (no parallax: no core, every pair counts)
        value = None
        if step.guess is not None:
            if step.guess.ready():
                value = step.guess.get()[0]
                value = None if value is None else value[2]
                if value is None:
                    return None
        elif isinstance(step.core[2], PoolTask):
            if step.core[2].ready():
                value = step.core[2].get()
                if value is None:
                    return None
        else:
            value = step.core[2]
            if value is None:
                return None
        from_kf = step.result[1] is not None
        if value is None:
            return round(self._frac[from_kf] * len(step.known[3]))
        self._frac[from_kf] = len(value[2]) / len(step.known[3])
        return len(value[2])

    def _decide(self, step, sim, g):
        """(``sim`` with the inliers after the keyframe, whether frame ``g`` of ``step`` becomes
        the keyframe) as ``track`` decides; None: lost."""
        config = self._args[6]
        inliers = self._inliers(step)
        if inliers is None or inliers < config.min_inliers:
            return None
        kf_inliers = sim[3] or inliers
        return (*sim[:3], kf_inliers), o.keyframe_due(g - sim[1], inliers, kf_inliers, config)

    def _drop(self, u):
        """Forget the walk from frame ``u`` on."""
        for v in [v for v in self._walked if v >= u]:
            del self._walked[v]

    def _prune(self, f):
        """Cancel the started cores the walk no longer takes (from frame ``f`` on) and forget
        those of the frames before."""
        for u in list(self._started):
            step = self._walked.get(u)
            keep = [c for c in self._started[u] if u >= f and step is not None and c is step.core]
            for c in self._started[u]:
                if not keep or c is not keep[0]:
                    c[2].cancel()
            if keep:
                self._started[u] = keep
            else:
                del self._started[u]

    def tracked(self, f):
        """(keyframe points, the previous frame's points, its keyframe keypoints, whether it
        is the keyframe, :func:`~warpvx.apps.orbslam.keyframe_pairs`' result) the walk worked
        out for frame ``f`` (see :func:`_tracks_ahead`), or None."""
        step = self._walked.get(f)
        return None if step is None else (step.kf_pts, *step.cursor, step.result)

    def known(self, f):
        """Frame ``f``'s parallax look-up (see :func:`_parallax_ahead`), or None."""
        step = self._walked.get(f)
        return None if step is None else step.known

    def core(self, f):
        """Frame ``f``'s core started on the pool or worked out by its frame job (p1, p2,
        PoolTask or value), or None."""
        step = self._walked.get(f)
        return None if step is None else step.core


__all__ = ["CoreSpeculation", "look_ahead", "SPECULATE_AHEAD", "MAX_LOOK_AHEAD", "COVERED", "INLIER_FRACTION"]
