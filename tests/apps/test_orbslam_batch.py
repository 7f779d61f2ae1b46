"""The batched ORB-SLAM2 front end (warpvx.apps.orbslam_batch) against the sequential one
(warpvx.apps.orbslam.track_frames) on a rendered sequence with exact poses.

Both run the same per-frame ``track``; the batch only works out the essential matrices (mono)
or stereo depths ahead on worker processes, so the poses must be the sequential ones (OpenCV's
USAC draws from a fixed seed) and the ATE bars those of tests/apps/test_orbslam.py (mono 4 cm
after Sim(3), stereo 1 cm). 12 frames in batches of 5: the last batch is filled up.
"""

from __future__ import annotations

import collections
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from warpvx.apps import orbslam as o
from warpvx.apps import orbslam_batch as ob
from warpvx.apps import orbslam_chain, orbslam_cli
from warpvx.apps import orbslam_pool as op
from warpvx.apps import orbslam_speculate as osp
from warpvx.apps import trajectory_eval as te
from warpvx.apps.orbslam_synth import render_sequence, write_kitti_sequence
from warpvx.errors import WarpvxError

FRAMES, BATCH = 12, 5


@pytest.fixture(scope="module")
def seq():
    """12 rendered stereo frames (640x480, baseline 0.2 m) and their exact poses."""
    left, right, K, poses = render_sequence(FRAMES, (640, 480), baseline=0.2, supersample=1)
    return left, right, K, poses


def _frames(seq, stereo):
    left, right, K, _ = seq
    camera = o.Camera(K, (640, 480), 0.2 if stereo else None)
    return [{"image": a, "right": b} if stereo else {"image": a} for a, b in zip(left, right)], camera


@pytest.fixture(scope="module")
def sequential(seq):
    """stereo (False, True) -> the sequential tracker's poses of ``seq`` (12 x 4 x 4 float64),
    tracked once: the reference every batched run here is compared with."""
    return {stereo: np.array([f.pose for f in o.track_frames(*_frames(seq, stereo))])
            for stereo in (False, True)}


@pytest.mark.parametrize("chain_process", [True, False], ids=["chain_process", "chain_in_process"])
@pytest.mark.parametrize("stereo", [False, True], ids=["mono", "stereo"])
def test_batched_poses_are_the_sequential_ones(seq, sequential, stereo, chain_process):
    frames, camera = _frames(seq, stereo)
    want = sequential[stereo]
    got = list(ob.track_frames_batched(frames, camera, batch=BATCH, workers=2, chain_process=chain_process))
    assert [f.index for f in got] == list(range(FRAMES))
    got = np.array([f.pose for f in got])
    np.testing.assert_allclose(got, want, atol=1e-9)
    bar = 0.01 if stereo else 0.04
    assert te.ate(got, seq[3], with_scale=not stereo)["rmse"] < bar


def test_warp_graph_places_batches_on_the_gpu_role(seq):
    frames, camera = _frames(seq, False)
    plans = []
    got = np.array([f.pose for f in ob.track_frames_batched(frames[:8], camera, batch=4, workers=0,
                                                            backend="warp-cpu", on_finish=plans.append)])
    want = np.array([f.pose for f in o.track_frames(frames[:8], camera, backend="warp-cpu")])
    np.testing.assert_allclose(got, want, atol=1e-9)
    placement = plans[0].placement
    assert placement["orb_batch"] == placement["match_batch"] == "gpu"
    assert placement["pose_batch"] != "gpu" and placement["chain"] != "gpu"


def test_essential_ahead_is_used_only_for_its_own_points(seq):
    """The look-up track() gets: the core worked out ahead for exactly those points (here a
    sentinel, so its use shows), essential_core for any others (the keyframe fallback)."""
    import warpvx

    (k0, d0), (k1, d1) = (warpvx.orb(im, backend="cpu") for im in seq[0][:2])
    pairs, _ = warpvx.match_hamming(d1, d0, True, None, backend="cpu")
    p1, p2 = o.keypoint_xy(k0)[0][pairs[:, 1]], o.keypoint_xy(k1)[0][pairs[:, 0]]
    K, config = np.ascontiguousarray(seq[2], np.float64), o.TrackerConfig()
    sentinel = object()
    essential = osp._essential_ahead((p1, p2, sentinel))
    assert essential(p1.copy(), p2.copy(), K, config) is sentinel
    want = o.essential_core(p1[1:], p2[1:], K, config)
    assert want is not None
    for g, w in zip(essential(p1[1:], p2[1:], K, config), want):
        np.testing.assert_array_equal(g, w)


