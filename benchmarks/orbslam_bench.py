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
   predicted vs measured makespan, and a Gantt chart of 3 pipelined frames.

Accuracy also on ViSP's castle_simu (monocular, warpvx vs the baseline) when
``../shared/data/real/castle_simu`` (or ``--castle``) exists.

Writes ``orbslam_bench.json``, ``orbslam_bench.md`` (the command that regenerates it at its
top), ``gantt_mono.png``, ``gantt_stereo.png`` into ``--out`` (default ``$OUT/orbslam``).

Usage::

    PYTHONPATH=. python benchmarks/orbslam_bench.py --out $OUT/orbslam   # GPU machine (cuda), < 3 min
    PYTHONPATH=. python benchmarks/orbslam_bench.py --quick              # anywhere: warp-cpu, few frames
"""

from __future__ import annotations

import argparse
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
from warpvx.apps import trajectory_eval as te  # noqa: E402
from warpvx.apps.orbslam_match import add_match_node, mutual_pairs  # noqa: E402
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
    dt = time.perf_counter() - t
    plan = plans[0]
    summary = plan.summary()
    try:
        plan.gantt(out / f"gantt_{name}.png", frames=3, title=f"ORB-SLAM front end ({name}, {backend})")
    except Exception as exc:  # noqa: BLE001 - matplotlib missing: the numbers still count
        summary["gantt_error"] = str(exc)
    track_ms = statistics.median(f.stats["track_ms"] for f in res)
    return {"fps": fps(len(res), dt), "frames": len(res), "track_ms_median": track_ms,
            "stages_ms": stage_ms(plan), "plan": summary}, np.array([f.pose for f in res])


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


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="warp-cpu, 12 unique frames, 30 timed")
    p.add_argument("--backend", default=None, help="default: cuda (warp-cpu with --quick)")
    p.add_argument("--frames", type=int, default=600, help="frames timed (replayed)")
    p.add_argument("--unique", type=int, default=60, help="frames rendered")
    p.add_argument("--size", default="1241x376")
    p.add_argument("--castle", default=str(CASTLE), help="castle_simu folder (skipped if absent)")
    p.add_argument("--out", default=os.path.join(os.environ.get("OUT") or ".", "orbslam"),
                   help="output folder (default: $OUT/orbslam)")
    args = p.parse_args(argv)
    backend = args.backend or ("warp-cpu" if args.quick else "cuda")
    n_unique, n = (12, 30) if args.quick else (args.unique, args.frames)
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
    report["opencv_baseline"] = bench_opencv(replay(left, min(n, 200)), K)
    progress("opencv", report["opencv_baseline"])
    # Accuracy on the rendered sequence itself (no replay), and on castle_simu when present.
    nan = {"ate_m": float("nan"), "rpe1_t_m": float("nan"), "rpe1_r_deg": float("nan")}
    report["accuracy"] = {
        "rendered: warpvx_mono (Sim3)": attempt("accuracy mono", lambda: accuracy(np.array(
            [f.pose for f in o.track_frames(mono_frames, mono, backend=backend)]), gt, True), nan),
        "rendered: warpvx_stereo (SE3)": attempt("accuracy stereo", lambda: accuracy(np.array(
            [f.pose for f in o.track_frames(stereo_frames, stereo, backend=backend)]), gt, False), nan),
        "rendered: opencv_baseline (Sim3)": accuracy(o.opencv_baseline(left, K), gt, True)}
    if os.path.isdir(args.castle):
        for k, v in attempt("castle", lambda: castle_accuracy(args.castle, backend), {}).items():
            if k != "error":
                report["accuracy"][f"castle_simu: {k}"] = v
    progress("accuracy", "done")

    base = report["opencv_baseline"]["thread_pool_fps"]
    rows = [("extraction + matching, pipelined (match node)", "extract_match"),
            ("extraction + matching, pipelined (match_hamming primitive, before)", "extract_match_primitive"),
            ("front end mono, end to end", "frontend_mono"),
            ("front end stereo, end to end", "frontend_stereo")]
    lines = [f"<!-- {command}   (OUT=$OUT) -->",
             f"# ORB-SLAM front end at {size[0]}x{size[1]} ({backend}, {n} frames, "
             f"{os.cpu_count()} CPU threads)", "",
             "| what | FPS | vs OpenCV (thread pool) |", "| --- | --- | --- |"]
    lines += [f"| {label}" + (f" (FAILED: {report[k]['error']})" if "error" in report[k] else "")
              + f" | {report[k]['fps']:.1f} | {report[k]['fps'] / base:.1f}x |" for label, k in rows]
    lines += [f"| OpenCV baseline, serial (all threads) | {report['opencv_baseline']['serial_fps']:.1f} | |",
              f"| OpenCV baseline, thread-pool extraction | {base:.1f} | 1.0x |",
              f"| (reading a PNG: {report['png_read_ms_per_frame']:.2f} ms/frame, not included) | | |",
              "", f"Tracking node alone, median: mono {report['frontend_mono']['track_ms_median']:.2f} ms, "
              f"stereo {report['frontend_stereo']['track_ms_median']:.2f} ms.", "",
              "Per node, median ms over the last frames (in a pipelined run a node's interval",
              "includes waiting for the GIL and for copies):", ""]
    lines += _stage_table(report, ["extract_match", "extract_match_primitive", "frontend_mono",
                                   "frontend_stereo"])
    lines += ["", "| accuracy | ATE (m) | RPE t (m) | RPE r (deg) |", "| --- | --- | --- | --- |"]
    for k, v in report["accuracy"].items():
        lines.append(f"| {k} | {v['ate_m']:.4f} | {v['rpe1_t_m']:.4f} | {v['rpe1_r_deg']:.3f} |")
    for k in ("frontend_mono", "frontend_stereo"):
        s = report[k]["plan"]
        if s is None:
            lines += ["", f"{k}: FAILED ({report[k].get('error')})"]
            continue
        measured = s["measured_makespan_ms"]
        lines += ["", f"{k}: placement {s['placement']}; predicted makespan "
                      f"{s['predicted_makespan_ms']:.2f} ms, measured (median frame latency, "
                      f"pipelined) {measured:.2f} ms" if measured is not None else "n/a"]
    (out / "orbslam_bench.md").write_text("\n".join(lines) + "\n")
    (out / "orbslam_bench.json").write_text(json.dumps(report, indent=2, default=str))
    print("\n".join(lines))
    progress("total", "done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
