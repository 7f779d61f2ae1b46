"""Graph runtime experiment: predicted vs measured makespans per policy, Gantt charts,
executor overhead and a soak run.

The graph (16 nodes): two camera streams, each running color convert (BGR2GRAY), a Gaussian
pyramid, Harris corners (the points to track), a 7x7 Gaussian blur and FAST on it
(keypoints), pyramidal LK from the previous frame (delays of the pyramid and of the points)
and a homography estimate (a CPU-only user node calling cv2.findHomography with RANSAC); a
CPU-only user node combines the two homographies, and a GPU-only user node (a Warp
"detector" standing in for the thesis' deep-learning node) runs on camera L's gray image.
OpenCV runs single-threaded (``--cv-threads 1``): each CPU worker is one core, as calibrated.

With ``two-cameras-cv`` (``--graphs``) each camera also runs a bilateral filter and Canny
edges, and one node combines them: OpenCV user nodes, CPU only (21 nodes).

Steps, per graph and camera size (default 1280x720 and 1920x1080):

1. verify on two real consecutive frames and calibrate (cached per machine); once, the GIL
   switch interval and executor spin are chosen (``--switch-interval``, ``--spin`` fix them);
2. the plans' first round (discarded), the model's probes (contention, GIL shares: they load
   every core for seconds; run between the training and the later rounds, the later rounds
   started 14-17% slower on the H100), then interleaved rounds, discarded, until the
   machine settles (``SETTLE_PCT``, at most ``SETTLE_ROUNDS``); baseline, heft and xeft run
   their first ``--fit-frames`` frames in interleaved rounds (as in step 3); the contention
   model (:mod:`warpvx.graph.model`) is fitted on ``--train``'s
   (baseline, calibrated costs); ``best`` takes its candidates (baseline, HEFT and XEFT on the calibrated and on the
   model's costs) and tries those predicted within 20% of the fastest (the model's error),
   and the runner-up if within 50% (its worst out-of-sample error on mixed placements),
   in ``--trial-rounds`` interleaved rounds of ``--trial-frames`` frames, keeping the least
   median makespan;
3. baseline, heft, xeft and best (joining here) run the later rounds up to ``--frames``
   frames each, one at a time, in interleaved rounds of ``--block`` frames (A B C D, D C B A, ...; warm-up frames after
   each switch discarded): a drift of the machine (the same placement measured 30-40%
   apart minutes later on the H100) falls on every policy alike; then each is pipelined
   (``--depth`` in flight, FPS); before each round a fixed single-threaded OpenCV call is
   timed (the CPU's speed then), with our process's CPU use while idle and the machine's
   busy and steal time over the round (``round_log``: the machine's drift, told apart from
   ours);
4. per policy: predicted in sample (a model on the frames it learnt from) and out of sample
   (the training model on the frames after the first ``--fit-frames``, and on those of the
   rounds right after training), errors, the noise floor (the same placement's even rounds
   against its odd rounds), its drift (later rounds over its training rounds), and whether best is
   within 5% of the fastest measured; Gantt charts of the prediction over a measured frame
   (``gantt_<graph>_<size>_<policy>.png``) and of 3 pipelined frames (``..._pipelined.png``),
   packed into ``gantt.tar`` (each graph's best chart also beside it: results come back from
   the GPU machine as at most 8 files);
5. the executor's per-node overhead with trivial nodes (CPU-only, GPU-only, alternating
   chains) and, with ``--soak N``, N frames pipelined with memory at start and end.

Writes ``graph_bench.json`` and ``graph_bench.md`` (its first line is the command). The JSON
keeps each policy's fit frames (``fit_frames_data``), per-frame makespans and the contention
probe, so ``--replay graph_bench.json`` refits the model offline and predicts every policy
again (no frames run; older results without frames are replayed from node medians).

Usage::

    PYTHONPATH=. python benchmarks/graph_bench.py --gpu cuda --out $OUT/graph   # GPU machine
    python benchmarks/graph_bench.py --quick         # anywhere: warp-cpu, 160x120, few frames
    python benchmarks/graph_bench.py --overhead-only # the overhead section alone: overhead.md
    PYTHONPATH=. python benchmarks/graph_bench.py --replay benchmarks/results/graph/h100-2026-11-24/graph_bench.json
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np
import warp as wp

# This checkout's warpvx, with or without PYTHONPATH=. (an installed one may be older).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import warpvx  # noqa: E402
from warpvx.backend import init_warp  # noqa: E402
from warpvx.graph import default_n_cpus  # noqa: E402
from warpvx.graph.costs import SWITCH_WARMUP, TRIAL_ROUNDS  # noqa: E402
from warpvx.graph.diagnostics import executor_overhead, soak  # noqa: E402
from warpvx.graph.model import eager_nodes, graph_reads  # noqa: E402
from warpvx.runtime import executor  # noqa: E402

POLICIES = ("baseline", "heft", "xeft", "best")
#: The policies run from the first rounds on (best is chosen after them).
SCHEDULERS = POLICIES[:-1]
#: Frames of each plan in a first interleaved round, discarded: a new plan's first 4-6
#: frames (its captures recorded) and the first frames after the first switches ran 7-22 ms
#: against 4-5 on the H100 (s3-s5 at 1920x1080), beyond the SWITCH_WARMUP frames discarded
#: after a switch: 4 of the 20 training frames there.
PLAN_WARMUP = 8
#: Gantt PNGs go to this folder of --out, packed into gantt.tar at the end (results come
#: back from the GPU machine as at most 8 files); each graph's best chart stays beside it.
GANTT_DIR = "gantt"
#: Before the training rounds, interleaved rounds of every plan (discarded) run until the
#: machine runs them as in the round before: each plan's median within SETTLE_PCT % of its
#: previous round's on average, at most SETTLE_ROUNDS rounds. The model's probes load every
#: core for seconds; on the H100 the rounds after them ran 14-17% slower than the rounds
#: before (s6, s6b at 1280x720), easing off over the next rounds.
SETTLE_PCT = 5.0
SETTLE_ROUNDS = 5
#: Rounds right after the training rounds, the nearest in time: the out-of-sample error is
#: also given against them (a drift of the machine over the later rounds left out).
NEAR_ROUNDS = 2
#: A fixed CPU-only reference timed in the caller's thread between rounds (ms): it moves
#: with the machine's speed, not with anything of the runtime's.
REFERENCE_SIZE = (640, 360)
ROOT = Path(__file__).resolve().parent
DETECTOR_ITERS = 8


# --------------------------------------------------------------------------- a GPU-only node


@wp.kernel
def smooth_response(src: wp.array2d(dtype=wp.float32), dst: wp.array2d(dtype=wp.float32)):
    y, x = wp.tid()
    h = src.shape[0]
    w = src.shape[1]
    acc = float(0.0)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            yy = wp.clamp(y + dy, 0, h - 1)
            xx = wp.clamp(x + dx, 0, w - 1)
            acc += src[yy, xx]
    dst[y, x] = wp.tanh(acc / 25.0 - 0.5)


@wp.kernel
def to_float(src: wp.array2d(dtype=wp.uint8), dst: wp.array2d(dtype=wp.float32)):
    y, x = wp.tid()
    dst[y, x] = float(src[y, x]) / 255.0


_DETECTOR_SCRATCH: dict = {}  # (shape, device) -> two float32 images, for calls with out=


def detector_warp(gray, out=None):
    """A stand-in for a network: DETECTOR_ITERS 5x5 nonlinear filter passes (GPU only).

    ``out``: the float32 HxW result buffer (the graph's: the node is declared capturable, so
    with ``out`` nothing is allocated; the scratch images are kept per size and device).
    """
    if out is None:
        bufs = [wp.empty(gray.shape, dtype=wp.float32, device=gray.device) for _ in range(2)]
    else:
        key = (tuple(gray.shape), str(gray.device))
        bufs = _DETECTOR_SCRATCH.get(key) or _DETECTOR_SCRATCH.setdefault(
            key, [wp.empty(gray.shape, dtype=wp.float32, device=gray.device) for _ in range(2)])
    src = bufs[0]
    wp.launch(to_float, dim=gray.shape, inputs=[gray], outputs=[src], device=gray.device)
    for i in range(DETECTOR_ITERS):
        dst = out if out is not None and i == DETECTOR_ITERS - 1 else bufs[(i + 1) % 2]
        wp.launch(smooth_response, dim=gray.shape, inputs=[src], outputs=[dst], device=gray.device)
        src = dst
    return src


# --------------------------------------------------------------------------- CPU-only nodes


def homography(prev_pts, next_pts, status):
    """RANSAC homography from tracked points (identity with fewer than 8 tracks)."""
    ok = np.asarray(status).reshape(-1) == 1
    p0 = np.asarray(prev_pts, np.float32).reshape(-1, 2)[ok]
    p1 = np.asarray(next_pts, np.float32).reshape(-1, 2)[ok]
    if len(p0) < 8:
        return np.eye(3)
    H, _ = cv2.findHomography(p0, p1, cv2.RANSAC, 3.0)
    return np.eye(3) if H is None else H


def fuse(h_left, h_right):
    """Mean translation of the two cameras' homographies (a rig-motion estimate)."""
    return np.array([(h_left[0, 2] + h_right[0, 2]) / 2, (h_left[1, 2] + h_right[1, 2]) / 2])