def test_tracks_and_parallax_ahead_are_used_only_for_their_own_inputs(seq):
    """The look-ups track() gets for keyframe_pairs and parallax_points: the result worked out
    ahead (a sentinel, so its use shows) for exactly those arrays (the keyframe keypoints
    compared by value), the function's own result for any others."""
    import warpvx

    (k0, d0), (k1, d1) = (warpvx.orb(im, backend="cpu") for im in seq[0][:2])
    pairs, _ = warpvx.match_hamming(d1, d0, True, None, backend="cpu")
    kf_pts, pts = o.keypoint_xy(k0)[0], o.keypoint_xy(k1)[0]
    config, kf_index, sentinel = o.TrackerConfig(), np.arange(len(kf_pts)), object()
    # Previous frame = the keyframe (k0): its keypoints track to themselves.
    tracks = osp._tracks_ahead(pts, pairs, (kf_pts, kf_pts, kf_index, False, sentinel))
    assert tracks(kf_pts, kf_pts, kf_index.copy(), False, pts, pairs, config) is sentinel
    for args in ((kf_pts.copy(), kf_pts, kf_index, False, pts, pairs),  # other arrays
                 (kf_pts, kf_pts, kf_index[::-1].copy(), False, pts, pairs),  # other tracks
                 (kf_pts, kf_pts, kf_index, False, pts, pairs.copy())):
        want = o.keyframe_pairs(*args, config)
        for g, w in zip(tracks(*args, config), want):
            np.testing.assert_array_equal(g, w)
    parallax = osp._parallax_ahead(None, (kf_pts, pts, pairs, sentinel, sentinel))
    assert parallax(kf_pts, pts, pairs, config) == (sentinel, sentinel, True)
    for g, w in zip(parallax(kf_pts, pts, pairs.copy(), config), o.parallax_points(kf_pts, pts, pairs, config)):
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("keyframe_motion, guesses", [(True, True), (False, True), (True, False)])
def test_chain_computes_no_essential_matrix_itself(seq, monkeypatch, keyframe_motion, guesses):
    """pose_batch works out every frame's essential matrix to the previous frame ahead (on 2
    processes), and with keyframe_motion on a pool with ``ahead`` the one to the frame before it
    as the keyframe, for the batch's first frames only; chain then tracks the batch with no
    essential_core call of its own (speculating the others on the pool: no miss) and gives
    the sequential poses; with no pool it computes those the pool did not work out."""
    frames, camera = _frames(seq, False)
    config, K = o.TrackerConfig(keyframe_motion=keyframe_motion), np.ascontiguousarray(seq[2], np.float64)
    images = np.stack([f["image"] for f in frames])
    feats = ob.orb_batch(images, config=config)[0]
    last, nearest = ob.match_batch(feats, np.zeros((0, 32), np.uint8), frames=FRAMES)
    np.testing.assert_array_equal(last, feats[-1][1])
    common = dict(K=K, config=config, baseline=None, frames=FRAMES)
    pool = ob.PosePool(2, ahead=guesses)
    try:
        tail, ahead = ob.pose_batch(images, feats, nearest, ob.NO_TAIL, pool=pool, **common)
        per_frame = ob.ahead_frames(ahead)  # waits for the pool's results
        np.testing.assert_array_equal(tail[0], o.keypoint_xy(feats[-1][0])[0])
        # Speculating, only the first COVERED frames' jobs work the core out; the chain
        # starts the later ones' (the one track takes, of the previous frame's or the keyframe's).
        covered = ob.COVERED if keyframe_motion and guesses else FRAMES
        assert sum(a[2] is not None for a in per_frame[:covered]) >= covered - 2  # frame 0 has no previous frame
        assert all(a[2] is None for a in per_frame[covered:])
        calls = []
        core = o.essential_core
        monkeypatch.setattr(o, "essential_core", lambda *a: calls.append(1) or core(*a))
        # Frames tracked from the keyframe (reference 1: which frame that is, is state) take
        # the cores chain speculated on the pool; the others the ones worked out ahead.
        _, poses, stats = ob.chain(o.TrackState(), feats, ahead, pool=pool, **common)
        assert calls == [] and stats.shape == (FRAMES, len(o.STATS))
        if keyframe_motion:
            from_kf = stats[:, 4] == o.REF_KEYFRAME
            assert np.count_nonzero(from_kf) > 0
            # The frames whose keyframe is the one before the previous frame: pose_batch
            # guessed their cores (on a pool with ahead), those of the keyframe's points.
            kf = stats[:, 3] == 1
            guessed = [t for t in range(2, covered) if from_kf[t] and kf[t - 2] and not kf[t - 1]]
            if guesses:
                assert guessed
                for t in guessed:
                    p1, p2, got = ahead.guesses[t].get()[0]
                    assert set(map(tuple, p1)) <= set(map(tuple, o.keypoint_xy(feats[t - 2][0])[0]))
                    for g, w in zip(got, core(p1, p2, K, config)):
                        np.testing.assert_array_equal(g, w)
            else:
                assert ahead.guesses == [None] * FRAMES
            # Without the pool, chain works those out itself, on the spot: the keyframe's, and
            # past the covered frames the previous frame's too.
            _, poses_here, stats = ob.chain(o.TrackState(), feats, ahead, **common)
            later = np.arange(FRAMES) >= covered
            assert len(calls) == np.count_nonzero(from_kf | (later & (stats[:, 4] == o.REF_PREVIOUS)))
            np.testing.assert_array_equal(poses_here, poses)
    finally:
        pool.shutdown()
    np.testing.assert_allclose(poses, [f.pose for f in o.track_frames(frames, camera, config)], atol=1e-9)


def test_slow_motion_takes_the_speculated_keyframe_cores(monkeypatch):
    """Slow motion (0.05 m/frame): keyframes several frames apart, so frames three or more
    after the keyframe take their motion from it; the chain takes those cores from the ones
    it speculated on the pool (computing none itself), the rest as guessed, and the poses
    are the sequential ones."""
    left, _, K, _ = render_sequence(14, (640, 480), step=0.05, speed_var=0.5, seed=5, supersample=1)
    frames, camera = [{"image": im} for im in left], o.Camera(K, (640, 480))
    want = list(o.track_frames(frames, camera))
    stats = np.array([[f.stats[k] for k in o.STATS] for f in want])
    kf = stats[:, 3] == 1
    last_kf = {t: max(k for k in range(t) if kf[k]) for t in range(1, 14)}  # each frame's keyframe
    assert any(stats[t, 4] == o.REF_KEYFRAME and t - last_kf[t] >= 3 for t in last_kf)  # not guessed
    # The cores the chain computes itself, by thread: the graph's verification and calibration
    # run it in the calling thread on samples (a batch's frames after themselves: other
    # keyframes, so guesses it cancels there may be needed in the next timing run); the
    # stream runs it on a worker thread.
    on_the_spot = []

    def essential(*args):
        on_the_spot.append(threading.current_thread() is threading.main_thread())
        return core(*args)

    core = o.essential_core
    monkeypatch.setattr(o, "essential_core", essential)
    with ob.make_pool(2) as pool:
        got = np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=7, pool=pool)])
        assert pool.started["_essential_job"] > 0 and pool.started["guess_job"] > 0
    assert all(on_the_spot)  # none in the stream
    np.testing.assert_allclose(got, [f.pose for f in want], atol=1e-9)


