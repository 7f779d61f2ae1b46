"""Graph runtime experiment: predicted vs measured makespans per policy, Gantt charts,
executor overhead and a soak run.

The graph (16 nodes): two camera streams, each running color convert (BGR2GRAY), a Gaussian
pyramid, Harris corners (the points to track), a 7x7 Gaussian blur and FAST on it
(keypoints), pyramidal LK from the previous frame (delays of the pyramid and of the points)
and a homography estimate (a CPU-only user node calling cv2.findHomography with RANSAC); a
CPU-only user node combines the two homographies, and a GPU-only user node (a Warp
"detector" standing in for the thesis' deep-learning node) runs on camera L's gray image.
OpenCV runs single-threaded (``--cv-threads 1``): each CPU worker is one core, as calibrated.

For each policy (baseline, heft, xeft, best): calibrate (cached), schedule, run ``--frames``
frames one at a time (predicted vs measured makespan: the target is within 20%) and then
pipelined (throughput), write ``gantt_<policy>.png`` (predicted above measured) and
``gantt_<policy>_pipelined.png`` (3 frames in flight), and a table (``graph_bench.json``,
``graph_bench.md``). Then the executor's per-node overhead with trivial nodes (target
< 50 us) and, with ``--soak N``, N frames pipelined with host RSS and GPU memory at start and end.

Usage::

    python benchmarks/graph_bench.py                 # GPU machine: CUDA, 1280x720 cameras
    python benchmarks/graph_bench.py --quick         # anywhere: warp-cpu, 160x120, few frames
    python benchmarks/graph_bench.py --soak 10000

Options: --out DIR, --frames N, --n-cpus N, --gpu cuda|cuda:N|warp-cpu, --size WxH,
--depth K, --soak N, --cv-threads N, --recalibrate.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import warp as wp

import warpvx
from warpvx.backend import init_warp
from warpvx.graph import default_n_cpus
from warpvx.graph.diagnostics import executor_overhead, soak

POLICIES = ("baseline", "heft", "xeft", "best")
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


def detector_warp(gray):
    """A stand-in for a network: DETECTOR_ITERS 5x5 nonlinear filter passes (GPU only)."""
    a = wp.empty(gray.shape, dtype=wp.float32, device=gray.device)
    b = wp.empty_like(a)
    wp.launch(to_float, dim=gray.shape, inputs=[gray], outputs=[a], device=gray.device)
    for _ in range(DETECTOR_ITERS):
        wp.launch(smooth_response, dim=gray.shape, inputs=[a], outputs=[b], device=gray.device)
        a, b = b, a
    return a


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


def build_graph(size, *, max_corners=500, levels=4) -> warpvx.Graph:
    w, h = size
    g = warpvx.Graph("two-cameras")
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
        H = g.user(homography, [prev_pts[-1], nxt, status], "H", name=f"homography{cam}")
        homs.append(H)
        g.output(f"keypoints{cam}", kps)
        g.output(f"H{cam}", H)
        if cam == "L":
            det = g.user(None, [gray], "score", warp_fn=detector_warp, name="detectorL")
            g.output("scoreL", det)
    motion = g.user(fuse, homs, "motion", name="fuse")
    g.output("motion", motion)
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


def run_policy(g, policy, frames, args, out_dir):
    plan = g.schedule(policy, n_cpus=args.n_cpus, gpu=args.gpu)
    for f in frames[:2]:  # warm the threads and allocations
        g.process(f)
    spans = []
    walls = []
    for f in frames:
        t0 = time.perf_counter()
        g.process(f)
        walls.append((time.perf_counter() - t0) * 1e3)
        spans.append(plan.last_run[-1].makespan)
    plan.gantt(out_dir / f"gantt_{policy}.png", title=f"{g.name} ({policy})")
    t0 = time.perf_counter()
    n = 0
    for _ in g.stream(frames, depth=args.depth):
        n += 1
    stream_s = time.perf_counter() - t0
    plan.gantt(out_dir / f"gantt_{policy}_pipelined.png", frames=3,
               title=f"{g.name} ({policy}, depth {args.depth})")
    predicted = plan.predicted_makespan
    measured = statistics.median(spans)
    row = {
        "policy": policy,
        "chosen": plan.schedule.info.get("chosen", policy),
        "predicted_ms": predicted,
        "measured_ms": measured,
        "measured_p90_ms": float(np.percentile(spans, 90)),
        "wall_ms": statistics.median(walls),
        "error_pct": 100.0 * (measured - predicted) / predicted if predicted > 0 else None,
        "pipelined_fps": n / stream_s,
        "sequential_fps": 1e3 / statistics.median(walls),
        "placement": plan.placement,
        "metrics": {k: v for k, v in plan.metrics.items() if k != "idle_per_processor"},
        "gpu_nodes": sorted(t for t, p in plan.placement.items() if p == "gpu"),
    }
    return row


def markdown(report) -> str:
    lines = [
        f"# Graph runtime benchmark ({report['mode']})",
        "",
        f"Machine: {report['machine']}; GPU role: {report['gpu']}; CPU workers: "
        f"{report['n_cpus']}; cameras {report['size'][0]}x{report['size'][1]}; "
        f"{report['frames']} frames per policy; {report['nodes']} nodes.",
        "",
        "| policy | predicted ms | measured ms (median) | error | p90 ms | sequential FPS | "
        f"pipelined FPS (depth {report['depth']}) | GPU nodes |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in report["policies"]:
        name = r["policy"] + (f" ({r['chosen']})" if r["chosen"] != r["policy"] else "")
        lines.append(
            f"| {name} | {r['predicted_ms']:.3f} | {r['measured_ms']:.3f} | "
            f"{r['error_pct']:+.1f}% | {r['measured_p90_ms']:.3f} | {r['sequential_fps']:.1f} | "
            f"{r['pipelined_fps']:.1f} | {len(r['gpu_nodes'])}: {', '.join(r['gpu_nodes'])} |"
        )
    lines += ["", "Calibrated node costs (ms):", "", "| node | cpu | gpu |", "| --- | ---: | ---: |"]
    for node, t in report["calibration"].items():
        fmt = lambda v: "-" if v is None else f"{v:.3f}"  # noqa: E731
        lines.append(f"| {node} | {fmt(t['cpu'])} | {fmt(t['gpu'])} |")
    tm = report["transfer"]
    lines += ["", f"Transfer model: h2d {tm['h2d_latency_ms'] * 1e3:.1f} us + "
                  f"{tm['h2d_gbps']:.2f} GB/s, d2h {tm['d2h_latency_ms'] * 1e3:.1f} us + "
                  f"{tm['d2h_gbps']:.2f} GB/s.", ""]
    lines += ["Executor overhead per node (trivial identity nodes, target < 50 us):", ""]
    for o in report["overhead"]:
        kind = "alternating CPU/GPU" if o["mixed"] else "one CPU worker"
        lines.append(f"- {o['n_nodes']} nodes, {kind}: {o['per_node_us']:.1f} us/node "
                     f"(process), {o['per_node_us_stream']:.1f} us/node (stream)")
    if report.get("soak"):
        s = report["soak"]
        gpu = ("n/a" if s["gpu_mem_start_mb"] is None else
               f"{s['gpu_mem_start_mb']:.1f} -> {s['gpu_mem_end_mb']:.1f} MB")
        lines += ["", f"Soak: {s['frames']} frames pipelined (depth {s['depth']}) at "
                      f"{s['fps']:.1f} FPS; host RSS {s['rss_start_mb']:.1f} -> "
                      f"{s['rss_end_mb']:.1f} MB; GPU memory {gpu}."]
    lines.append("")
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="small sizes, few frames, warp-cpu if no CUDA")
    p.add_argument("--out", type=Path, default=None, help="results folder")
    p.add_argument("--frames", type=int, default=None, help="frames per policy (default 50, quick 8)")
    p.add_argument("--n-cpus", type=int, default=None, help="CPU workers (default: cores - 1, max 4)")
    p.add_argument("--gpu", default=None, help="cuda, cuda:N or warp-cpu (default: cuda if present)")
    p.add_argument("--size", default=None, help="camera size WxH (default 1280x720, quick 160x120)")
    p.add_argument("--depth", type=int, default=3, help="frames in flight when pipelined")
    p.add_argument("--soak", type=int, default=0, help="also run N frames pipelined, report memory")
    p.add_argument("--overhead-nodes", type=int, default=100)
    p.add_argument("--cv-threads", type=int, default=1,
                   help="cv2.setNumThreads for the run (default 1: one core per CPU worker)")
    p.add_argument("--recalibrate", action="store_true")
    args = p.parse_args(argv)
    cv_threads_before = cv2.getNumThreads()
    cv2.setNumThreads(args.cv_threads)
    try:
        return _run(args)
    finally:
        cv2.setNumThreads(cv_threads_before)


def _run(args):
    init_warp()
    if args.gpu is None:
        args.gpu = "cuda" if warpvx.cuda_available() else "warp-cpu"
    if args.n_cpus is None:
        args.n_cpus = default_n_cpus()
    size = tuple(int(v) for v in (args.size or ("160x120" if args.quick else "1280x720")).split("x"))
    n_frames = args.frames or (8 if args.quick else 50)
    out_dir = args.out or (ROOT / "results" / "graph" / ("quick" if args.quick else ""))
    out_dir.mkdir(parents=True, exist_ok=True)

    frames = make_frames(size, n_frames)
    g = build_graph(size, max_corners=200 if args.quick else 500)
    g.verify(frames[0])
    cal = g.calibrate(gpu=args.gpu, recalibrate=args.recalibrate,
                      repeats=5 if args.quick else 11)
    print(f"calibrated {len(cal.nodes)} nodes on {cal.machine} ({len(cal.fresh)} measured now)")

    rows = []
    for policy in POLICIES:
        row = run_policy(g, policy, frames, args, out_dir)
        rows.append(row)
        print(f"{policy:9s} predicted {row['predicted_ms']:8.3f} ms  measured "
              f"{row['measured_ms']:8.3f} ms  ({row['error_pct']:+6.1f}%)  pipelined "
              f"{row['pipelined_fps']:7.1f} FPS  gpu: {row['gpu_nodes']}")

    overhead = [
        executor_overhead(args.overhead_nodes, 20 if args.quick else 200),
        executor_overhead(args.overhead_nodes // 2, 10 if args.quick else 100, mixed=True,
                          gpu=args.gpu),
    ]
    for o in overhead:
        print(f"overhead ({'mixed' if o['mixed'] else 'cpu'}, {o['n_nodes']} nodes): "
              f"{o['per_node_us']:.1f} us/node process, {o['per_node_us_stream']:.1f} us/node stream")

    soak_report = None
    if args.soak:
        g.schedule("best", n_cpus=args.n_cpus, gpu=args.gpu)
        soak_report = soak(g, lambda i: frames[i % len(frames)], args.soak, depth=args.depth,
                           report_every=max(1, args.soak // 10))
        print(f"soak: {soak_report['frames']} frames, {soak_report['fps']:.1f} FPS, RSS "
              f"{soak_report['rss_start_mb']:.1f} -> {soak_report['rss_end_mb']:.1f} MB, GPU "
              f"{soak_report['gpu_mem_start_mb']} -> {soak_report['gpu_mem_end_mb']} MB")

    up, down = cal.transfer.bandwidth_gbps
    report = {
        "mode": "quick" if args.quick else "full",
        "machine": cal.machine,
        "platform": platform.platform(),
        "python": sys.version.split()[0],
        "warp": wp.config.version,
        "gpu": args.gpu,
        "n_cpus": args.n_cpus,
        "size": size,
        "frames": n_frames,
        "depth": args.depth,
        "cv_threads": args.cv_threads,
        "nodes": len(g.nodes),
        "policies": rows,
        "calibration": cal.nodes,
        "transfer": {"h2d_latency_ms": cal.transfer.h2d_latency, "h2d_gbps": up,
                     "d2h_latency_ms": cal.transfer.d2h_latency, "d2h_gbps": down},
        "overhead": overhead,
        "soak": soak_report,
    }
    (out_dir / "graph_bench.json").write_text(json.dumps(report, indent=1, default=str))
    (out_dir / "graph_bench.md").write_text(markdown(report))
    g.close()
    print(f"wrote {out_dir}")
    return report


if __name__ == "__main__":
    main()