# --------------------------------------------------------------------------- graph and frames


def denoise(gray):
    """Edge-preserving smoothing (OpenCV bilateral filter, CPU only)."""
    return cv2.bilateralFilter(gray, 7, 40.0, 5.0)


def edges(gray):
    """Canny edge map (CPU only)."""
    return cv2.Canny(gray, 60, 140)


def edge_density(e_left, e_right):
    """Share of edge pixels in each camera (CPU only)."""
    return np.array([np.count_nonzero(e_left), np.count_nonzero(e_right)]) / e_left.size


def build_graph(size, *, max_corners=500, levels=4, cpu_heavy=False, homography_fn=None,
                detector=True, homography_process=False) -> warpvx.Graph:
    """The two-camera graph (16 nodes); ``cpu_heavy`` adds per camera a bilateral filter and
    Canny edges and one node combining them (OpenCV user nodes, CPU only: 21 nodes).
    Variants for diagnostics (``benchmarks/perf/pipeline_bottleneck.py``): ``homography_fn``
    in place of :func:`homography`, and ``detector=False`` leaves out ``detectorL`` and its
    output (15 nodes); ``homography_process`` runs the homographies in worker processes
    (``Graph.user(..., process=True)``)."""
    w, h = size
    g = warpvx.Graph("two-cameras-cv" if cpu_heavy else "two-cameras")
    cv_edges = []
    homs = []
    for cam in ("L", "R"):
        frame = g.input(f"frame{cam}", shape=(h, w, 3), dtype=np.uint8)
        gray = g.color_convert(frame, code="BGR2GRAY", name=f"gray{cam}")
        pyr = g.gaussian_pyramid(gray, levels=levels, name=f"pyramid{cam}")
        pts = g.harris_corners(gray, max_corners=max_corners, quality_level=0.01,
                               min_distance=7, name=f"harris{cam}")
        blur = g.gaussian_blur(gray, ksize=(7, 7), sigma=2.0, name=f"blur{cam}")
        kps = g.fast_corners(blur, threshold=20, name=f"fast{cam}")
        prev_pyr = g.delay(pyr, slots=1)
        prev_pts = g.delay(pts, slots=1)
        nxt, status, _err = g.optical_flow_pyr_lk(prev_pyr[-1], pyr, prev_pts[-1],
                                                  win_size=(21, 21), max_level=levels - 1,
                                                  name=f"lk{cam}")
        H = g.user(homography_fn or homography, [prev_pts[-1], nxt, status], "H",
                   name=f"homography{cam}", process=homography_process)
        homs.append(H)
        g.output(f"keypoints{cam}", kps)
        g.output(f"H{cam}", H)
        if cpu_heavy:
            smooth = g.user(denoise, [gray], "smooth", name=f"denoise{cam}")
            cv_edges.append(g.user(edges, [smooth], "edges", name=f"edges{cam}"))
        if cam == "L" and detector:
            det = g.user(None, [gray], "score", warp_fn=detector_warp, name="detectorL",
                         capturable=True)
            g.output("scoreL", det)
    motion = g.user(fuse, homs, "motion", name="fuse")
    g.output("motion", motion)
    if cpu_heavy:
        g.output("edge_density", g.user(edge_density, cv_edges, "density", name="edgeDensity"))
    return g


def source_images(size):
    """Two real views (Middlebury motorcycle via scikit-image), else textured synthetic ones."""
    try:
        from skimage import data

        left, right, _ = data.stereo_motorcycle()
        views = [cv2.cvtColor(v, cv2.COLOR_RGB2BGR) for v in (left, right)]
    except Exception:  # noqa: BLE001 - scikit-image missing on the GPU machine
        from warpvx.graph.data import synth

        views = [synth((size[1] * 2, size[0] * 2, 3), np.uint8, seed=s) for s in (1, 2)]
    return [cv2.resize(v, (size[0] + 64, size[1] + 64), interpolation=cv2.INTER_AREA) for v in views]


def make_frames(size, n):
    """``n`` frames of a slowly panning, slightly rotating camera pair (precomputed)."""
    views = source_images(size)
    w, h = size
    frames = []
    for i in range(n):
        out = {}
        for cam, v in zip(("L", "R"), views):
            angle = 0.3 * np.sin(i / 7.0)
            M = cv2.getRotationMatrix2D((v.shape[1] / 2, v.shape[0] / 2), angle, 1.0)
            M[:, 2] += (-32 + 8 * np.sin(i / 5.0), -32 + 6 * np.cos(i / 6.0))
            out[f"frame{cam}"] = cv2.warpAffine(v, M, (w, h), borderMode=cv2.BORDER_REFLECT)
        frames.append(out)
    return frames


# --------------------------------------------------------------------------- experiment


def run_frames(g, plan, frames):
    """Run ``frames`` one at a time with ``plan`` (the current plan); their FrameResults."""
    runs = []
    for f in frames:
        g.process(f)
        runs.append(plan.last_run[-1])
    return runs


def node_table(plan, runs) -> dict:
    """Per node: where it ran, its calibrated cost there, and medians of what the frames
    measured (interval without transfers, the transfers, the GPU thread's host time)."""
    cal = plan.calibration
    out = {}
    for node, proc in plan.placement.items():
        pe = "gpu" if proc == "gpu" else "cpu"
        got = [r for r in runs if node in r.timeline]
        if not got:
            continue
        host = [r.host[node][1] - r.host[node][0] for r in got if node in r.host]
        out[node] = {
            "pe": proc,
            "calibrated_ms": cal.nodes[node][pe],
            "calibrated_host_ms": cal.nodes[node].get("gpu_host") if pe == "gpu" else None,
            "planned_ms": plan.schedule.tasks[node].finish - plan.schedule.tasks[node].start,
            "measured_ms": statistics.median(r.compute_ms(node) for r in got),
            "transfer_ms": statistics.median(r.transfers.get(node, 0.0) for r in got),
            "host_ms": statistics.median(host) if host else None,
            "start_ms": statistics.median(r.timeline[node].start for r in got),
            "planned_start_ms": plan.schedule.tasks[node].start,
        }
    return out


def copies(runs) -> dict:
    """Bytes copied per frame (medians): uploads by GPU tasks, downloads by CPU tasks."""
    up, down = [], []
    for r in runs:
        up.append(sum(b for t, b in r.copied.items() if r.timeline[t].processor == "gpu"))
        down.append(sum(b for t, b in r.copied.items() if r.timeline[t].processor != "gpu"))
    return {"h2d_bytes": statistics.median(up) if up else 0,
            "d2h_bytes": statistics.median(down) if down else 0}


def device_edges(plan) -> dict:
    """Edges of the frame by where their data lives: GPU->GPU stay on the device."""
    kinds = defaultdict(int)
    place = plan.placement
    for u, v in plan.dag.edges:
        a = "gpu" if place[u] == "gpu" else "cpu"
        b = "gpu" if place[v] == "gpu" else "cpu"
        kinds[f"{a}->{b}"] += 1
    return dict(kinds)


def pipelined(g, plan, frames, depth):
    """Make ``plan`` current and stream ``frames`` through it, ``depth`` in flight: the
    pipelined FrameResults and FPS."""
    g.use_plan(plan)
    t0 = time.perf_counter()
    n = sum(1 for _ in g.stream(frames, depth=depth))
    return list(plan.last_run), n / (time.perf_counter() - t0)


def sequential_fps(runs) -> float:
    """Frames per second one at a time: the median time between consecutive frames'
    submissions (within a round: a switch between plans is a long gap, and the median
    ignores the one per round)."""
    gaps = [b.t0 - a.t0 for a, b in zip(runs, runs[1:])]
    return 1.0 / statistics.median(gaps) if gaps else float("nan")


def halves_drift_pct(runs, block) -> float:
    """The noise floor of one placement: its median makespan over the even rounds against
    the odd rounds (``block`` frames a round), as % of their mean -- two runs of the same
    placement, interleaved with the others like every measurement here."""
    rounds = [runs[i:i + block] for i in range(0, len(runs), block)]
    halves = [[r.makespan for rd in rounds[k::2] for r in rd] for k in (0, 1)]
    if not all(halves):
        return float("nan")
    a, b = (statistics.median(h) for h in halves)
    return 100.0 * abs(a - b) / (0.5 * (a + b))


def median_span(runs) -> float:
    return statistics.median(r.makespan for r in runs)