@pytest.mark.parametrize("look_ahead", [None, 1, 16], ids=["from_pool", "one_frame", "past_the_next_batch"])
def test_about_one_essential_matrix_per_frame(seq, sequential, look_ahead):
    """Speculating, the pool works out the essential matrix track takes and not the other
    candidate (before: both, ~2 per frame): only the run's first frames (the first batch here)
    get both, the chain's speculation starts the others' (no miss on this sequence), and the
    poses are the sequential ones, whatever the look-ahead (16: the walk reaches into the
    next batch of 5 as soon as the chain starts a batch)."""
    frames, camera = _frames(seq, False)
    want = sequential[False]
    with ob.make_pool(2, chain_process=True, look_ahead=look_ahead) as proc:
        def run():
            return np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=BATCH, pool=proc)])

        np.testing.assert_array_equal(run(), want)  # (calibrates; the first batch primed in vain)
        # A first run again, calibration cached: its verification is dry but for the first
        # batch, primed there and taken by the stream (not sent twice: its frame jobs once).
        proc.graphs.clear()
        before = proc.started
        got = run()
        started = proc.started - before
    np.testing.assert_array_equal(got, want)
    first, padded = min(BATCH, ob.COVERED), -(-FRAMES // BATCH) * BATCH  # (the last batch filled up)
    assert started["frame_job"] == first and started["pairs_job"] == padded - first
    assert started["on the spot"] == 0
    cores = started["frame_job"] + started["guess_job"] + started["_essential_job"]
    assert cores <= FRAMES + first


@pytest.mark.parametrize("look_ahead, batch", [(None, FRAMES), (16, BATCH)], ids=["one_batch", "deep_across_batches"])
@pytest.mark.parametrize("estimate", [0, 10 ** 6], ids=["always_keyframe", "never_keyframe"])
def test_speculation_misses_give_the_sequential_poses(seq, sequential, monkeypatch, estimate, look_ahead, batch):
    """CoreSpeculation's keyframe decisions wrong whenever they rest on an estimate (every frame
    a keyframe, or none): the cores it starts are the wrong ones, the chain computes the
    right ones on the spot (counted as misses) or takes the speculation's corrections once
    the cores come in, and the poses stay the sequential ones, bit for bit; also with a
    look-ahead past the batch's end (16 frames, batches of 5: the walk goes on into the next
    batch frame by frame and hands it over)."""
    frames, camera = _frames(seq, False)
    want = sequential[False]
    inliers = osp.CoreSpeculation._inliers

    def wrong(self, step):
        n = inliers(self, step)
        exact = step.known is None or (step.guess.ready() if step.guess is not None else
                                       not isinstance(step.core[2], op.PoolTask) or step.core[2].ready())
        return n if exact else estimate

    monkeypatch.setattr(osp.CoreSpeculation, "_inliers", wrong)
    with ob.make_pool(2, look_ahead=look_ahead) as pool:
        got = np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=batch, pool=pool)])
        assert pool.started["on the spot"] > 0 or pool.cancelled["_essential_job"] > 0
    np.testing.assert_array_equal(got, want)


def test_speculation_walks_into_the_next_batch_frame_by_frame(seq, sequential, monkeypatch):
    """With the next batch's frame jobs done one by one (its ``done`` count grows by one per
    look), a look-ahead past the batch's end walks into the next batch a frame at a time,
    starts those frames' cores while the chain is still in this batch and hands them over;
    the poses are the sequential ones, bit for bit."""
    frames, camera = _frames(seq, False)
    want = sequential[False]
    config, K = o.TrackerConfig(), np.ascontiguousarray(seq[2], np.float64)
    common = dict(K=K, config=config, baseline=None, frames=BATCH)
    done, looks, reach = ob._Later.done, collections.Counter(), []

    def one_by_one(self):
        looks[id(self)] += 1
        return min(done(self), looks[id(self)])

    end = osp.CoreSpeculation._end

    def spy(self, until):
        known = end(self, until)
        reach.append(known - self._frames)  # frames of the next batch known to the walk
        return known

    monkeypatch.setattr(ob._Later, "done", one_by_one)
    monkeypatch.setattr(osp.CoreSpeculation, "_end", spy)
    batches = [images for images, _ in ob._batches(frames, BATCH, False)]
    with ob.make_pool(2, look_ahead=2 * BATCH) as pool:
        tail, aheads, feats = ob.NO_TAIL, [], []
        last = np.zeros((0, 32), np.uint8)
        for b in batches:
            feats.append(ob.orb_batch(b["images"], config=config)[0])
            last, nearest = ob.match_batch(feats[-1], last, frames=BATCH)
            tail, ahead = ob.pose_batch(b["images"], feats[-1], nearest, tail, pool=pool, **common)
            aheads.append(ahead)
        for a in aheads:
            ob.ahead_frames(a)  # (all done: the counts above decide what the walk sees)
        state, poses = o.TrackState(), []
        for f, a in zip(feats, aheads):
            state, p, _ = ob.chain(state, f, a, pool=pool, **common)
            poses.append(p)
        assert pool.started["on the spot"] == 0
    assert 0 < min(r for r in reach if r > 0) < BATCH  # a part of the next batch, then more
    np.testing.assert_array_equal(np.concatenate(poses)[:FRAMES], want)


