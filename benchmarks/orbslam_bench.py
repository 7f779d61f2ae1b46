"""ORB-SLAM front end benchmark: FPS at 1241x376 (KITTI size) against an OpenCV-only baseline.

The sequence is rendered (warpvx.apps.orbslam_synth: a room textured with real photos, exact
poses; KITTI-like camera, stereo baseline 0.54 m), so no data set is needed; its frames are
replayed forward and back to make long runs with continuous motion. Frames are in host memory;
reading PNGs is timed separately. Measured, side by side in one run:

1. extraction + matching pipelined (``stream(depth=3)``) on the backend (target 1000+ FPS on an
   H100), two ways: the front end's ``match`` node (nearest rows both ways on the device, rows
   padded so the matcher's buffers are reused, no host sync; the mutual pairs kept by a CPU
   node) and, as before, the ``match_hamming`` primitive with cross-check (one host sync per
   frame for the match count);
2. the front end end to end (warpvx.apps.orbslam, monocular and stereo), pipelined, with the
   median time of each node (ms, from the executor's timelines: compute, transfers, and the
   GPU thread's host time per GPU node);
3. the OpenCV-only monocular baseline (``cv2.ORB_create(2000, 1.2, 8)``, ``BFMatcher`` with
   cross-check, ``findEssentialMat`` + ``recoverPose``) with OpenCV on all cores, serial, and
   with extraction spread over a thread pool of all cores (matching and pose in order);
4. accuracy (ATE, RPE) of each on the rendered sequence, the scheduler's placement and
   predicted vs measured makespan, and a Gantt chart of 3 pipelined frames;
5. the batched front end (warpvx.apps.orbslam_batch, ``--batch B`` frames per graph frame):
   extraction + matching batched (``orb_batch`` + ``match_batch`` on the device: one launch
   matches all consecutive pairs both ways; the mutual pairs on the host), mono and stereo
   end to end with the tracking chain and the pose work in a process of their own
   (``orbslam_chain.ChainProcess``, the default) and the pose work on a process pool of all
   cores but three (mono also on one of all cores but one, the default before; and with the
   chain in this process, the path before), the pool's speed-up on one batch's pose work
   (``pose_batch`` on one process vs the pool), what the pool did per batch (how long the
   chain waited on it, for the frame jobs and for the keyframe cores it speculates; jobs
   started and dropped; the chain's wall vs thread CPU time), and its accuracy
   (the poses must be the sequential ones); mono also with Python's GIL switch interval
   (5 ms) against the batched mode's default (``orbslam_batch.SWITCH_INTERVAL``), and with
   the jobs' arrays pickled with each job against a shared block per batch (the default),
   and on multiprocessing's stock ``Pool`` against the pose pool's (``PosePool(quiet=False)``),
   and with the pool's jobs handed to multiprocessing's task thread against written to the
   processes by the thread that dispatches them (``PosePool(direct=...)``), and with the
   chain's core look-ahead at 6 frames (the fixed value before) and 16 against the default
   (one frame per pose process but one, ``orbslam_speculate.look_ahead``); the default run
   also as a first run (graph built and verified in the timed call; its setup split into
   build, verification and schedule, and the first batches' output intervals).

FPS columns: "wall" counts everything from the call (graph build, verification: the batched
mode's by the warm-up run on the same open pool, which keeps the verified graph for the next
run, see ``orbslam_batch.track_frames_batched``; a chain process answers a verification dry,
``ChainProcess.dry_run``; calibration: cached after the warm-up run; the batched mode's pool
is opened once, before); "steady" is frames over the sum of their output intervals (from the
first frame out, no setup).

Accuracy also on ViSP's castle_simu (monocular, warpvx vs the baseline) when
``../shared/data/real/castle_simu`` (or ``--castle``) exists.

Writes ``orbslam_bench.json``, ``orbslam_bench.md`` (the command that regenerates it at its
top), ``gantt_mono.png``, ``gantt_stereo.png``, ``gantt_batch_mono.png``,
``gantt_batch_stereo.png`` into ``--out`` (default ``$OUT/orbslam``).

Usage::

    PYTHONPATH=. python benchmarks/orbslam_bench.py --out $OUT/orbslam   # GPU machine (cuda), < 5 min
    PYTHONPATH=. python benchmarks/orbslam_bench.py --quick              # anywhere: warp-cpu, few frames
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import sys
import tempfile
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warpvx  # noqa: E402
from warpvx.apps import orbslam as o  # noqa: E402
from warpvx.apps import orbslam_batch as ob  # noqa: E402
from warpvx.apps import trajectory_eval as te  # noqa: E402
from warpvx.apps import orbslam_speculate as osp  # noqa: E402
from warpvx.apps.orbslam_match import add_match_node, batch_pairs, mutual_pairs  # noqa: E402
from warpvx.apps.orbslam_synth import render_sequence  # noqa: E402

# ../shared/data next to the repository (the main checkout), else the dev machine's copy.
CASTLE = next((p for p in (Path(__file__).resolve().parents[2] / "shared", Path("/work/shared"))
               if (p / "data" / "real" / "castle_simu").is_dir()), Path("/work/shared")) \
    / "data" / "real" / "castle_simu"


def replay(frames, n):
    """``n`` items of ``frames`` played forward then backward (0 1 .. m-1 m-2 .. 1 0 1 ...)."""
    cycle = list(range(len(frames))) + list(range(len(frames) - 2, 0, -1))
    return [frames[cycle[i % len(cycle)]] for i in range(n)]


def fps(n, seconds):
    return n / seconds if seconds > 0 else float("inf")


def _pairs_node(prev_n, kps, nearest, distance, back):
    """The CPU side of the ``match`` node's matching: (this frame's keypoint count, pairs)."""
    n = len(kps)
    return n, mutual_pairs(nearest, distance, back, n, prev_n)[0]


def bench_extract_match(images, backend, primitive, depth=3):
    """Pipelined FPS of ORB + frame-to-frame matching (pairs on the host each frame)."""
    g = warpvx.Graph("orb_match")
    h, w = images[0].shape
    image = g.input("image", shape=(h, w), dtype=np.uint8)
    pin = None if backend == "cpu" else "gpu"
    kps, desc = g.orb(image, name="orb", target=pin)
    if primitive:
        pairs, _ = g.match_hamming(desc, g.delay(desc)[-1], cross_check=True, name="match", target=pin)
    else:
        count = g.virtual("count")
        nearest = add_match_node(g, desc, target=pin)
        _, pairs = g.user(_pairs_node, [g.delay(count, init=0)[-1], kps, *nearest], [count, "pairs"],
                          name="pairs")
    g.output("pairs", pairs)
    g.verify([{"image": images[0]}, {"image": images[1]}])
    plan = g.schedule("best", gpu=False if backend == "cpu" else backend)
    with g:
        list(g.stream(({"image": im} for im in images[:10]), depth=depth))  # warm-up
        t = time.perf_counter()
        n = sum(1 for _ in g.stream(({"image": im} for im in images), depth=depth))
        dt = time.perf_counter() - t
    return {"fps": fps(n, dt), "frames": n, "placement": plan.placement, "stages_ms": stage_ms(plan)}


def _pairs_batch(feats, nearest, tail):
    """The host side of batched matching: each frame's mutual pairs (and the last count);
    ``feats`` packed (``orb_batch``'s second output)."""
    prev_n, pairs = tail, []
    for f, (kps, _) in enumerate(ob.unpack_feats(feats), 1):
        pairs.append(mutual_pairs(*batch_pairs(*nearest, f), len(kps), prev_n)[0])
        prev_n = len(kps)
    return prev_n, pairs


def bench_extract_match_batched(images, backend, batch, depth=3):
    """Pipelined FPS of batched ORB + matching (``orb_batch`` + ``match_batch`` of the batched
    front end, B frames per graph frame), the pairs on the host each frame."""
    g = warpvx.Graph("orb_match_batch")
    h, w = images[0].shape
    x = g.input("images", shape=(batch, h, w), dtype=np.uint8)
    _, feats, nearest = ob.add_extract_match(g, x, batch, o.TrackerConfig(),
                                             target=None if backend == "cpu" else "gpu")
    count = g.virtual("count")
    _, pairs = g.user(_pairs_batch, [feats, nearest, g.delay(count, init=0)[-1]], [count, "pairs"],
                      name="pairs")
    g.output("pairs", pairs)
    batches = [{"images": np.stack(images[i:i + batch])} for i in range(0, len(images) - batch + 1, batch)]
    g.verify(batches[:2])
    plan = g.schedule("best", gpu=False if backend == "cpu" else backend)
    with g:
        list(g.stream(batches[:2], depth=depth))  # warm-up
        t = time.perf_counter()
        n = batch * sum(1 for _ in g.stream(batches, depth=depth))
        dt = time.perf_counter() - t
    return {"fps": fps(n, dt), "frames": n, "batch": batch, "placement": plan.placement,
            "stages_ms": stage_ms(plan)}


def _frontend_result(res, dt, plan, out, name, backend):
    """FPS (wall, steady), median track ms, stages, the plan's summary and a Gantt chart
    (``gantt_{name}.png``; name None: none)."""
    summary = plan.summary()
    try:
        if name is not None:
            plan.gantt(out / f"gantt_{name}.png", frames=3, title=f"ORB-SLAM front end ({name}, {backend})")
    except Exception as exc:  # noqa: BLE001 - matplotlib missing: the numbers still count
        summary["gantt_error"] = str(exc)
    track_ms = statistics.median(f.stats["track_ms"] for f in res)
    # (setup: the call's time before its stream started: the graph's build, verification and
    # schedule on a first run)
    return {"fps": fps(len(res), dt), "steady_fps": fps(len(res), 1e-3 * sum(f.ms for f in res)),
            "setup_ms": 1e3 * dt - sum(f.ms for f in res),
            "frames": len(res), "track_ms_median": track_ms, "stages_ms": stage_ms(plan),
            "plan": summary}, np.array([f.pose for f in res])


#: Monocular motion from the previous frame only: every essential matrix worked out ahead.
PREVIOUS_ONLY = o.TrackerConfig(keyframe_motion=False)
#: The batched runs: report key, camera, Gantt name (None: none), tracker settings, the pool's
#: settings for the run (``look_ahead``: frames whose cores the chain keeps started, 6 the
#: fixed value before it followed the pool's processes; ``ahead`` False: jobs in submit order and no guessed cores, the
#: scheduling before them; ``share`` False: the jobs' arrays pickled with each job, the
#: transport before shared blocks; ``direct`` False: the jobs handed to multiprocessing's task
#: thread, as before), the GIL switch interval (s; None: Python's, 5 ms).
BATCHED = (("batched_mono", "mono", "batch_mono", o.TrackerConfig(), {}, ob.SWITCH_INTERVAL),
           ("batched_mono_look_ahead_6", "mono", None, o.TrackerConfig(), {"look_ahead": osp.SPECULATE_AHEAD},
            ob.SWITCH_INTERVAL),
           ("batched_mono_look_ahead_16", "mono", None, o.TrackerConfig(), {"look_ahead": 16}, ob.SWITCH_INTERVAL),
           ("batched_mono_switch_5ms", "mono", None, o.TrackerConfig(), {}, None),
           ("batched_mono_pickled", "mono", None, o.TrackerConfig(), {"share": False}, ob.SWITCH_INTERVAL),
           ("batched_mono_fifo", "mono", None, o.TrackerConfig(), {"ahead": False}, ob.SWITCH_INTERVAL),
           ("batched_mono_task_thread", "mono", None, o.TrackerConfig(), {"direct": False}, ob.SWITCH_INTERVAL),
           ("batched_mono_prev", "mono", "batch_mono_prev", PREVIOUS_ONLY, {}, ob.SWITCH_INTERVAL),
           ("batched_stereo", "stereo", "batch_stereo", o.TrackerConfig(), {}, ob.SWITCH_INTERVAL))


#: Report key of the default batched mono run timed as a first run (its graph built and
#: verified in the timed call, as on a fresh pool; the other rows reuse the warm-up's graph).
FIRST_CALL = "batched_mono_first_call"

#: Over all ``orbslam_batch.chain`` calls: seconds of wall time and of its thread's CPU time;
#: their gap is what the chain waited for (the pool, the GIL, a core). See :func:`_timed_chain`.
CHAIN_TIME = {"wall_s": 0.0, "cpu_s": 0.0}


def _timed_chain(fn):
    """``fn`` (``orbslam_batch.chain``) adding its wall and thread CPU time to :data:`CHAIN_TIME`."""

    @functools.wraps(fn)
    def timed(*args, **kwargs):
        w, c = time.perf_counter(), time.thread_time()
        try:
            return fn(*args, **kwargs)
        finally:
            CHAIN_TIME["cpu_s"] += time.thread_time() - c
            CHAIN_TIME["wall_s"] += time.perf_counter() - w

    return timed


# The graphs built from here on call the timed chain (build_batch_graph looks it up by name).
ob.chain = _timed_chain(ob.chain)

#: Over all batched runs: seconds in the parts of a call's setup (a first run's: the graph's
#: build, its verification; every run's: its schedule). See :func:`_timed_setup`.
SETUP_TIME = {"build_s": 0.0, "verify_s": 0.0, "schedule_s": 0.0}


def _timed(key, fn):
    """``fn`` adding its wall time to ``SETUP_TIME[key]``."""

    @functools.wraps(fn)
    def timed(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            SETUP_TIME[key] += time.perf_counter() - t

    return timed


def _timed_build(*args, **kwargs):
    """``orbslam_batch.build_batch_graph`` timed, its graph's ``verify`` too."""
    g = _timed("build_s", _build_batch_graph)(*args, **kwargs)
    g.verify = _timed("verify_s", g.verify)
    return g


# (track_frames_batched looks both up by name at each call)
_build_batch_graph, ob.build_batch_graph = ob.build_batch_graph, _timed_build
o.schedule = _timed("schedule_s", o.schedule)


#: The default batched mono run on multiprocessing's stock Pool (PosePool(quiet=False)).
STOCK_POOL = "batched_mono_stock_pool"
#: The default batched mono run on a pool of all cores but one (the default before
#: ``orbslam_batch.default_workers``), run when the default pool is smaller.
OLD_POOL = "batched_mono_pool_old"


#: The default batched mono run with the chain in this process (the pose pool alone, no chain process).
CHAIN_IN_PROCESS = "batched_mono_chain_in_process"


def _pool_counts(pool):
    """(waited_s, started, cancelled, chain time) so far: a chain process's from it (timed
    there), a pose pool's with :data:`CHAIN_TIME`."""
    if isinstance(pool, ob.ChainProcess):
        return pool.counts()
    return tuple(dict(c) for c in (pool.waited_s, pool.started, pool.cancelled)) + (dict(CHAIN_TIME),)


#: pool_per_batch's counts: key, the pool's counter, the job's function.
POOL_COUNTS = (("frame_jobs", 1, "frame_job"), ("pairs_jobs", 1, "pairs_job"), ("guess_jobs", 1, "guess_job"),
               ("guesses_dropped", 2, "guess_job"), ("keyframe_cores", 1, "_essential_job"),
               ("keyframe_cores_dropped", 2, "_essential_job"), ("cores_on_the_spot", 1, "on the spot"))


def pool_per_batch(pool, before, batches) -> dict:
    """What the pool did per batch since ``before`` (:func:`_pool_counts`): ms the chain waited
    for the frame jobs (``ahead``) and for keyframe cores (speculated or guessed), and
    computed cores itself (none worked out ahead); jobs started and dropped unstarted
    (:data:`POOL_COUNTS`)."""
    now = _pool_counts(pool)
    row = {f"chain_{key}_ms": 1e3 * (now[0].get(what, 0) - before[0].get(what, 0)) / batches
           for key, what in (("wait_ahead", "ahead"), ("wait_keyframe", "keyframe"), ("on_the_spot", "on the spot"))}
    row.update({key: (now[i].get(fn, 0) - before[i].get(fn, 0)) / batches for key, i, fn in POOL_COUNTS})
    row.update({f"chain_{k}_ms": 1e3 * (now[3][f"{k}_s"] - before[3][f"{k}_s"]) / batches for k in ("wall", "cpu")})
    return row


def bench_frontend_batched(frames, camera, backend, out, name, batch, pool, depth=3, config=o.TrackerConfig(),
                           settings=None, switch=ob.SWITCH_INTERVAL, first_call=False):
    """The batched front end end to end (``pool``: a chain process or the pose work's process
    pool (the chain in this process), opened once (None: neither, ``--workers 0``);
    ``settings``: its attributes for the run, e.g. ``{"ahead": False}``, restored after;
    ``switch``: the run's GIL switch interval, s; ``first_call``: the pool's kept graphs
    dropped after the warm-up, so the timed call builds and verifies its graph as a first run
    on a fresh pool does), with what the pool did per batch (:func:`pool_per_batch`)."""
    if pool is not None and settings:
        saved = {k: getattr(pool, k) for k in settings}
        for k, v in settings.items():
            setattr(pool, k, v)
        try:
            return bench_frontend_batched(frames, camera, backend, out, name, batch, pool, depth, config,
                                          switch=switch, first_call=first_call)
        finally:
            for k, v in saved.items():
                setattr(pool, k, v)
    plans = []
    run = functools.partial(ob.track_frames_batched, camera=camera, config=config, batch=batch, pool=pool,
                            workers=0 if pool is None else None, chain_process=False, backend=backend,
                            depth=depth, gil_switch_s=switch)
    list(run(frames[:4 * batch]))  # warm-up, calibration
    if first_call and pool is not None:
        pool.graphs.clear()
    before = _pool_counts(pool) if pool is not None else None
    primes = dict(getattr(pool, "primes", {}))
    setup = dict(SETUP_TIME)
    t = time.perf_counter()
    res = list(run(frames, on_finish=plans.append))
    row, poses = _frontend_result(res, time.perf_counter() - t, plans[0], out, name, backend)
    row["setup_parts_ms"] = {k[:-2]: 1e3 * (v - setup[k]) for k, v in SETUP_TIME.items()}
    # (the first batches' output intervals: where a first run's stream may pay more than a kept graph's)
    row["first_batches_ms"] = [res[i].ms * batch for i in range(0, min(len(res), 4 * batch), batch)]
    # (a chain process's primed first batches: sent, taken by the stream, dropped; ChainProcess.dry_run)
    row["primes"] = {k: v - primes.get(k, 0) for k, v in getattr(pool, "primes", {}).items()}
    if pool is not None:
        row["pool_per_batch"] = pool_per_batch(pool, before, -(-len(frames) // batch))
    return row, poses


def bench_pose_pool(frames, camera, batch, pool):
    """The pose work of one mono batch after the first, ms per frame: on one process vs on
    ``pool``: ``pose_batch``'s jobs (the pairs and their filter, no core: the batch follows
    another) and one essential core per frame, to the previous frame (as many as the chain's
    speculation starts; which reference each takes is the chain's)."""
    import types

    images = np.stack([f["image"] for f in frames[:batch + 1]])
    config = o.TrackerConfig()
    feats = ob.orb_batch(images, config=config)[0]  # the features only feed the timed pose work
    descs = [d for _, d in feats]
    _, nearest = ob.nearest_batch(descs[1:], descs[0])
    pts0 = o.keypoint_xy(feats[0][0])
    K = np.ascontiguousarray(camera.K)
    common = dict(K=K, config=config, baseline=None, frames=batch)
    row = {}

    def work(p):
        # (a previous batch's ahead: pose_batch then leaves every core to the chain)
        tail = (*pts0, None, types.SimpleNamespace(next=None, start=0))
        ahead = ob.pose_batch(images[1:], feats[1:], nearest, tail, pool=p, **common)[1]
        per_frame = ob.ahead_frames(ahead)
        prev = [pts0[0]] + [xy for xy, _ in ahead.points[:-1]]
        points = [osp._essential_points(r, xy, a[3], config) for r, (xy, _), a in zip(prev, ahead.points, per_frame)]
        tasks = [p.submit(osp._essential_job, *c, K, config) for c in points if c is not None]
        return [t.get() for t in tasks]

    with ob.make_pool(1) as one:
        for key, p in (("one_process_ms", one), ("pool_ms", pool)):
            row["cores"] = len(work(p))  # (warm-up)
            t = time.perf_counter()
            for _ in range(3):
                work(p)
            row[key] = 1e3 * (time.perf_counter() - t) / (3 * batch)
    row["speedup"] = row["one_process_ms"] / row["pool_ms"]
    row["workers"] = pool.workers
    return row


def stage_ms(plan) -> dict:
    """Median per node over the plan's last frames (ms): its interval, the copies in it, and
    for GPU nodes the GPU thread's host time (enqueue plus syncs)."""
    runs = list(plan.last_run)
    out = {}
    for task in runs[0].timeline if runs else ():
        row = {"ms": statistics.median(r.timeline[task].finish - r.timeline[task].start for r in runs),
               "transfer_ms": statistics.median(r.transfers.get(task, 0.0) for r in runs)}
        if all(task in r.host for r in runs):
            row["host_ms"] = statistics.median(r.host[task][1] - r.host[task][0] for r in runs)
        out[task] = {k: round(v, 3) for k, v in row.items()}
    return out


def bench_frontend(frames, camera, backend, out, name, depth=3):
    plans = []
    list(o.track_frames(frames[:10], camera, backend=backend, depth=depth))  # warm-up, calibration
    t = time.perf_counter()
    res = list(o.track_frames(frames, camera, backend=backend, depth=depth, on_finish=plans.append))
    return _frontend_result(res, time.perf_counter() - t, plans[0], out, name, backend)


def bench_opencv(images, K):
    cv2.setNumThreads(os.cpu_count())
    t = time.perf_counter()
    o.opencv_baseline(images, K)
    serial = fps(len(images), time.perf_counter() - t)
    # Extraction over a thread pool (ORB releases the GIL), matching and pose in order.
    orbs = {}

    def extract(img):
        import threading

        orb = orbs.setdefault(threading.get_ident(), cv2.ORB_create(2000, 1.2, 8))
        return orb.detectAndCompute(img, None)

    bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    t = time.perf_counter()
    with ThreadPoolExecutor(os.cpu_count()) as pool:
        prev = None
        for cur in pool.map(extract, images):
            if prev is not None:
                o.baseline_step(cur, prev, bf, K)
            prev = cur
    pooled = fps(len(images), time.perf_counter() - t)
    return {"serial_fps": serial, "thread_pool_fps": pooled, "threads": os.cpu_count()}


def accuracy(est, gt, with_scale):
    r = te.evaluate(est, gt, with_scale)
    return {"ate_m": r["ate"]["rmse"], "rpe1_t_m": r["rpe"]["delta_1"]["trans_rmse"],
            "rpe1_r_deg": r["rpe"]["delta_1"]["rot_rmse_deg"]}


def castle_accuracy(folder, backend):
    """Monocular accuracy on castle_simu (KITTI layout): warpvx and the OpenCV baseline."""
    from warpvx.apps.orbslam_sources import open_source

    seq = open_source(folder)
    frames = list(seq)
    gt = te.read_kitti(Path(folder) / "poses.txt")[:len(frames)]
    est = np.array([f.pose for f in o.track_frames(frames, seq.camera, backend=backend)])
    base = o.opencv_baseline([f["image"] for f in frames], seq.camera.K)
    return {"warpvx_mono (Sim3)": accuracy(est, gt, True), "opencv_baseline (Sim3)": accuracy(base, gt, True)}


def _stage_table(report, keys):
    """Markdown rows: per node, median ms (copies, GPU-thread host time) of each run."""
    tasks = []
    for k in keys:
        tasks += [t for t in report[k]["stages_ms"] if t not in tasks]
    lines = ["| node | " + " | ".join(keys) + " |", "| --- |" + " --- |" * len(keys)]
    for t in tasks:
        cells = []
        for k in keys:
            v = report[k]["stages_ms"].get(t)
            cells.append("" if v is None else f"{v['ms']:.2f} (copies {v['transfer_ms']:.2f}"
                         + (f", host {v['host_ms']:.2f})" if "host_ms" in v else ")"))
        lines.append(f"| {t} | " + " | ".join(cells) + " |")
    return lines


def _setup(row) -> str:
    """A run's setup, ms, and its parts (graph build, verification, schedule) when measured."""
    parts = row.get("setup_parts_ms")
    return f"{row.get('setup_ms', float('nan')):.0f} ms" + (
        " (" + ", ".join(f"{k} {v:.0f}" for k, v in parts.items()) + ")" if parts else "")


def markdown(report: dict) -> list:
    """The result file's lines from a report (``orbslam_bench.json``; also re-rendered by
    ``--markdown JSON``)."""
    command, backend, n = report["command"], report["backend"], report["frames_timed"]
    size, batch = report["size"], report["batch"]["batch"]
    base = report["opencv_baseline"]["thread_pool_fps"]
    # (in report: a run's JSON from before a row was added re-renders without it)
    batched_keys = [k for k in [key for key, *_ in BATCHED] + [FIRST_CALL, STOCK_POOL, OLD_POOL, CHAIN_IN_PROCESS]
                    if k in report]
    rows = [("extraction + matching, pipelined (match node)", "extract_match"),
            ("extraction + matching, pipelined (match_hamming primitive, before)", "extract_match_primitive")]
    rows += [(f"extraction + matching, batched B={k[len('extract_match_batch'):]} (orb_batch + match_batch)", k)
             for k in report if k.startswith("extract_match_batch")]
    rows += [("front end mono, end to end, frame by frame", "frontend_mono"),
             (f"front end mono, end to end, batched B={batch} (chain in its own process; look-ahead "
              f"{report['batch'].get('look_ahead', osp.SPECULATE_AHEAD)} frames)", "batched_mono"),
             *([("same, a first run: the graph built and verified in the timed call (not kept from the "
                 f"warm-up; setup {_setup(report[FIRST_CALL])} against {_setup(report['batched_mono'])})",
                 FIRST_CALL)] if FIRST_CALL in report else []),
             *[(f"front end mono, end to end, batched B={batch}, look-ahead {n} frames"
                + (" (before: fixed)" if n == osp.SPECULATE_AHEAD else ""), f"batched_mono_look_ahead_{n}")
               for n in (osp.SPECULATE_AHEAD, 16) if f"batched_mono_look_ahead_{n}" in report],
             *([(f"front end mono, end to end, batched B={batch}, chain in this process (the path before)",
                 CHAIN_IN_PROCESS)] if CHAIN_IN_PROCESS in report else []),
             (f"front end mono, end to end, batched B={batch}, GIL switch interval 5 ms (Python's; default "
              f"{ob.SWITCH_INTERVAL * 1e3:g} ms)", "batched_mono_switch_5ms"),
             (f"front end mono, end to end, batched B={batch}, jobs' arrays pickled per job (no shared "
              "block, the transport before)", "batched_mono_pickled"),
             (f"front end mono, end to end, batched B={batch}, pool in submit order, no guessed cores",
              "batched_mono_fifo"),
             (f"front end mono, end to end, batched B={batch}, pool jobs through multiprocessing's task thread "
              "(before)", "batched_mono_task_thread"),
             (f"front end mono, end to end, batched B={batch}, keyframe_motion off", "batched_mono_prev"),
             *([(f"front end mono, end to end, batched B={batch}, multiprocessing's stock Pool (its handler "
                 "thread spins while results wait)", STOCK_POOL)] if STOCK_POOL in report else []),
             *([(f"front end mono, end to end, batched B={batch}, {report[OLD_POOL].get('workers')} pose processes "
                 "(all cores but one, the old default)", OLD_POOL)] if OLD_POOL in report else []),
             ("front end stereo, end to end, frame by frame", "frontend_stereo"),
             (f"front end stereo, end to end, batched B={batch}", "batched_stereo")]
    lines = [f"<!-- {command}   (OUT=$OUT) -->",
             f"# ORB-SLAM front end at {size[0]}x{size[1]} ({backend}, {n} frames, "
             f"{report['cpu_count']} CPU threads; batched mode: {report['batch']['workers']} pose processes)", "",
             "| what | FPS (wall) | FPS (steady) | vs OpenCV (thread pool) |", "| --- | --- | --- | --- |"]
    for label, k in rows:
        r = report[k]
        steady = f"{r['steady_fps']:.1f}" if "steady_fps" in r else ""
        lines.append(f"| {label}" + (f" (FAILED: {r['error']})" if "error" in r else "")
                     + f" | {r['fps']:.1f} | {steady} | {r['fps'] / base:.1f}x |")
    lines += [f"| OpenCV baseline, serial (all threads) | {report['opencv_baseline']['serial_fps']:.1f} | | |",
              f"| OpenCV baseline, thread-pool extraction | {base:.1f} | | 1.0x |",
              f"| (reading a PNG: {report['png_read_ms_per_frame']:.2f} ms/frame, not included) | | | |",
              "", "FPS (wall): frames over the whole call (scheduling, run start and end; the batched "
              "mode's graph built and verified by the warm-up run on the same open pool, which keeps it; "
              "calibration cached by the warm-up run); FPS (steady): frames over the sum of their output intervals.",
              "", f"Pose work of one mono batch after the first (pose_batch, B={batch}: pairs jobs and "
              f"{report['pose_pool'].get('cores', '?')} essential cores), ms per frame: "
              + (f"{report['pose_pool']['one_process_ms']:.2f} on one process, {report['pose_pool']['pool_ms']:.2f} "
                 f"on {report['pose_pool']['workers']} processes ({report['pose_pool']['speedup']:.1f}x)"
                 if "speedup" in report["pose_pool"] else f"FAILED ({report['pose_pool'].get('error')})"),
              *([f"Output interval of the first 4 batches, ms: default "
                 f"{[round(v, 1) for v in report['batched_mono'].get('first_batches_ms', [])]}, a first run "
                 f"{[round(v, 1) for v in report[FIRST_CALL].get('first_batches_ms', [])]} (its first batch's "
                 f"pose work primed during the verification, ChainProcess.dry_run: "
                 f"{report[FIRST_CALL].get('primes')})."]
               if FIRST_CALL in report else []),
              f"Batched poses vs frame-by-frame poses, largest difference: "
              f"{report['batch']['max_pose_difference_vs_sequential']}; mono, chain process vs chain in "
              f"this process: {report['batch']['max_pose_difference_chain_process_vs_in_process']}.",
              "", f"Tracking node alone, median: mono {report['frontend_mono']['track_ms_median']:.2f} ms, "
              f"stereo {report['frontend_stereo']['track_ms_median']:.2f} ms.", "",
              "Per node, median ms over the last frames (in a pipelined run a node's interval",
              "includes waiting for the GIL and for copies):", ""]
    lines += _stage_table(report, ["extract_match", "extract_match_primitive", "frontend_mono",
                                   "frontend_stereo", *batched_keys])
    lines += ["", "What the pose pool did per batch (the chain's waits: for the batch's frame jobs, and for",
              "keyframe cores speculated or guessed on the pool; jobs started and dropped unstarted (the",
              "essential cores started: frame jobs, guess jobs, keyframe cores and misses; frame jobs",
              "without core leave it to the chain's speculation, its cores in 'cores speculated by the chain');",
              "batched_mono_fifo: the pool in submit order, no guessed cores, as before them; counts include",
              "the verification of the run's graph in the chain-in-this-process row (a chain process answers",
              "it dry); chain wall and CPU: the chain's wall time and its",
              "thread's CPU time, whose gap is what it waited for: the pool, the GIL, a free core; measured",
              "in the chain process but for the chain-in-this-process row):", "",
              "| run | chain waits, frame jobs (ms) | chain waits, keyframe cores (ms) | chain computes cores "
              "(ms) | frame jobs | frame jobs without core | guess jobs | guesses dropped | cores speculated by the chain "
              "| those dropped | cores on the spot (misses) | chain wall (ms) | chain CPU (ms) |",
              "| --- |" + " --- |" * 12]
    for key in batched_keys:
        b = report[key].get("pool_per_batch")
        cells = [f"{b[f'chain_{k}_ms']:.2f}" for k in ("wait_ahead", "wait_keyframe", "on_the_spot")] \
            + [f"{b.get(k, 0):.1f}" for k, *_ in POOL_COUNTS] \
            + [f"{b[f'chain_{k}_ms']:.2f}" for k in ("wall", "cpu")] if b else ["n/a"] + [""] * 11
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    lines += ["", "| accuracy | ATE (m) | RPE t (m) | RPE r (deg) |", "| --- | --- | --- | --- |"]
    for k, v in report["accuracy"].items():
        lines.append(f"| {k} | {v['ate_m']:.4f} | {v['rpe1_t_m']:.4f} | {v['rpe1_r_deg']:.3f} |")
    for k in ("frontend_mono", "frontend_stereo", *batched_keys):
        s = report[k]["plan"]
        if s is None:
            lines += ["", f"{k}: FAILED ({report[k].get('error')})"]
            continue
        measured = s["measured_makespan_ms"]
        lines += ["", f"{k}: placement {s['placement']}; predicted makespan "
                      f"{s['predicted_makespan_ms']:.2f} ms, measured (median frame latency, "
                      f"pipelined) {measured:.2f} ms" if measured is not None else "n/a"]
    return lines


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="warp-cpu, 12 unique frames, 30 timed")
    p.add_argument("--backend", default=None, help="default: cuda (warp-cpu with --quick)")
    p.add_argument("--frames", type=int, default=600, help="frames timed (replayed)")
    p.add_argument("--unique", type=int, default=60, help="frames rendered")
    p.add_argument("--size", default="1241x376")
    p.add_argument("--castle", default=str(CASTLE), help="castle_simu folder (skipped if absent)")
    p.add_argument("--batch", type=int, default=16, help="frames per batch of the batched mode (default 16)")
    p.add_argument("--match-batch", type=int, default=32,
                   help="also time extraction + matching at this batch (0: skip; default 32)")
    p.add_argument("--workers", type=int, default=None,
                   help="pose processes (default: orbslam_batch.default_workers(), all cores but three)")
    p.add_argument("--out", default=os.path.join(os.environ.get("OUT") or ".", "orbslam"),
                   help="output folder (default: $OUT/orbslam)")
    p.add_argument("--markdown", type=Path, default=None, metavar="JSON",
                   help="only write orbslam_bench.md (into --out) from a run's orbslam_bench.json")
    args = p.parse_args(argv)
    if args.markdown is not None:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "orbslam_bench.md").write_text("\n".join(markdown(json.loads(args.markdown.read_text()))) + "\n")
        return 0
    backend = args.backend or ("warp-cpu" if args.quick else "cuda")
    n_unique, n = (12, 32) if args.quick else (args.unique, args.frames)
    batch = 4 if args.quick else args.batch
    size = tuple(int(v) for v in args.size.lower().split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    command = " ".join(["PYTHONPATH=. python3 benchmarks/orbslam_bench.py",
                        *(argv if argv is not None else sys.argv[1:])])
    report = {"command": command, "backend": backend, "size": size, "frames_timed": n,
              "frames_rendered": n_unique, "cpu_count": os.cpu_count(), "opencv": cv2.__version__}
    started = time.perf_counter()

    def progress(what, value):
        print(f"[{time.perf_counter() - started:6.1f} s] {what}: {value}", flush=True)

    t = time.perf_counter()
    left, right, K, gt = render_sequence(n_unique, size, baseline=0.54, step=0.25, supersample=1)
    report["render_s"] = time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        paths = [os.path.join(tmp, f"{i:06d}.png") for i in range(n_unique)]
        for path, img in zip(paths, left):
            cv2.imwrite(path, img)
        t = time.perf_counter()
        for path in paths:
            cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        report["png_read_ms_per_frame"] = 1e3 * (time.perf_counter() - t) / n_unique
    progress("rendered", f"{n_unique} frames in {report['render_s']:.1f} s")

    mono = o.Camera(K, size)
    stereo = o.Camera(K, size, 0.54)
    mono_frames = [{"image": im} for im in left]
    stereo_frames = [{"image": a, "right": b} for a, b in zip(left, right)]
    images = replay(left, n)
    failed = {"fps": float("nan"), "stages_ms": {}, "track_ms_median": float("nan"), "plan": None}

    def attempt(what, fn, fallback):
        """``fn()``; on an error its traceback, and ``fallback`` with the error, so one broken
        section does not cost the other numbers of the (single) GPU run."""
        try:
            return fn()
        except Exception as exc:  # noqa: BLE001 - reported in the table and the JSON
            traceback.print_exc()
            progress(f"{what} FAILED", exc)
            return dict(fallback, error=f"{type(exc).__name__}: {exc}")

    for key, primitive, what in (("extract_match", False, "match node"),
                                 ("extract_match_primitive", True, "match_hamming primitive")):
        report[key] = attempt(what, lambda: bench_extract_match(images, backend, primitive=primitive), failed)
        progress(f"extraction+matching ({what}) FPS", f"{report[key]['fps']:.1f}")
    for key, frames, camera, name in (("frontend_mono", mono_frames, mono, "mono"),
                                      ("frontend_stereo", stereo_frames, stereo, "stereo")):
        report[key] = attempt(name, lambda: bench_frontend(replay(frames, n), camera, backend, out, name)[0],
                              failed)
        progress(f"front end {name} FPS", f"{report[key]['fps']:.1f}")
    # The batched mode: one chain process with its pool of pose processes for all its runs
    # (opened before timing).
    # (--workers 0: neither, the pose work and the chain in this process)
    pool = ob.make_pool(args.workers, chain_process=True) if args.workers != 0 else None
    report["batch"] = {"batch": batch, "workers": 0 if pool is None else pool.workers,
                       "look_ahead": None if pool is None else osp.look_ahead(pool)}
    progress("pose pool", f"{report['batch']['workers']} processes")
    try:
        for b in sorted({batch, args.match_batch if not args.quick else batch} - {0}):
            key = f"extract_match_batch{b}"
            report[key] = attempt(f"batched matching {b}", lambda: bench_extract_match_batched(images, backend, b),
                                  failed)
            progress(f"extraction+matching batched (B={b}) FPS", f"{report[key]['fps']:.1f}")
        for key, cam, name, config, settings, switch in BATCHED:
            camera, frames = (mono, mono_frames) if cam == "mono" else (stereo, stereo_frames)
            report[key] = attempt(key, lambda: bench_frontend_batched(replay(frames, n), camera, backend, out, name,
                                                                      batch, pool, config=config, settings=settings,
                                                                      switch=switch)[0],
                                  failed)
            progress(f"front end {key} (B={batch}) FPS", f"{report[key]['fps']:.1f}")
        if pool is not None:
            # The default run as a first run: its graph built and verified inside the timed call.
            report[FIRST_CALL] = attempt(FIRST_CALL, lambda: bench_frontend_batched(
                replay(mono_frames, n), mono, backend, out, None, batch, pool, first_call=True)[0], failed)
            progress(f"front end {FIRST_CALL} FPS", f"{report[FIRST_CALL]['fps']:.1f}")
            # The same pose work on multiprocessing's stock Pool (its handler thread spins
            # while results wait): a pool of its own, opened before timing.
            with ob.ChainProcess(pool.workers, quiet=False) as stock:
                report[STOCK_POOL] = attempt(STOCK_POOL, lambda: bench_frontend_batched(
                    replay(mono_frames, n), mono, backend, out, None, batch, stock)[0], failed)
            progress(f"front end {STOCK_POOL} FPS", f"{report[STOCK_POOL]['fps']:.1f}")
        old = max(2, os.cpu_count() - 1)  # the pool's default before default_workers()
        if args.workers is None and pool is not None and old != pool.workers:
            with ob.make_pool(old, chain_process=True) as more:
                report[OLD_POOL] = attempt(OLD_POOL, lambda: bench_frontend_batched(
                    replay(mono_frames, n), mono, backend, out, None, batch, more)[0], failed)
            report[OLD_POOL]["workers"] = old
            progress(f"front end {OLD_POOL} ({old} processes) FPS", f"{report[OLD_POOL]['fps']:.1f}")
        batched = {name: attempt(f"accuracy batched {name}", lambda: np.array(
            [f.pose for f in ob.track_frames_batched(frames, camera, config, batch=batch, pool=pool,
                                                     workers=0, chain_process=False, backend=backend)]), None)
            for name, frames, camera, config in (("mono", mono_frames, mono, o.TrackerConfig()),
                                                 ("stereo", stereo_frames, stereo, o.TrackerConfig()),
                                                 ("mono_prev", mono_frames, mono, PREVIOUS_ONLY))}
    finally:
        if pool is not None:
            pool.shutdown()
    # The chain in this process (the path before the chain process): its own pose pool.
    inproc = ob.make_pool(args.workers) if pool is not None else None
    try:
        if inproc is not None:
            report[CHAIN_IN_PROCESS] = attempt(CHAIN_IN_PROCESS, lambda: bench_frontend_batched(
                replay(mono_frames, n), mono, backend, out, None, batch, inproc)[0], failed)
            progress(f"front end {CHAIN_IN_PROCESS} FPS", f"{report[CHAIN_IN_PROCESS]['fps']:.1f}")
            batched["mono_in_process"] = attempt("accuracy batched mono in process", lambda: np.array(
                [f.pose for f in ob.track_frames_batched(mono_frames, mono, batch=batch, pool=inproc,
                                                         backend=backend)]), None)
        report["pose_pool"] = attempt("pose pool", lambda: bench_pose_pool(mono_frames, mono, batch, inproc), {}) \
            if inproc is not None else {"error": "no pool (--workers 0)"}
        progress("pose_batch alone (ms/frame): one process vs pool", report["pose_pool"])
    finally:
        if inproc is not None:
            inproc.shutdown()
    report["opencv_baseline"] = bench_opencv(replay(left, min(n, 200)), K)
    progress("opencv", report["opencv_baseline"])
    # Accuracy on the rendered sequence itself (no replay), and on castle_simu when present.
    nan = {"ate_m": float("nan"), "rpe1_t_m": float("nan"), "rpe1_r_deg": float("nan")}
    sequential = {name: attempt(f"accuracy {name}", lambda: np.array(
        [f.pose for f in o.track_frames(frames, camera, backend=backend)]), None)
        for name, frames, camera in (("mono", mono_frames, mono), ("stereo", stereo_frames, stereo))}
    report["accuracy"] = {}
    for name, label in (("mono", "Sim3"), ("stereo", "SE3")):
        modes = [("", sequential[name]), (f" batched B={batch}", batched[name])]
        if name == "mono":
            modes.append((f" batched B={batch}, keyframe_motion off", batched["mono_prev"]))
        for mode, poses in modes:
            ok = isinstance(poses, np.ndarray)
            report["accuracy"][f"rendered: warpvx_{name}{mode} ({label})"] = \
                accuracy(poses, gt, name == "mono") if ok else dict(nan, error=str(poses))
    report["accuracy"]["rendered: opencv_baseline (Sim3)"] = accuracy(o.opencv_baseline(left, K), gt, True)
    report["batch"]["max_pose_difference_vs_sequential"] = {
        name: float(np.abs(batched[name] - sequential[name]).max())
        if isinstance(batched[name], np.ndarray) and isinstance(sequential[name], np.ndarray) else None
        for name in ("mono", "stereo")}
    ok = [isinstance(batched.get(k), np.ndarray) for k in ("mono", "mono_in_process")]
    report["batch"]["max_pose_difference_chain_process_vs_in_process"] = \
        float(np.abs(batched["mono"] - batched["mono_in_process"]).max()) if all(ok) else None
    if os.path.isdir(args.castle):
        for k, v in attempt("castle", lambda: castle_accuracy(args.castle, backend), {}).items():
            if k != "error":
                report["accuracy"][f"castle_simu: {k}"] = v
    progress("accuracy", "done")

    lines = markdown(report)
    (out / "orbslam_bench.md").write_text("\n".join(lines) + "\n")
    (out / "orbslam_bench.json").write_text(json.dumps(report, indent=2, default=str))
    print("\n".join(lines))
    progress("total", "done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