def _err(pred, meas) -> float:
    return 100.0 * (pred - meas) / meas if meas > 0 else float("nan")


def reference_ms(repeats: int = 3) -> float:
    """Median ms of a fixed single-threaded OpenCV call (:func:`denoise` on a
    :data:`REFERENCE_SIZE` image) in this thread: the machine's CPU speed now."""
    img = reference_ms.image
    return statistics.median(_timed(denoise, img) for _ in range(repeats))


reference_ms.image = np.random.default_rng(0).integers(0, 256, REFERENCE_SIZE[::-1], dtype=np.uint8)


def _timed(fn, *args) -> float:
    t0 = time.perf_counter()
    fn(*args)
    return (time.perf_counter() - t0) * 1e3


def idle_cpu_pct(seconds: float = 0.02) -> float:
    """This process's CPU use (% of one core) while the caller sleeps ``seconds``: the
    runtime's threads between frames should use none (a spinning one shows here)."""
    t, c = time.perf_counter(), time.process_time()
    time.sleep(seconds)
    return 100.0 * (time.process_time() - c) / (time.perf_counter() - t)


def cpu_counters():
    """(wall s, this process's CPU s, the machine's /proc/stat jiffies: busy, steal, all)
    or None where there is no /proc/stat."""
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    idle, steal = v[3] + v[4], v[7] if len(v) > 7 else 0
    return time.perf_counter(), time.process_time(), sum(v) - idle - steal, steal, sum(v)


def round_sample(before, after) -> dict:
    """Between two :func:`cpu_counters`: the machine's busy and steal time (% of all its
    cores' time: another tenant of the host shows as steal) and the cores this process kept
    busy on average."""
    if before is None or after is None:
        return {}
    d = [b - a for a, b in zip(before, after)]
    return {"busy_pct": 100.0 * d[2] / max(d[4], 1), "steal_pct": 100.0 * d[3] / max(d[4], 1),
            "process_cores": d[1] / max(d[0], 1e-9)}


def work_cores(runs) -> float:
    """Cores the frames' tasks kept busy on average: the CPU tasks' intervals and the GPU
    tasks' host calls over the makespans (beside a round's ``process_cores``: what the
    process burnt beyond its tasks, a spinning wait say)."""
    busy = sum((r.host[t][1] - r.host[t][0]) if tl.processor == "gpu" and t in r.host else
               (0.0 if tl.processor == "gpu" else tl.finish - tl.start)
               for r in runs for t, tl in r.timeline.items())
    return busy / max(sum(r.makespan for r in runs), 1e-9)


def rounds(g, plans, frames, n, block, *, start=0, flip=False, log=None) -> list:
    """:meth:`~warpvx.graph.Graph.measure_plans` one round at a time (A B C, C B A, ...;
    ``flip``: C B A first), the inputs going on from ``start``. Appended to ``log`` per
    round: the :func:`reference_ms` and :func:`idle_cpu_pct` before it, its
    :func:`round_sample`, its :func:`work_cores` and its median makespan per plan. Per
    plan, its FrameResults."""
    out = [[] for _ in plans]
    k = start
    for r in range(n):
        order = list(range(len(plans)))
        if (r + flip) % 2:
            order.reverse()
        ref, idle, c0 = reference_ms(), idle_cpu_pct(), cpu_counters()
        got = g.measure_plans([plans[i] for i in order],
                              frames[k % len(frames):] + frames[:k % len(frames)],
                              rounds=1, frames=block, warmup=SWITCH_WARMUP)
        k += len(plans) * (block + SWITCH_WARMUP)
        for i, runs in zip(order, got):
            out[i].extend(runs)
        if log is not None:
            log.append({"reference_ms": ref, "idle_cpu_pct": idle,
                        **round_sample(c0, cpu_counters()),
                        "work_cores": work_cores([x for runs in got for x in runs]),
                        "medians": [median_span(out[i][-block:]) for i in range(len(plans))]})
    return out


def settle(g, plans, frames, block) -> dict:
    """Interleaved rounds of ``plans`` (discarded) until each plan's round median is within
    :data:`SETTLE_PCT` % of its previous round's on average (at most :data:`SETTLE_ROUNDS`):
    the rounds run, the change after each (%), whether it settled, the reference per round."""
    log, changes = [], []
    for r in range(SETTLE_ROUNDS):
        rounds(g, plans, frames, 1, block, start=r * len(plans) * (block + SWITCH_WARMUP),
               flip=bool(r % 2), log=log)
        if r:
            changes.append(100.0 * statistics.mean(
                abs(b / a - 1) for a, b in zip(log[-2]["medians"], log[-1]["medians"])))
            if changes[-1] < SETTLE_PCT:
                break
    return {"rounds": len(log), "change_pct": changes,
            "settled": bool(changes) and changes[-1] < SETTLE_PCT, "log": log}