@pytest.mark.parametrize("flags", [[], ["--chain-in-process"]], ids=["chain_process", "chain_in_process"])
def test_cli_batch_flag_end_to_end(tmp_path, seq, capsys, flags, monkeypatch):
    opened = []

    class Spied(orbslam_chain.ChainProcess):
        def __init__(self, *args, **kwargs):
            opened.append(args)
            super().__init__(*args, **kwargs)

    monkeypatch.setattr(orbslam_chain, "ChainProcess", Spied)
    left, right, K, poses = seq
    folder = write_kitti_sequence(tmp_path / "seq", left, K, poses)
    out = tmp_path / "out"
    status = orbslam_cli.main([str(folder), "--gt", str(folder / "poses.txt"), "--out", str(out),
                               "--quiet", "--no-plot", "--batch", str(BATCH), "--pose-workers", "1", *flags])
    assert status == 0, capsys.readouterr().err
    m = json.loads((out / "metrics.json").read_text())
    assert m["batch"] == BATCH and m["frames"] == FRAMES
    assert opened == ([] if flags else [(1,)])
    assert m["warpvx"]["ate"]["rmse"] < 0.04
    assert len((out / "frames.csv").read_text().splitlines()) == FRAMES + 1


def test_bad_input_names_the_argument(seq, tmp_path, capsys):
    frames, camera = _frames(seq, False)
    cases = [(dict(batch=0), "batch"), (dict(batch=2, workers=-1), "workers"),
             (dict(batch=2, config=o.TrackerConfig(ratio=0.8)), "config"),
             (dict(batch=2, backend="gpu"), "backend"), (dict(batch=2, gil_switch_s=0), "gil_switch_s"),
             (dict(batch=2, gil_switch_s=-1e-3), "gil_switch_s"), (dict(batch=2, gil_switch_s="1ms"), "gil_switch_s")]
    for kwargs, name in cases:
        with pytest.raises(WarpvxError, match=name):
            list(ob.track_frames_batched(frames[:3], camera, **{"workers": 0, **kwargs}))
    with pytest.raises(WarpvxError, match="no frames"):
        list(ob.track_frames_batched([], camera, batch=2, workers=0))
    folder = write_kitti_sequence(tmp_path / "seq", seq[0][:3], seq[2], seq[3][:3])
    for flag, value, name in (("--batch", "0", "batch"), ("--gil-switch-ms", "-1", "gil_switch_ms")):
        assert orbslam_cli.main([str(folder), flag, value, "--quiet", "--no-plot",
                                 "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and name in err[0]


def test_switch_interval_is_set_for_the_run_and_the_callers_restored(seq):
    """The run's interval while frames come out; the caller's after the last one, after an
    error in the frames, after the caller stops early; None leaves it alone."""
    import sys

    frames, camera = _frames(seq, False)
    caller, run = 0.003, 0.0007
    saved = sys.getswitchinterval()

    def failing():
        yield from frames[:5]
        raise RuntimeError("camera unplugged")

    try:
        sys.setswitchinterval(caller)
        seen = [sys.getswitchinterval() for _ in ob.track_frames_batched(frames[:6], camera, batch=3, workers=0,
                                                                          gil_switch_s=run)]
        assert seen == pytest.approx([run] * 6) and sys.getswitchinterval() == pytest.approx(caller)
        with pytest.raises(RuntimeError, match="unplugged"):
            list(ob.track_frames_batched(failing(), camera, batch=2, workers=0, gil_switch_s=run))
        assert sys.getswitchinterval() == pytest.approx(caller)
        it = ob.track_frames_batched(frames[:6], camera, batch=2, workers=0, gil_switch_s=run)
        next(it)
        it.close()
        assert sys.getswitchinterval() == pytest.approx(caller)
        seen = [sys.getswitchinterval() for _ in ob.track_frames_batched(frames[:2], camera, batch=2, workers=0,
                                                                          gil_switch_s=None)]
        assert seen == pytest.approx([caller] * 2)
    finally:
        sys.setswitchinterval(saved)


def test_pool_starts_urgent_jobs_first_and_drops_cancelled_ones():
    """One process, busy: queued jobs start by urgency, then by the frame they are needed at
    (sooner first), then those needed at no frame, each in submit order; a cancelled job
    never starts; wait() books its blocked time. Without ``ahead``: all in submit order."""
    import time

    with ob.make_pool(1) as pool:
        busy = pool.submit(time.sleep, 0.5)
        later = [pool.submit(time.time) for _ in range(3)]
        dropped = pool.submit(time.time)
        needed = [pool.submit(time.time, need=n) for n in (16, 3, 16, 0)]
        urgent = pool.submit(time.time, urgent=True)
        dropped.cancel()
        busy.cancel()  # already started: still runs
        assert pool.wait(busy, "busy") is None and pool.waited_s["busy"] > 0.2
        times = [t.get() for t in later]
        n16, n3, n16b, n0 = (t.get() for t in needed)
        assert urgent.get() < n0 < n3 < n16 < n16b < times[0] < times[1] < times[2]
        with pytest.raises(WarpvxError, match="cancelled"):
            dropped.get()
        assert pool.cancelled == {"time": 1} and pool.started == {"sleep": 1, "time": 8}
        pool.ahead = False
        busy = pool.submit(time.sleep, 0.3)
        order = [pool.submit(time.time, **kw) for kw in ({}, {"need": 0}, {"urgent": True})]
        times = [t.get() for t in order]
        assert times == sorted(times)


def test_shared_block_carries_each_array_once_and_its_segment_is_reused_when_its_jobs_are_done():
    """A batch's jobs' large arrays go once into a shared block: the pickles carry references,
    the processes read the same values; small arrays stay inline; once every job holding the
    block is done or dropped unstarted, its segment serves the next block; the pool's
    shutdown unlinks it."""
    import copy
    import os
    import pickle
    import time

    rng = np.random.default_rng(0)
    pts, angles = rng.random((2000, 2)), rng.random(2000).astype(np.float32)
    near = (rng.integers(-1, 2000, 1500, dtype=np.int32), np.arange(1500, dtype=np.int32))
    K = np.eye(3)
    jobs = [(near, pts, angles, K), (pts, (near, pts), "x")]
    with ob.make_pool(1) as pool:
        busy = pool.submit(time.sleep, 0.3)
        block = pool.shared(jobs)
        name = block._shm.name
        refs = [block.refer(j) for j in jobs]
        assert len(pickle.dumps(refs)) < 1500 < pts.nbytes
        assert block._shm.size < 1.5 * (pts.nbytes + angles.nbytes + sum(a.nbytes for a in near))  # each once
        assert refs[0][3] is K and refs[1][2] == "x"
        # copy.copy returns its (resolved) argument: what the process read.
        tasks = [pool.submit(copy.copy, r, block=block) for r in refs]
        dropped = pool.submit(copy.copy, refs[0], block=block)
        dropped.cancel()
        block.release()
        got = [t.get() for t in tasks]
        busy.get()
        for want, have in zip(jobs, got):
            for a, b in zip(op._arrays_in(want), op._arrays_in(have)):
                assert a.dtype == b.dtype and np.array_equal(a, b)
        # (A job's release runs in its callback, before get() returns.)
        assert block._shm is None
        again = pool.shared(jobs[:1])
        assert again._shm.name == name
        np.testing.assert_array_equal(copy.copy(op._resolve(again.refer(pts))), pts)
    assert not os.path.exists(f"/dev/shm/{name}")
    again.release()  # (after the shutdown unlinked it: nothing more to do)


def _thread_cpu_s(thread) -> float:
    """CPU seconds of ``thread`` so far (Linux: /proc)."""
    import os

    with open(f"/proc/{os.getpid()}/task/{thread.native_id}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self/task"), reason="needs Linux /proc")
def test_pool_handler_thread_sleeps_while_results_wait():
    """Results left in the pipe (the result thread blocked in a callback, as when it waits
    for the GIL) do not wake the worker-handler thread (the stock Pool's spins on them: 0.31 s
    of CPU in 0.4 s here); the pool then works on, and shuts down (the handler wakes for it)."""
    import operator
    import time

    with ob.make_pool(2) as pool:
        handler, gate = pool._pool._worker_handler, threading.Lock()
        with gate:  # the first result's callback blocks the result thread: the others stay in the pipe
            tasks = [pool._pool.apply_async(time.time, callback=lambda _: gate.acquire() and gate.release())
                     for _ in range(4)]
            time.sleep(0.2)
            before = _thread_cpu_s(handler)
            time.sleep(0.4)
            spent = _thread_cpu_s(handler) - before
        assert spent < 0.1
        [t.get() for t in tasks]
        assert pool.map(operator.add, [(1, 2), (3, 4), (5, 6)]) == [3, 7, 11]


def test_pool_in_an_unguarded_script(tmp_path):
    """A script without ``if __name__ == "__main__"`` can open a pool: the spawned processes
    do not re-run it (they would raise, and run its top level once per process)."""
    import subprocess
    import sys
    from pathlib import Path

    marker = tmp_path / "runs.txt"
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import operator\n"
        "from warpvx.apps import orbslam_batch as ob\n"
        f"open({str(marker)!r}, 'a').write('run\\n')\n"
        "pool = ob.make_pool(2)\n"
        "print(pool.map(operator.add, [(1, 2), (3, 4)]))\n"
        "pool.shutdown()\n")
    root = Path(__file__).resolve().parents[2]
    res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         cwd=root, env={**__import__("os").environ, "PYTHONPATH": str(root)})
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.strip() == "[3, 7]"
    assert marker.read_text() == "run\n"  # the script's top level ran once, in the parent


def test_new_settings_refuse_bad_values_by_name():
    """keyframe_motion, the pool's workers and verify's gpu= answer bad values with warpvx
    errors naming them."""
    from warpvx.errors import GraphError
    import warpvx

    for bad in (1, "yes", None):
        with pytest.raises(WarpvxError, match="keyframe_motion"):
            o.TrackerConfig(keyframe_motion=bad)
    for bad in (-1, 1.5, "2"):
        with pytest.raises(WarpvxError, match="workers"):
            ob.make_pool(bad)
    for bad in (-1, 20, 1.5, None):
        with pytest.raises(WarpvxError, match="nice"):
            ob.make_pool(0, nice=bad)
    for bad in ("no", 1, None):
        with pytest.raises(WarpvxError, match="chain_process"):
            ob.make_pool(0, chain_process=bad)
        with pytest.raises(WarpvxError, match="chain_process"):
            next(ob.track_frames_batched([np.zeros((8, 8), np.uint8)], None, chain_process=bad))
    # nice: checked on every call; with an open pool (whose processes were started with their
    # own niceness) a nonzero one is refused rather than silently unused.
    for bad in (-1, 20, 1.5, None):
        with pytest.raises(WarpvxError, match="nice"):
            next(ob.track_frames_batched([np.zeros((8, 8), np.uint8)], None, nice=bad))
    with pytest.raises(WarpvxError, match="nice"):
        next(ob.track_frames_batched([np.zeros((8, 8), np.uint8)], None, pool=object(), nice=3))
    g = warpvx.Graph("g")
    x = g.input("x", shape=(4,), dtype=np.float32)
    g.output("y", g.user(np.negative, [x], name="neg"))
    with pytest.raises(GraphError, match="gpu"):
        g.verify({"x": np.zeros(4, np.float32)}, gpu="cpu")
    with pytest.raises(WarpvxError, match="backend|gpu"):
        g.verify({"x": np.zeros(4, np.float32)}, gpu="tpu")