def experiment(g, frames, args, out_dir, tag: str) -> dict:
    """One graph at one size. The plans' first round is discarded; the model's probes run
    (they load every core for seconds); interleaved rounds run, discarded, until the
    machine settles (:func:`settle`); then baseline, heft and xeft run their first
    ``args.fit_frames`` frames in interleaved rounds; the contention model learns from the
    training policy's; ``best`` is chosen with it (its trial interleaves its candidates);
    then the four policies run the later rounds, up to ``len(frames)`` frames each (best:
    less the first rounds), in interleaved rounds of ``args.block`` (A B C D, D C B A, ...;
    warm-up frames after each switch discarded; a CPU-only reference timed before each
    round), so a drift of the machine falls on every policy alike, and the drift between a
    policy's even and odd rounds is the noise floor. Each policy is predicted in sample (a
    model fitted on the frames it is scored on: the training frames for the training
    policy, its own first frames for the others) and out of sample (the training model
    against its frames after the first ``fit_frames``, and against those of the
    :data:`NEAR_ROUNDS` rounds right after training); its *drift* is its later rounds'
    median over its training rounds'. Gantt charts (predicted over measured, one frame and
    pipelined)."""
    fit_n = min(args.fit_frames, len(frames) - 1)
    plans = {p: g.schedule(p, n_cpus=args.n_cpus, gpu=args.gpu) for p in SCHEDULERS}
    block = min(args.block, len(frames))
    fit_rounds = -(-fit_n // block)
    # A round discarded first: the plans record their captures and switch once.
    g.measure_plans([plans[p] for p in SCHEDULERS], frames, rounds=1, frames=PLAN_WARMUP,
                    warmup=SWITCH_WARMUP)
    # The model: GIL-weighted (busy neighbours counted by their GIL shares), the unweighted
    # one reported beside (replayed on the H100 runs s3-s5, trained on each of baseline, heft
    # and xeft: 78 of 108 cells within 20% out of sample against 70, 81 with the segment
    # prior: benchmarks/results/graph/model-replay-s6.md); not in --quick: its probe times each node
    # beside a Python loop, minutes on Warp's CPU device (calls there hand the GIL over per
    # launch, each waiting a switch interval), so there the unweighted one.
    gil = not args.quick
    # The probes now (measured once, kept in the calibration), not between the training and
    # the later rounds: the rounds after them ran slower on the H100 (s6, s6b).
    g.measure_probes(plans[args.train], gil=gil)
    settled = settle(g, [plans[p] for p in SCHEDULERS], frames, block)
    # Training frames in the regime they predict: the policies' first rounds interleaved as
    # later (frames run alone before the others measured 13-18% faster or 10% slower than the
    # same placement interleaved on the H100: s3-s5 of benchmarks/results/graph/).
    log = []
    first = rounds(g, [plans[p] for p in SCHEDULERS], frames, fit_rounds, block, log=log)
    train_runs = dict(zip(SCHEDULERS, first))[args.train][:fit_n]
    plain = g.fit_model(plans[args.train], runs=train_runs)
    model = g.fit_model(plans[args.train], runs=train_runs, gil=True) if gil else plain
    # best: the model's candidates; those it cannot tell apart are tried in rounds.
    trial = {"trial_inputs": frames, "trial_frames": args.trial_frames,
             "trial_rounds": args.trial_rounds} if args.trial_frames else {}
    plans["best"] = g.schedule("best", n_cpus=args.n_cpus, gpu=args.gpu, model=model, **trial)
    # best joins the later rounds; the inputs go on where the first rounds stopped.
    later_log = []
    later = rounds(g, [plans[p] for p in POLICIES], frames,
                   max(1, -(-len(frames) // block) - fit_rounds), block,
                   start=fit_rounds * len(SCHEDULERS) * (block + SWITCH_WARMUP), log=later_log)
    seq = {p: (runs if p == "best" else first[i] + runs)[:len(frames)]
           for i, (p, runs) in enumerate(zip(POLICIES, later))}
    near = {p: runs[:NEAR_ROUNDS * block] for p, runs in zip(POLICIES, later)}
    drift = {p: _err(median_span(seq[p][fit_n:]), median_span(first[i]))
             for i, p in enumerate(SCHEDULERS)}
    piped, fps = {}, {}
    for policy in POLICIES:
        piped[policy], fps[policy] = pipelined(g, plans[policy], frames, args.depth)
    rows = []
    reads = model.reads
    for policy in POLICIES:
        plan, runs = plans[policy], seq[policy]
        fit_runs = train_runs if policy == args.train else runs[:fit_n]
        own = model if policy == args.train else g.fit_model(plan, runs=fit_runs, gil=gil)
        pred_in, meas_in = own.makespan(plan), median_span(fit_runs)
        pred_out, meas_out = model.makespan(plan), median_span(runs[fit_n:])
        # Which segments' captures failed (they run eagerly from then on): read off the
        # policy's first frames, not the ones the prediction is scored on.
        eager = eager_nodes(fit_runs, reads, model.capturable, plan.placement)
        pred_eager = model.makespan(plan, eager=eager) if eager else pred_out
        pred_plain = plain.makespan(plan) if gil else None
        rows.append({
            "policy": policy,
            "chosen": plan.schedule.info.get("chosen", policy),
            "candidates": plan.schedule.info.get("candidates"),
            "scheduler_ms": plan.schedule.makespan,
            "pred_in_ms": pred_in, "measured_in_ms": meas_in, "error_in_pct": _err(pred_in, meas_in),
            "pred_out_ms": pred_out, "measured_out_ms": meas_out,
            "error_out_pct": _err(pred_out, meas_out),
            "eager": sorted(eager),
            "pred_out_eager_ms": pred_eager, "error_out_eager_pct": _err(pred_eager, meas_out),
            "pred_out_plain_ms": pred_plain,
            "error_out_plain_pct": _err(pred_plain, meas_out) if gil else None,
            "measured_p90_ms": float(np.percentile([r.makespan for r in runs[fit_n:]], 90)),
            "noise_pct": halves_drift_pct(runs, block),
            "drift_pct": drift.get(policy),
            "measured_near_ms": median_span(near[policy]),
            "error_near_pct": _err(pred_out, median_span(near[policy])),
            # The training policy as the reference clock: its drift taken out of the
            # prediction (a machine that slowed down slows every placement alike).
            "error_dedrift_pct": None if policy == args.train else
            _err(pred_out * (1 + drift[args.train] / 100), meas_out),
            "sequential_fps": sequential_fps(runs),
            "pipelined_fps": fps[policy],
            "gpu_nodes": sorted(t for t, p in plan.placement.items() if p == "gpu"),
            "placement": plan.placement,
            "metrics": {k: v for k, v in plan.metrics.items() if k != "idle_per_processor"},
            "nodes": node_table(plan, runs[fit_n:]),
            "fit_nodes": node_table(plan, fit_runs),
            "fit_frames_data": [frame_record(r) for r in fit_runs],
            "makespans": [r.makespan for r in runs],
            "trial_ms": plan.schedule.info.get("trial_ms"),
            "trial_frames": plan.schedule.info.get("trial_frames"),
            "copies": copies(runs[fit_n:]),
            "edges": device_edges(plan),
            "own_model": own.summary(),
        })
        # Charts: the out-of-sample prediction over the frames it predicted.
        plan.prediction = model.predict(plan)
        plan.last_run.clear()
        plan.last_run.extend(runs[fit_n:])
        charts = out_dir / GANTT_DIR
        charts.mkdir(exist_ok=True)
        plan.gantt(charts / f"gantt_{tag}_{policy}.png", title=tag)
        plan.last_run.clear()
        plan.last_run.extend(piped[policy])
        plan.gantt(charts / f"gantt_{tag}_{policy}_pipelined.png", frames=3,
                   title=f"{tag} (depth {args.depth})")
        r = rows[-1]
        print(f"{tag} {policy:9s} in sample {r['pred_in_ms']:8.3f} vs {r['measured_in_ms']:8.3f} ms "
              f"({r['error_in_pct']:+6.1f}%)  out of sample {r['pred_out_ms']:8.3f} vs "
              f"{r['measured_out_ms']:8.3f} ms ({r['error_out_pct']:+6.1f}%)  scheduler "
              f"{r['scheduler_ms']:8.3f}  pipelined {r['pipelined_fps']:7.1f} FPS  gpu: {r['gpu_nodes']}",
              flush=True)
    for plan in plans.values():  # measure_plans keeps every plan's executor warm
        plan.close()
    fastest = min(rows, key=lambda r: r["measured_out_ms"])
    best = rows[-1]
    return {
        "graph": g.name, "tag": tag, "nodes": len(g.nodes), "fit_frames": fit_n,
        "frames": len(frames), "train": args.train, "model": model.summary(), "policies": rows,
        "fastest": fastest["policy"],
        "best_vs_fastest_pct": _err(best["measured_out_ms"], fastest["measured_out_ms"]),
        "calibration": plans["baseline"].calibration.nodes,
        "probe": [[list(k), list(v)] for k, v in
                  plans[args.train].calibration.contention.get(args.n_cpus, {}).items()],
        "gil": plans[args.train].calibration.gil,
        "capturable": sorted(g.capturable_nodes(plans[args.train].gpu)),
        "serial": sorted(model.serial),
        "model_pick": min(best["candidates"], key=best["candidates"].get),
        "drift_pct": drift[args.train],
        "settle": settled,
        "round_log": {"training": log, "later": later_log},
    }


def choose_threading(g, frames, args) -> dict:
    """The GIL switch interval and the executor's spin: median makespan of the heft plan
    under a few values of each; keeps the fastest (``--switch-interval``/``--spin`` fix them).

    Python threads share one interpreter lock: a CPU worker coming back from OpenCV, or the
    GPU thread coming back from a CUDA call, waits for it while another thread runs Python,
    up to the switch interval before it forces a switch.
    """
    sample = frames[: max(4, min(len(frames), 12))]

    def trial():
        plan = g.schedule("heft", n_cpus=args.n_cpus, gpu=args.gpu)
        run_frames(g, plan, sample[:2])
        runs = run_frames(g, plan, sample)
        return median_span(runs)

    out = {"switch": {}, "spin": {}}
    if args.switch_interval is not None:
        chosen = args.switch_interval
    else:
        for s in (0.005, 0.001, 0.0002, 0.00005):
            sys.setswitchinterval(s)
            out["switch"][s] = trial()
        chosen = min(out["switch"], key=out["switch"].get)
    sys.setswitchinterval(chosen)
    if args.spin is not None:
        spin = args.spin
    else:
        for s in (0.0, 3e-5):
            executor.SPIN_SECONDS = s
            out["spin"][s] = trial()
        spin = min(out["spin"], key=out["spin"].get)
    executor.SPIN_SECONDS = spin
    out["chosen"] = chosen
    out["spin_chosen"] = spin
    return out


def _pct(v) -> str:
    return "-" if v is None or v != v else f"{v:.1f}%"


def _signed(v) -> str:
    return "-" if v is None or v != v else f"{v:+.1f}%"


def _fmt(v, spec=".3f"):
    return "-" if v is None else format(v, spec)


def markdown(report) -> str:
    si = report["switch_interval"]
    lines = [
        f"Regenerate: `{report['command']}`",
        "",
        f"# Graph runtime benchmark ({report['mode']})",
        "",
        f"Machine: {report['machine']}; GPU role: {report['gpu']}; CPU workers: "
        f"{report['n_cpus']}; {report['frames']} frames per policy run one at a time in "
        f"interleaved rounds of {report.get('block', '-')} (A B C D, D C B A, ...; "
        f"{SWITCH_WARMUP} warm-up frames discarded after each switch), then pipelined "
        f"(depth {report['depth']}, one policy after the other); OpenCV threads "
        f"{report['cv_threads']}; GIL switch interval {si['chosen'] * 1e3:g} ms; executor spin "
        f"{si['spin_chosen'] * 1e6:g} us.",
        "",
        "The contention model (`warpvx.graph.model`): each node's calibrated cost alone (a "
        "GPU node: its host call) times an in-frame ratio plus a fixed cost per task, times a "
        "per-node correction, plus its copies (the transfer model plus the median extra the "
        "training frames' copies took; copies not timed apart, as in a captured segment, are taken out "
        "of the interval they are in), slowed down by `1 + a * (other CPU workers busy) + b * "
        "(GPU host thread busy)`, with the measured waits between tasks by kind of edge, "
        "played through a simulation of the executor; `a`, `b` from all nodes at once and "
        "from a contention probe (mixes of the graph's nodes run beside each other, alone and loaded in "
        "turn; the heavy CPU nodes also beside each other). A captured GPU segment is played as "
        "one replay: a ratio times its nodes' calibrated device times as its lanes run them "
        "(independent branches side by side, every lane joined before a node that inserts "
        "conditional graph nodes, Harris's and FAST's: `lane_span`) plus a fixed cost, fitted on "
        "the training frames' segments (all of one size: the fixed cost a prior, "
        "`SEGMENT_FIXED_PRIOR`, and all of the lanes' concurrency). "
        "*Settle*: before training, the model's probes run (they load every core for seconds), "
        "then interleaved rounds, discarded, until each plan's round median is within "
        f"{SETTLE_PCT:g}% of its round before (at most {SETTLE_ROUNDS} rounds). "
        "*Training*: the training policy's first frames, in the first rounds (baseline, heft and "
        "xeft interleaved; best joins the later rounds). "
        "*In sample*: a model against the frames it learnt from (the training model for the "
        "training policy, each other policy's own model fitted on its first interleaved "
        "frames). *Out of sample*: the training model against every policy's interleaved "
        "frames after the first ones (target: within 20%). *noise*: the same placement's "
        "median makespan in its even against its odd rounds (two interleaved runs of one "
        "placement): an error below it cannot be told from drift. *drift*: the policy's "
        "later rounds' median over its training rounds' (the training policy's is the "
        "machine's drift as the model sees it: it reproduces those training rounds); *near*: the "
        f"out-of-sample prediction against the {NEAR_ROUNDS} rounds right after training "
        "(nearest in time); *drift out*: the out-of-sample error of the prediction times the "
        "training policy's drift (that policy as the reference clock; not for itself). "
        "*reference*: a fixed single-threaded OpenCV call timed in the "
        "caller's thread before each round (the CPU's speed then, none of the runtime's "
        "work). The model counts each busy "
        "neighbour by its node's GIL pressure and each victim by its sensitivity "
        "(`warpvx.graph.calibration.measure_gil`; not in a quick run); *unweighted*: the same "
        "training frames fitted with every busy thread counted alike. *failed captures known*: "
        "the out-of-sample prediction told which of the plan's segments the executor runs "
        "eagerly, their capture having failed (`warpvx.graph.model.eager_nodes` of the policy's "
        "first frames). *scheduler*: the makespan "
        "the policy's own schedule claims (isolated calibration). `best`: the model's "
        "candidates (baseline, HEFT and XEFT on the calibrated DAG and on the model's "
        "in-frame costs); those predicted within 20% of the fastest (closer than the model "
        "can tell apart), and the runner-up if within 50% (the model's worst out-of-sample "
        f"error on mixed placements), run {report.get('trial_rounds', 1)} interleaved rounds of "
        f"{report.get('trial_frames', 0)} frames each ({SWITCH_WARMUP} warm-up frames discarded "
        "after each switch) and the least median makespan is kept.",
        "",
    ]
    for e in report["experiments"]:
        m = e["model"]
        sd = m["slowdown"]
        lines += [
            f"## {e['tag']} ({e['nodes']} nodes)", "",
            f"Trained on {m['trained_on']}; fit frames 1-{e['fit_frames']}, out of sample "
            f"frames {e['fit_frames'] + 1}-{e['frames']}. Fitted: "
            + "; ".join(f"{pe} ratio {sd[pe]['ratio']:.2f}, fixed {sd[pe].get('overhead_us', 0):.0f} "
                        f"us, slowdown per busy CPU worker {sd[pe].get('per_cpu', 0):.2f}, while "
                        f"the GPU host thread is busy {sd[pe].get('per_gpu', 0):.2f}"
                        for pe in ("cpu", "gpu"))
            + "; copies + " + ", ".join(f"{k} {v:.0f} us" for k, v in m.get("copy_extra_us", {}).items())
            + "; waits (us) " + ", ".join(f"{k} {v:.1f}" for k, v in m["latency_us"].items())
            + (f"; captured segment replay {m['segment_ratio']:.2f} x its nodes' calibrated GPU "
               f"(device) time + "
               f"{m.get('segment_fixed_us', 0):.0f} us, lanes {m.get('segment_lanes', 1.0):.2f}"
               + (f", every lane joined before {', '.join(e['serial'])}" if e.get("serial") else "")
               if m.get("segment_ratio") else "")
            + ".", "", probe_line(e.get("probe") or []), "", drift_line(e), "",
            "| policy | scheduler ms | predicted in sample | measured | error | predicted out "
            "of sample | measured | error | noise | drift | near: measured | error | drift out | "
            "unweighted: predicted | error | failed captures known: predicted | error | p90 ms | "
            "sequential FPS | pipelined FPS | GPU nodes |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
        ]
        for r in e["policies"]:
            name = r["policy"] + (f" ({r['chosen']})" if r["chosen"] != r["policy"] else "")
            lines.append(
                f"| {name} | {r['scheduler_ms']:.3f} | {r['pred_in_ms']:.3f} | "
                f"{r['measured_in_ms']:.3f} | {r['error_in_pct']:+.1f}% | {r['pred_out_ms']:.3f} | "
                f"{r['measured_out_ms']:.3f} | {r['error_out_pct']:+.1f}% | "
                f"{_pct(r.get('noise_pct'))} | {_signed(r.get('drift_pct'))} | "
                f"{_fmt(r.get('measured_near_ms'))} | {_signed(r.get('error_near_pct'))} | "
                f"{_signed(r.get('error_dedrift_pct'))} | "
                f"{_fmt(r.get('pred_out_plain_ms'))} | "
                f"{_pct(r.get('error_out_plain_pct'))} | {_fmt(r.get('pred_out_eager_ms'))} | "
                f"{_signed(r.get('error_out_eager_pct'))}"
                + (f" (eager: {', '.join(r['eager'])})" if r.get("eager") else "")
                + f" | {r['measured_p90_ms']:.3f} | "
                f"{r['sequential_fps']:.1f} | "
                f"{r['pipelined_fps']:.1f} | {len(r['gpu_nodes'])}: {', '.join(r['gpu_nodes'])} |")
        best = e["policies"][-1]
        within = abs(e["best_vs_fastest_pct"]) <= 5.0
        trial = best.get("trial_ms")
        lines += ["", f"Fastest measured: {e['fastest']}; best measured "
                      f"{e['best_vs_fastest_pct']:+.1f}% from it ({'within' if within else 'NOT within'} "
                      f"5%). Best's candidates, predicted ms: "
                      + ", ".join(f"{k} {v:.3f}" for k, v in (best["candidates"] or {}).items())
                      + f". The model alone would pick {e.get('model_pick', '-')}"
                      + ("; trial (median ms, frames): " + ", ".join(
                          f"{k} {v:.3f} ({(best.get('trial_frames') or {}).get(k, '-')})"
                          for k, v in trial.items())
                         if trial else "; no trial (one candidate within the margins)") + ".", ""]
        lines += same_placement_lines(e["policies"])
        lines += ["Per node (out-of-sample frames of each policy): calibrated alone vs measured in "
                  "the frames (interval without transfers; GPU: device interval), ms:", ""]
        for r in e["policies"]:
            lines += [f"{r['policy']}: " + "; ".join(
                f"{n} {t['pe']} {_fmt(t['calibrated_ms'])}/{_fmt(t['measured_ms'])}"
                for n, t in r["nodes"].items()), ""]
    if si["switch"]:
        lines += ["GIL switch interval (heft plan, median makespan): " + ", ".join(
            f"{float(k) * 1e3:g} ms -> {v:.3f} ms" for k, v in si["switch"].items()) + ".", ""]
    tm = report["transfer"]
    lines += [f"Transfer model: h2d {tm['h2d_latency_ms'] * 1e3:.1f} us + "
              f"{tm['h2d_gbps']:.2f} GB/s, d2h {tm['d2h_latency_ms'] * 1e3:.1f} us + "
              f"{tm['d2h_gbps']:.2f} GB/s.", ""]
    if report["overhead"]:
        lines += overhead_lines(report["overhead"])
    if report.get("soak"):
        s = report["soak"]
        gpu = ("n/a" if s["gpu_mem_start_mb"] is None else
               f"Warp mempool in use {s['gpu_mem_start_mb']:.1f} -> {s['gpu_mem_end_mb']:.1f} MB")
        lines += ["", f"Soak: {s['frames']} frames pipelined (depth {s['depth']}) at "
                      f"{s['fps']:.1f} FPS; host RSS {s['rss_start_mb']:.1f} -> "
                      f"{s['rss_end_mb']:.1f} MB; GPU: {gpu}."]
    lines.append("")
    return "\n".join(lines)


CHAIN_TEXT = {"cpu": "one CPU worker", "gpu": "all on the GPU role", "mixed": "alternating CPU/GPU"}


def same_placement_lines(policies) -> list:
    """A line per group of policies that placed every node alike (HEFT and XEFT often do):
    their out-of-sample medians differ only by the machine's drift between rounds, a floor
    under any "within 5% of the fastest" comparison."""
    groups: dict = {}
    for r in policies:
        groups.setdefault(tuple(sorted(r["placement"].items())), []).append(r)
    lines = []
    for rows in groups.values():
        if len(rows) > 1:
            ms = [r["measured_out_ms"] for r in rows]
            lines.append("Identical placements: " + ", ".join(
                f"{r['policy']} {r['measured_out_ms']:.3f} ms" for r in rows)
                + f" (spread {100 * (max(ms) / min(ms) - 1):.1f}%: one placement measured twice).")
    return lines + [""] if lines else []


#: Per-round quantities of the round log in the drift line: key, label, format.
ROUND_FIELDS = (("reference_ms", "CPU reference ms", ".2f"),
                ("idle_cpu_pct", "our CPU % between rounds", ".0f"),
                ("busy_pct", "machine busy %", ".0f"), ("steal_pct", "steal %", ".1f"),
                ("process_cores", "our busy cores", ".2f"),
                ("work_cores", "cores our tasks' intervals span", ".2f"))


def drift_line(e) -> str:
    """The settle phase, the training policy's drift and the per-round machine state (the
    CPU reference, our idle CPU use, the machine's busy and steal time) in words: medians
    over the settle, training and later rounds, and per later round (older results have
    none of them: '')."""
    st, log = e.get("settle"), e.get("round_log")
    if not st:
        return ""
    changes = ", ".join(f"{c:.1f}" for c in st["change_pct"]) or "-"
    text = (f"Settle: {st['rounds']} rounds (change after each, %: {changes}; "
            f"{'settled' if st['settled'] else 'NOT settled'}). Drift of the training policy "
            f"({e['train']}), later over training rounds: {_signed(e.get('drift_pct'))}.")
    phases = {"settle": st["log"], "training": log["training"], "later": log["later"]}
    for key, label, spec in ROUND_FIELDS:
        got = {ph: [x[key] for x in rows if key in x] for ph, rows in phases.items()}
        if not any(got.values()):
            continue
        text += f" {label} (median settle / training / later): " + " / ".join(
            format(statistics.median(v), spec) if v else "-" for v in got.values())
        text += " (per later round: " + ", ".join(format(v, spec) for v in got["later"]) + ")."
    return text


def probe_line(probe) -> str:
    """The contention probe of one experiment in words (:func:`warpvx.graph.calibration.
    measure_contention`: each mix alone and loaded, in interleaved rounds)."""
    parts = [(f"the heavy CPU nodes ({mix}) beside one worker looping them" if loader == "heavy"
              else f"{victim} mix ({len(mix.split(','))} nodes) beside {cpus + gpus} {loader} "
                   "thread(s)")
             + f": {alone:.3f} -> {loaded:.3f} ms (x{loaded / alone:.2f})"
             for (victim, loader), (mix, alone, loaded, cpus, gpus) in probe]
    return "Contention probe: " + ("; ".join(parts) if parts else "none") + "."


def overhead_lines(overhead) -> list:
    """Markdown lines of the executor-overhead section."""
    lines = ["Executor overhead per node (trivial identity nodes, target < 50 us):", ""]
    for o in overhead:
        chain = o.get("chain", "mixed" if o["mixed"] else "cpu")
        line = (f"- {o['n_nodes']} nodes, {CHAIN_TEXT[chain]}, spin {o.get('spin_us', 0):g} us: "
                f"{o['per_node_us']:.1f} us/node (process), {o['per_node_us_stream']:.1f} us/node (stream)")
        b = o.get("breakdown")
        if b and chain == "mixed":
            line += ("; one round: GPU task " + _fmt(b["gpu_task"], ".1f") + " us, CPU task "
                     + _fmt(b["cpu_task"], ".1f") + " us, CPU->GPU hand-off " + _fmt(b["cpu_to_gpu"], ".1f")
                     + " us, GPU->CPU hand-off " + _fmt(b["gpu_to_cpu"], ".1f") + " us")
        elif b and chain == "gpu":
            line += ("; GPU thread per task " + _fmt(b["gpu_task"], ".1f") + " us, between tasks "
                     + _fmt(b["gpu_gap"], ".1f") + " us")
        lines.append(line)
    return lines


def measure_overhead(args) -> list:
    """The overhead section: CPU-only, GPU-only and mixed chains (mixed at spin 0 and 30 us)."""
    n, frames = args.overhead_nodes, args.overhead_frames
    overhead = [
        executor_overhead(n, frames or (20 if args.quick else 200)),
        executor_overhead(n, frames or (20 if args.quick else 200), chain="gpu", gpu=args.gpu),
        executor_overhead(n // 2, frames or (10 if args.quick else 100), chain="mixed",
                          gpu=args.gpu, spin=0.0),
        executor_overhead(n // 2, frames or (10 if args.quick else 100), chain="mixed",
                          gpu=args.gpu, spin=3e-5),
    ]
    for o in overhead:
        print(f"overhead ({o['chain']}, {o['n_nodes']} nodes, spin "
              f"{o['spin_us']:g} us): {o['per_node_us']:.1f} us/node process, "
              f"{o['per_node_us_stream']:.1f} us/node stream; {o.get('breakdown', '')}", flush=True)
    return overhead


def overhead_only(args):
    """``--overhead-only``: the overhead section alone; writes overhead.json and
    overhead.md (never graph_bench.*)."""
    init_warp()
    if args.gpu is None:
        args.gpu = "cuda" if warpvx.cuda_available() else "warp-cpu"
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    if args.overhead_frames is None and args.frames:
        args.overhead_frames = args.frames  # here --frames means frames per chain
    out_dir = args.out or (ROOT / "results" / "graph" / ("quick" if args.quick else ""))
    out_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    overhead = measure_overhead(args)
    machine = f"{platform.node()}|{_gpu_name(args.gpu)}"
    report = {"mode": "overhead-only", "machine": machine, "platform": platform.platform(),
              "python": sys.version.split()[0], "warp": wp.config.version, "gpu": args.gpu,
              "switch_interval": sys.getswitchinterval(), "overhead": overhead,
              "seconds": time.perf_counter() - t_start}
    (out_dir / "overhead.json").write_text(json.dumps(report, indent=1, default=str))
    text = "\n".join([f"# Executor overhead ({machine})", "",
                      f"GPU role: {args.gpu}; GIL switch interval {sys.getswitchinterval() * 1e3:g} ms; "
                      f"Python {report['python']}, Warp {report['warp']}.", ""]
                     + overhead_lines(overhead) + [""])
    (out_dir / "overhead.md").write_text(text)
    print(f"wrote {out_dir / 'overhead.md'} in {report['seconds']:.1f} s")
    return report


def _gpu_name(gpu) -> str:
    if not gpu or not gpu.startswith("cuda"):
        return "no GPU"
    return wp.get_device(gpu).name


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="small sizes, few frames, warp-cpu if no CUDA")
    p.add_argument("--out", type=Path, default=None, help="results folder")
    p.add_argument("--frames", type=int, default=None, help="frames per policy (default 100, quick 24)")
    p.add_argument("--fit-frames", type=int, default=None,
                   help="frames the model learns from (default 20, quick 8); the rest are predicted")
    p.add_argument("--train", default="baseline", choices=("baseline", "heft", "xeft"),
                   help="the policy whose first frames train the out-of-sample model")
    p.add_argument("--n-cpus", type=int, default=None, help="CPU workers (default: cores - 1, max 4)")
    p.add_argument("--gpu", default=None, help="cuda, cuda:N or warp-cpu (default: cuda if present)")
    p.add_argument("--sizes", default=None,
                   help="camera sizes WxH, comma-separated (default 1280x720,1920x1080; quick 160x120)")
    p.add_argument("--size", default=None, help="one camera size (same as --sizes WxH)")
    p.add_argument("--graphs", default="two-cameras,two-cameras-cv",
                   help="two-cameras (16 nodes) and/or two-cameras-cv (more CPU-only OpenCV nodes)")
    p.add_argument("--depth", type=int, default=3, help="frames in flight when pipelined")
    p.add_argument("--trial-frames", type=int, default=5,
                   help="frames per round best runs each candidate the model cannot tell apart "
                        "(0: no trial)")
    p.add_argument("--trial-rounds", type=int, default=TRIAL_ROUNDS,
                   help="interleaved rounds of best's trial")
    p.add_argument("--block", type=int, default=10,
                   help="frames a policy runs per round when the policies are measured in "
                        "interleaved rounds")
    p.add_argument("--replay", type=Path, default=None,
                   help="refit the model on a graph_bench.json's recorded per-node medians and "
                        "print each policy's predicted vs measured makespan (no frames run)")
    p.add_argument("--gil", action="store_true",
                   help="--replay: weigh busy neighbours by the recorded GIL shares")
    p.add_argument("--train-only", action="store_true",
                   help="--replay: train on --train only (default: each of baseline, heft, xeft)")
    p.add_argument("--soak", type=int, default=0, help="also run N frames pipelined, report memory")
    p.add_argument("--soak-seconds", type=float, default=None,
                   help="stop the soak after this long (it reports the frames it ran)")
    p.add_argument("--overhead-nodes", type=int, default=100)
    p.add_argument("--overhead-frames", type=int, default=None,
                   help="frames per overhead chain (default 200 CPU/GPU-only, 100 mixed; quick 20/10)")
    p.add_argument("--overhead-only", action="store_true",
                   help="only the executor-overhead section (seconds; --frames: frames per chain); "
                        "writes overhead.md/.json")
    p.add_argument("--cv-threads", type=int, default=1,
                   help="cv2.setNumThreads for the run (default 1: one core per CPU worker)")
    p.add_argument("--switch-interval", type=float, default=None,
                   help="sys.setswitchinterval for the run (default: the fastest of a few)")
    p.add_argument("--spin", type=float, default=None,
                   help="the executor's spin before blocking, s (default: the faster of 0, 30 us)")
    p.add_argument("--recalibrate", action="store_true")
    args = p.parse_args(argv)
    args.command = "PYTHONPATH=. python benchmarks/graph_bench.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    cv_threads_before = cv2.getNumThreads()
    # Progress lines as they come (a log file is block-buffered: a stalled run said nothing).
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)
    switch_before = sys.getswitchinterval()
    spin_before = executor.SPIN_SECONDS
    cv2.setNumThreads(args.cv_threads)
    try:
        if args.replay:
            return replay_main(args)
        return overhead_only(args) if args.overhead_only else _run(args)
    finally:
        cv2.setNumThreads(cv_threads_before)
        sys.setswitchinterval(switch_before)
        executor.SPIN_SECONDS = spin_before


def _sizes(args) -> list:
    text = args.size or args.sizes or ("160x120" if args.quick else "1280x720,1920x1080")
    return [tuple(int(v) for v in s.split("x")) for s in text.split(",")]


def _run(args):
    init_warp()
    if args.gpu is None:
        args.gpu = "cuda" if warpvx.cuda_available() else "warp-cpu"
    if args.n_cpus is None:
        args.n_cpus = default_n_cpus()
    n_frames = args.frames or (24 if args.quick else 100)
    args.fit_frames = args.fit_frames or (8 if args.quick else 20)
    out_dir = args.out or (ROOT / "results" / "graph" / ("quick" if args.quick else ""))
    out_dir.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    graphs = [n.strip() for n in args.graphs.split(",") if n.strip()]
    unknown = set(graphs) - {"two-cameras", "two-cameras-cv"}
    if unknown:
        raise SystemExit(f"--graphs: unknown {sorted(unknown)}")

    experiments, switch, cal = [], None, None
    for size in _sizes(args):
        frames = make_frames(size, max(n_frames, args.fit_frames + 2))
        for name in graphs:
            g = build_graph(size, max_corners=200 if args.quick else 500,
                            cpu_heavy=name == "two-cameras-cv")
            g.verify(frames[:2])
            cal = g.calibrate(gpu=args.gpu, recalibrate=args.recalibrate,
                              repeats=5 if args.quick else 11)
            print(f"{g.name} {size[0]}x{size[1]}: calibrated {len(cal.nodes)} nodes on "
                  f"{cal.machine} ({len(cal.fresh)} measured now)", flush=True)
            if switch is None:  # once: it sets the process-wide GIL switch interval and spin
                switch = choose_threading(g, frames, args)
                print(f"GIL switch interval {switch['chosen'] * 1e3:g} ms; spin "
                      f"{switch['spin_chosen'] * 1e6:g} us", flush=True)
            e = experiment(g, frames, args, out_dir, f"{g.name}_{size[0]}x{size[1]}")
            print(f"  fastest measured {e['fastest']}; best {e['best_vs_fastest_pct']:+.1f}% from it",
                  flush=True)
            experiments.append(e)
            g.close()
            _write(out_dir, _report(args, cal, n_frames, switch, experiments, [], None, t_start))

    overhead = measure_overhead(args)
    soak_report = None
    if args.soak:
        g = build_graph(_sizes(args)[0], max_corners=200 if args.quick else 500)
        frames = make_frames(_sizes(args)[0], 8)
        g.verify(frames[:2])
        g.schedule("best", n_cpus=args.n_cpus, gpu=args.gpu)
        soak_report = soak(g, lambda i: frames[i % len(frames)], args.soak, depth=args.depth,
                           report_every=max(1, args.soak // 10), max_seconds=args.soak_seconds)
        print(f"soak: {soak_report['frames']} frames, {soak_report['fps']:.1f} FPS, RSS "
              f"{soak_report['rss_start_mb']:.1f} -> {soak_report['rss_end_mb']:.1f} MB", flush=True)
        g.close()
    report = _report(args, cal, n_frames, switch, experiments, overhead, soak_report, t_start)
    _write(out_dir, report)
    pack_charts(out_dir)
    print(f"wrote {out_dir} in {report['seconds']:.1f} s")
    return report


def _report(args, cal, n_frames, switch, experiments, overhead, soak_report, t_start) -> dict:
    up, down = cal.transfer.bandwidth_gbps
    return {
        "mode": "quick" if args.quick else "full",
        "command": args.command,
        "machine": cal.machine,
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "warp": wp.config.version,
        "gpu": args.gpu,
        "n_cpus": args.n_cpus,
        "frames": n_frames,
        "depth": args.depth,
        "trial_frames": args.trial_frames,
        "trial_rounds": args.trial_rounds,
        "block": args.block,
        "cv_threads": args.cv_threads,
        "switch_interval": switch,
        "experiments": experiments,
        "transfer": {"h2d_latency_ms": cal.transfer.h2d_latency, "h2d_gbps": up,
                     "d2h_latency_ms": cal.transfer.d2h_latency, "d2h_gbps": down},
        "dispatch": cal.dispatch,
        "overhead": overhead,
        "soak": soak_report,
        "seconds": time.perf_counter() - t_start,
    }


# --------------------------------------------------------------------------- replay

#: Fields of a task in a recorded frame (graph_bench.json's ``fit_frames_data``).
FRAME_FIELDS = ("processor", "start_ms", "finish_ms", "transfer_ms", "copied_bytes",
                "host_start_ms", "host_finish_ms")


def frame_record(run) -> dict:
    """A FrameResult's timeline as JSON: task -> :data:`FRAME_FIELDS` (what the contention
    model's fit reads), so the fit can be replayed offline."""
    out = {}
    for task, t in run.timeline.items():
        h = run.host.get(task, (None, None))
        out[task] = [t.processor, t.start, t.finish, run.transfers.get(task, 0.0),
                     run.copied.get(task, 0), h[0], h[1]]
    return out


def recorded_frame(record: dict):
    """:func:`frame_record` back to a FrameResult."""
    from warpvx.runtime.timeline import FrameResult
    from warpvx.sched.schedule import ScheduledTask

    timeline, transfers, copied, host = {}, {}, {}, {}
    for task, (proc, s, f, tr, nb, h0, h1) in record.items():
        timeline[task] = ScheduledTask(task, proc, s, f)
        transfers[task], copied[task] = tr, nb
        if h0 is not None:
            host[task] = (h0, h1)
    return FrameResult(0, {}, timeline, 0.0, transfers, copied, host)



def replay_frame(table: dict):
    """A FrameResult rebuilt from a policy's recorded per-node medians (``nodes`` of
    graph_bench.json): each node's interval from its median start, its median measured
    time plus transfers; a GPU node's host call from the same start for its median host
    time (no copied bytes: the caller works them out)."""
    record = {}
    for n, t in table.items():
        s, host = t["start_ms"], t["host_ms"]
        record[n] = [t["pe"], s, s + t["measured_ms"] + t["transfer_ms"], t["transfer_ms"], 0,
                     None if host is None else s, None if host is None else s + host]
    return recorded_frame(record)


def experiments_of(report: dict) -> list:
    """A graph_bench.json's experiments; a result of the one-graph format (before
    2026-11-24: one 16-node graph, no fit frames, ``calibrated``/``history`` policies) as
    one experiment whose policies were measured on all their frames."""
    if "experiments" in report:
        return report["experiments"]
    w, h = report["size"]
    policies = [{**p, "policy": p["policy"] + ("" if p.get("costs", "calibrated") == "calibrated"
                                               else f" ({p['costs']})"),
                 "measured_out_ms": p["measured_ms"]} for p in report["policies"]]
    return [{"graph": "two-cameras", "tag": f"two-cameras_{w}x{h}",
             "calibration": report["calibration"], "policies": policies}]


_SERIAL: dict = {}
_READS: dict = {}


def bench_reads(graph: str, size, max_corners: int) -> dict:
    """:func:`~warpvx.graph.model.graph_reads` of the bench's ``graph`` at ``size`` (verified
    on 2 frames: the data sizes are the input size's), cached per graph and size: a replay
    refits every experiment, and a results folder holds the same graphs and sizes many times."""
    key = (graph, tuple(size), max_corners)
    if key not in _READS:
        g = build_graph(size, max_corners=max_corners, cpu_heavy=graph == "two-cameras-cv")
        try:
            g.verify(make_frames(size, 2))
            _READS[key] = graph_reads(g)
        finally:
            g.close()
    return _READS[key]


def serial_nodes(graph: str, size, max_corners: int) -> frozenset:
    """The GPU nodes of the bench's ``graph`` at ``size`` that insert conditional graph nodes
    (a captured segment's lanes join before each: ``ContentionModel.serial``), for results
    that did not record them (before session 9): found as the executor finds them, by its
    segments' first runs, on Warp's CPU device with capture forced (a few frames; the same
    code paths as on CUDA, where the rule is the input size's); cached per graph and size."""
    key = (graph, tuple(size), max_corners)
    if key not in _SERIAL:
        g = build_graph(size, max_corners=max_corners, cpu_heavy=graph == "two-cameras-cv")
        try:
            frames = make_frames(size, 3)
            g.verify(frames[:2])
            plan = g.schedule("baseline", n_cpus=1, gpu="warp-cpu")
            for f in frames:
                g.process(f, capture=True)
            _SERIAL[key] = plan.serial_tasks
        finally:
            g.close()
    return _SERIAL[key]


def replay_models(report: dict, train: str = "baseline", *, gil: bool = False):
    """Per experiment of a graph_bench.json, the contention model refit offline on
    ``train``'s recorded fit frames (``fit_frames_data`` and the contention ``probe``;
    results older than those: one frame rebuilt from its later frames' node medians, no
    probe; ``gil``: busy neighbours weighed by the recorded GIL shares). Yields
    ``(experiment, model, policy -> its recorded Schedule)``."""
    import types

    from warpvx.graph.calibration import TransferModel
    from warpvx.graph.model import copied_bytes, fit
    from warpvx.sched.schedule import Schedule, ScheduledTask

    tm = report["transfer"]
    transfer = TransferModel(tm["h2d_latency_ms"], 1e-6 / tm["h2d_gbps"],
                             tm["d2h_latency_ms"], 1e-6 / tm["d2h_gbps"])
    procs = ["gpu"] + [f"cpu{i}" for i in range(report["n_cpus"])]
    for e in experiments_of(report):
        w, h = (int(v) for v in e["tag"].rsplit("_", 1)[1].split("x"))
        reads = bench_reads(e["graph"], (w, h), 200 if report["mode"] == "quick" else 500)
        cal = types.SimpleNamespace(nodes=e["calibration"], gpu=report["gpu"], transfer=transfer,
                                    dispatch=report["dispatch"])
        src = next(p for p in e["policies"] if p["policy"] == train)
        placement = src["placement"]
        if src.get("fit_frames_data"):
            frames = [recorded_frame(r) for r in src["fit_frames_data"]]
        else:  # older results: one frame rebuilt from the node medians
            table = src["nodes"]
            frames = [replay_frame(table)]
            frames[0].copied.update(copied_bytes(
                reads, placement, sorted(table, key=lambda n: table[n]["start_ms"])))
        probe = {tuple(k): tuple(v) for k, v in e.get("probe") or []}
        serial = e["serial"] if "serial" in e else serial_nodes(
            e["graph"], (w, h), 200 if report["mode"] == "quick" else 500)
        model = fit(cal, reads, frames, placement, policy=train, probe=probe,
                    gil=e.get("gil") if gil else None, capturable=e.get("capturable", ()),
                    serial=serial)
        yield e, model, {p["policy"]: Schedule(
            {n: ScheduledTask(n, t["pe"], t["planned_start_ms"], t["planned_start_ms"] + t["planned_ms"])
             for n, t in p["nodes"].items()}, procs) for p in e["policies"]}


def replay(report: dict, train: str = "baseline", *, gil: bool = False) -> list:
    """:func:`replay_models`' models predicting every policy's recorded plan. Rows: tag,
    policy, predicted ms, measured ms (later frames), error %, and ``pooled``: the error
    against the mean measured makespan of every policy that ran the same schedule
    (identical plans measured in separate runs differ by up to 25% on the H100, a noise
    floor no model can beat per run); ``pred_eager_ms``/``error_eager_pct``: the
    prediction told which of the plan's capturable tasks ran eagerly
    (:func:`~warpvx.graph.model.eager_nodes` of its recorded frames: which segment
    captures failed, not how long anything took; ``eager``); ``measured_first_ms``: the
    median of its first frames (the training rounds, where recorded)."""
    rows = []
    for e, model, schedules in replay_models(report, train, gil=gil):
        same = defaultdict(list)
        for p in e["policies"]:
            same[_plan_key(p)].append(p["measured_out_ms"])
        for p in e["policies"]:
            sch = schedules[p["policy"]]
            pred = model.makespan(sch)
            eager = eager_nodes([recorded_frame(r) for r in p.get("fit_frames_data") or ()],
                                model.reads, model.capturable, p["placement"])
            pred_eager = model.makespan(sch, eager=eager) if eager else pred
            pooled = statistics.mean(same[_plan_key(p)])
            rows.append({"tag": e["tag"], "policy": p["policy"], "train": train, "pred_ms": pred,
                         "measured_ms": p["measured_out_ms"],
                         "measured_first_ms": p.get("measured_in_ms"),
                         "error_pct": _err(pred, p["measured_out_ms"]),
                         "eager": sorted(eager), "pred_eager_ms": pred_eager,
                         "error_eager_pct": _err(pred_eager, p["measured_out_ms"]),
                         "pooled_ms": pooled, "pooled_error_pct": _err(pred, pooled),
                         "trained_here": p["policy"] == train})
    return rows


def _plan_key(p) -> tuple:
    """A policy's placement and per-processor order (identical plans share it)."""
    return tuple(sorted((t["pe"], t["planned_start_ms"], n) for n, t in p["nodes"].items()))


#: Policies each replay trains on in turn (cross-validation: each predicts the others).
REPLAY_TRAIN = ("baseline", "heft", "xeft")


def replay_main(args):
    report = json.loads(args.replay.read_text())
    trains = [args.train] if args.train_only else list(REPLAY_TRAIN)
    by_train = {t: replay(report, t, gil=args.gil) for t in trains}
    first = by_train[trains[0]]
    lines = [f"Replay of {args.replay}: the model refit on each training policy's recorded "
             "frames (or node medians) predicts every policy's plan; error against the "
             "measured makespan (later frames), and against the mean of every run of the "
             "same plan (pooled)", "",
             "| experiment | policy | measured ms | same plan, mean of runs | "
             + " | ".join(f"trained on {t}: predicted ms | error | pooled error" for t in trains) + " |",
             "| --- | --- | ---: | ---: | " + " | ".join("---: | ---: | ---:" for _ in trains) + " |"]
    for i, r in enumerate(first):
        cells = []
        for t in trains:
            o = by_train[t][i]
            mark = " (in)" if o["trained_here"] else ""
            cells.append(f"{o['pred_ms']:.3f} | {o['error_pct']:+.1f}%{mark} | {o['pooled_error_pct']:+.1f}%")
        lines.append(f"| {r['tag']} | {r['policy']} | {r['measured_ms']:.3f} | {r['pooled_ms']:.3f} | "
                     + " | ".join(cells) + " |")
    lines += ["", "Summary, policies not trained on (out of sample): "]
    for t in trains:
        out = [r for r in by_train[t] if not r["trained_here"]]
        errs = [abs(r["error_pct"]) for r in out]
        pooled = [abs(r["pooled_error_pct"]) for r in out]
        lines.append(f"- trained on {t}: {sum(e <= 20 for e in errs)}/{len(errs)} within 20%, "
                     f"mean |error| {statistics.mean(errs):.1f}%, max {max(errs):.1f}%; against "
                     f"the mean of same-plan runs {sum(e <= 20 for e in pooled)}/{len(pooled)}, "
                     f"mean {statistics.mean(pooled):.1f}%, max {max(pooled):.1f}%")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "replay.md").write_text(f"Regenerate: `{args.command}`\n\n{text}\n")
    return by_train


def _write(out_dir, report):
    (out_dir / "graph_bench.json").write_text(json.dumps(report, indent=1, default=str))
    (out_dir / "graph_bench.md").write_text(markdown(report))


def pack_charts(out_dir):
    """Pack the Gantt folder into gantt.tar; each experiment's best chart stays beside it."""
    import shutil
    import tarfile

    charts = out_dir / GANTT_DIR
    if not charts.is_dir():
        return
    for png in charts.glob("gantt_*_best.png"):
        shutil.copy(png, out_dir / png.name)
    with tarfile.open(out_dir / "gantt.tar", "w") as tar:
        tar.add(charts, arcname=GANTT_DIR)
    shutil.rmtree(charts)


if __name__ == "__main__":
    main()