def test_look_ahead_follows_the_pool_and_refuses_bad_values_by_name():
    """The chain's core look-ahead: one frame per pose process but one, within
    [SPECULATE_AHEAD, MAX_LOOK_AHEAD], unless the pool's look_ahead sets it; a bad look_ahead
    (to make_pool, PosePool, ChainProcess, or set on a chain process before a run) is a
    warpvx error naming it, raised before any process starts."""

    class Pool:
        def __init__(self, workers, look_ahead=None):
            self.workers, self.look_ahead = workers, look_ahead

    assert [osp.look_ahead(Pool(w)) for w in (1, 2, 7, 8, 13, 40)] == \
        [osp.SPECULATE_AHEAD] * 3 + [7, 12, osp.MAX_LOOK_AHEAD]
    assert osp.look_ahead(Pool(13, 3)) == 3 and osp.look_ahead(Pool(2, 30)) == 30
    for bad in (0, -2, 1.5, "4", True):
        for make in (lambda: ob.make_pool(0, look_ahead=bad), lambda: op.PosePool(1, look_ahead=bad),
                     lambda: orbslam_chain.ChainProcess(0, look_ahead=bad)):
            with pytest.raises(WarpvxError, match="look_ahead"):
                make()

    class Proc:  # a chain process whose look_ahead was set to a bad value after it opened
        dry, ahead, share, direct, look_ahead = False, True, True, True, 0

        def send(self, payload, run):
            raise AssertionError("sent")

    with pytest.raises(WarpvxError, match="look_ahead"):
        orbslam_chain.send_batch(None, [], (), 0, K=np.eye(3), config=o.TrackerConfig(), baseline=None,
                                 frames=1, proc=Proc())


def test_packed_features_unpack_to_the_device_ones(seq):
    """orb_batch_warp's packed features (each field joined on the device, one download each)
    split back into every frame's keypoints and descriptors, a frame without any included."""
    import warp as wp

    from warpvx.keypoints import FIELDS
    from warpvx.runtime.transfers import Transfers

    left = seq[0]
    images = wp.array(np.stack([left[0], np.zeros_like(left[0]), left[1]]), dtype=wp.uint8, device="cpu")
    feats, packed = ob.orb_batch_warp(images, config=o.TrackerConfig())
    host = ob.unpack_feats(Transfers("cpu").download(packed))  # as the executor hands it over
    assert [len(k.x) for k, _ in host] == [int(d.shape[0]) for _, d in feats]
    assert len(host[1][0].x) == 0 and len(host[0][0].x) > 0
    for (k, d), (hk, hd) in zip(feats, host):
        assert all(np.array_equal(getattr(k, f).numpy(), getattr(hk, f)) for f in FIELDS)
        assert np.array_equal(d.numpy(), hd)


def _children(pid) -> list:
    """``pid``'s child processes (Linux /proc)."""
    kids = []
    for task in os.listdir(f"/proc/{pid}/task"):
        with open(f"/proc/{pid}/task/{task}/children") as f:
            kids += [int(k) for k in f.read().split()]
    return kids


def _running(pid) -> bool:
    """Whether ``pid`` exists and is not a zombie."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _gone(pids, within_s=60.0) -> bool:
    end = time.monotonic() + within_s
    while any(_running(p) for p in pids) and time.monotonic() < end:
        time.sleep(0.1)
    return not any(_running(p) for p in pids)


def _segments() -> set:
    return {name.lstrip("/") for name in os.listdir("/dev/shm")}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc and /dev/shm")
def test_chain_process_survives_stopped_runs_and_leaves_no_process_or_segment(seq, sequential):
    """One chain process for several runs: a run closed early and one whose frames fail leave
    batches in flight there, yet the next run gives the sequential poses; its shutdown ends it
    and its pool's processes and unlinks its shared blocks (stereo: the images travel too)."""
    frames, camera = _frames(seq, True)
    want = sequential[True]

    def failing():
        yield from frames[:7]
        raise RuntimeError("camera unplugged")

    with ob.make_pool(2, chain_process=True) as proc:
        assert isinstance(proc, ob.ChainProcess)
        pids = [proc._process.pid, *_children(proc._process.pid)]  # the pool's processes among them
        assert len(pids) >= 3
        it = ob.track_frames_batched(frames, camera, batch=3, pool=proc)
        next(it)
        it.close()
        with pytest.raises(RuntimeError, match="unplugged"):
            list(ob.track_frames_batched(failing(), camera, batch=2, pool=proc))
        got = np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=BATCH, pool=proc)])
        np.testing.assert_allclose(got, want, atol=1e-9)
        assert proc.started["frame_job"] > 0 and proc.counts()[3]["wall_s"] > 0
        # The batches' blocks (other processes on this machine may make segments meanwhile).
        mine = {shm.name for shm in proc._segments._free} | {shm.name for _, shm in proc._segments._held.values()}
        assert mine
    assert _gone(pids)
    assert not mine & _segments()


@pytest.mark.parametrize("direct", [True, False], ids=["direct", "task_thread"])
def test_pool_jobs_written_directly_or_through_the_task_thread(direct):
    """PosePool(direct=True) writes jobs to the processes itself (multiprocessing's task
    thread never sees one); either way values come back and a job that cannot be pickled
    fails alone, with its error, the pool still usable."""
    pool = op.PosePool(1, direct=direct)
    try:
        handed = []

        class Spied:  # the task thread's queue, its puts recorded
            def __init__(self, queue):
                self.queue = queue

            def put(self, item):
                handed.append(item)
                self.queue.put(item)

        pool._pool._taskqueue = Spied(pool._pool._taskqueue)
        assert pool.map(divmod, [(7, 2), (9, 4)]) == [(3, 1), (2, 1)]
        with pytest.raises(Exception, match="pickle|lambda"):
            pool.submit(divmod, lambda: 0, 1).get()
        assert pool.submit(divmod, 5, 5).get() == (1, 0)
        assert (len(handed) == 0) == direct
    finally:
        pool.shutdown()


@pytest.mark.parametrize("chain_process", [True, False], ids=["chain_process", "chain_in_process"])
def test_an_open_pool_keeps_its_verified_graph_for_the_next_run(seq, chain_process, monkeypatch):
    """A second run on the same open pool with the same settings reuses the first run's
    verified graph (none built, none verified) and gives the same poses, bit for bit; other
    settings build their own; a run that fails gives none back; shutdown drops them."""
    frames, camera = _frames(seq, False)
    built = []
    build = ob.build_batch_graph
    monkeypatch.setattr(ob, "build_batch_graph", lambda *a, **k: built.append(a[1]) or build(*a, **k))
    with ob.make_pool(1, chain_process=chain_process) as pool:
        first = np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=BATCH, pool=pool)])
        again = np.array([f.pose for f in ob.track_frames_batched(frames, camera, batch=BATCH, pool=pool)])
        np.testing.assert_array_equal(again, first)
        assert built == [BATCH]
        list(ob.track_frames_batched(frames[:6], camera, batch=3, pool=pool))
        assert built == [BATCH, 3] and len(pool.graphs) == 2
        with pytest.raises(WarpvxError, match="dtype"):
            list(ob.track_frames_batched([{"image": f["image"].astype(np.float32)} for f in frames], camera,
                                         batch=BATCH, pool=pool))
        assert len(pool.graphs) == 1  # (taken by the failed run, not given back)
        np.testing.assert_array_equal([f.pose for f in ob.track_frames_batched(frames, camera, batch=BATCH,
                                                                             pool=pool)], first)
        assert built == [BATCH, 3, BATCH]
        monkeypatch.setattr(ob, "KEEP_GRAPHS", 1)  # the least recently run dropped
        list(ob.track_frames_batched(frames[:6], camera, batch=3, pool=pool))
        assert built == [BATCH, 3, BATCH] and [key[3] for key in pool.graphs] == [3]
    assert pool.graphs == {}


def _two_frame_batch(seq):
    """The sequence's first two frames as one batch: (images, features, nearest rows, the
    other arguments of send_batch)."""
    frames, camera = _frames(seq, False)
    config = o.TrackerConfig()
    images = np.stack([f["image"] for f in frames[:2]])
    feats = ob.orb_batch(images, config=config)[0]
    nearest = ob.match_batch(feats, np.zeros((0, 32), np.uint8), frames=2)[1]
    return images, feats, nearest, dict(K=np.ascontiguousarray(camera.K), config=config, baseline=None, frames=2)


def test_chain_process_dry_run_answers_without_tracking(seq):
    """In ChainProcess.dry_run (what the graph's verification runs in) this thread's batches
    get zero poses and stats shaped and typed as real ones, no pose work started; another
    thread's batch meanwhile is tracked for real."""
    images, feats, nearest, kwargs = _two_frame_batch(seq)
    with ob.make_pool(1, chain_process=True) as proc:
        before = proc.started["frame_job"]
        elsewhere = []
        with proc.dry_run():
            sent, ticket = orbslam_chain.send_batch(images, feats, nearest, 0, proc=proc, **kwargs)
            other = threading.Thread(target=lambda: elsewhere.append(
                orbslam_chain.send_batch(images, feats, nearest, 0, proc=proc, **kwargs)[1]))
            other.start()
            other.join()
        poses, stats = proc.result(ticket)
        real_poses, real_stats = proc.result(elsewhere[0])
        assert sent == 1 and not poses.any() and not stats.any()
        assert (poses.shape, poses.dtype, stats.shape, stats.dtype) == (
            real_poses.shape, real_poses.dtype, real_stats.shape, real_stats.dtype) == ((2, 4, 4), np.float64,
                                                                                         (2, len(o.STATS)), np.float64)
        np.testing.assert_array_equal(real_poses[0], np.eye(4))  # (the run's first frame)
        assert real_stats[1, 0] > 0
        assert proc.started["frame_job"] - before == 2  # the real batch's only


def test_chain_process_primes_a_runs_first_batch_during_the_dry_run(seq):
    """In a priming dry run (the verification's), a run's first batch gets its dry zeros at
    once and goes to the process for real too; the stream's first batch, equal to it, takes
    its ticket (its real poses, no second pose work); one that differs is sent anew; a batch
    of no run after a prime (the calibration's samples) ends the primed run: it fails as in
    a fresh process, and the next run starts clean."""
    images, feats, nearest, kwargs = _two_frame_batch(seq)

    def same(got, want):  # poses and stats but the time per frame
        np.testing.assert_array_equal(got[0], want[0])
        timed = o.STATS.index("track_ms")
        np.testing.assert_array_equal(np.delete(got[1], timed, 1), np.delete(want[1], timed, 1))

    def send(sent=0, near=nearest):
        return orbslam_chain.send_batch(images, feats, near, sent, proc=proc, **kwargs)[1]

    with ob.make_pool(1, chain_process=True) as proc:
        want = proc.result(send())  # (unprimed: the reference)
        before = proc.started["frame_job"]
        with proc.dry_run(prime=True):
            dry = send()
        poses, stats = proc.result(dry)
        assert not poses.any() and not stats.any()
        ticket = send()  # the stream's first: the primed batch's ticket
        assert ticket < dry
        same(proc.result(ticket), want)
        assert proc.started["frame_job"] - before == 2  # (its 2 frames' jobs, once)
        with proc.dry_run(prime=True):
            send()
        other = send(near=tuple(a.copy() for a in nearest[:2]) + (nearest[2][::-1].copy(),))  # differs
        assert proc.started["frame_job"] - before == 6
        assert proc.primes == {"sent": 2, "taken": 1, "dropped": 1}
        with pytest.raises(WarpvxError, match="batch outside a run"):
            with proc.dry_run(prime=True):
                send()
            proc.result(send(sent=1))  # the calibration's: not the primed run's continuation
        proc.result(other)
        same(proc.result(send()), want)  # a new run: as the first


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_nice_lowers_the_pose_processes_priority_only():
    """make_pool(nice=N): the pose processes run N nicer than the caller, in this process's
    pool and in a chain process's (whose own priority stays the caller's)."""
    base = os.getpriority(os.PRIO_PROCESS, 0)
    want = min(19, base + 3)
    with ob.make_pool(1, nice=3) as pool:
        assert pool.submit(os.getpriority, os.PRIO_PROCESS, 0).get() == want
    with ob.make_pool(1, chain_process=True, nice=3) as proc:
        # (its pose processes; not the resource tracker it may have started)
        kids = [k for k in _children(proc._process.pid) if b"spawn_main" in Path(f"/proc/{k}/cmdline").read_bytes()]
        assert kids
        assert os.getpriority(os.PRIO_PROCESS, proc._process.pid) == base
        deadline = time.monotonic() + 60  # (set by the processes' initializer, once they have started)
        while {os.getpriority(os.PRIO_PROCESS, k) for k in kids} != {want} and time.monotonic() < deadline:
            time.sleep(0.1)
        assert {os.getpriority(os.PRIO_PROCESS, k) for k in kids} == {want}


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_chain_process_killed_is_an_error_and_its_pool_goes_with_it(seq):
    """The chain process killed outright mid-run: the caller gets an error, not a hang, and
    the pool's processes (which wait on a queue they hold both ends of) end too."""
    frames, camera = _frames(seq, False)
    with ob.make_pool(2, chain_process=True) as proc:
        pids = [proc._process.pid, *_children(proc._process.pid)]
        it = ob.track_frames_batched(frames, camera, batch=2, pool=proc)
        next(it)
        os.kill(proc._process.pid, signal.SIGKILL)
        with pytest.raises(WarpvxError, match="chain process"):
            list(it)
    assert _gone(pids)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_chain_process_ends_when_its_parent_dies(tmp_path):
    """A caller that exits without shutting the chain process down (killed, os._exit): the
    process sees its pipe close and ends with its pool."""
    script = tmp_path / "orphan.py"
    script.write_text(
        "import os\n"
        "from warpvx.apps import orbslam_pool as op\n"
        "proc = op.make_pool(2, chain_process=True)\n"
        "pid = proc._process.pid\n"
        "kids = [k for t in os.listdir(f'/proc/{pid}/task') for k in open(f'/proc/{pid}/task/{t}/children').read().split()]\n"
        "print(pid, *kids, flush=True)\n"
        "os._exit(0)\n")
    root = Path(__file__).resolve().parents[2]
    run = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(root)})
    pids = [int(p) for p in run.stdout.split()]
    assert len(pids) >= 3, run.stderr
    assert _gone(pids)


def test_a_prime_is_taken_only_by_the_same_bits():
    # The stream's first batch takes the primed ticket only when every array is the primed
    # one bit for bit: -0.0 is not 0.0 (an atan2 tells them apart); a NaN is itself.
    same = orbslam_chain._same_value
    assert not same((np.array([0.0]), {"k": 1}), (np.array([-0.0]), {"k": 1}))
    assert same((np.array([np.nan, 1.0]), [2]), (np.array([np.nan, 1.0]), [2]))
    assert not same(np.zeros(3, np.float32), np.zeros(3, np.float64))
    assert not same(np.zeros((1, 3)), np.zeros(3))


def test_chain_process_result_of_an_unknown_ticket_is_an_error_not_a_wait():
    # A ticket it never sent (or whose result it no longer keeps) raises at once (before: a
    # dry ticket evicted from its table waited for a message that never comes).
    with ob.make_pool(1, chain_process=True) as proc:
        t0 = time.perf_counter()
        with pytest.raises(WarpvxError, match="no longer kept"):
            proc.result(12345)
        assert time.perf_counter() - t0 < 5.0
