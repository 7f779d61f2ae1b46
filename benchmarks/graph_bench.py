"""Graph runtime experiment: predicted vs measured makespans per policy, Gantt charts,
executor overhead and a soak run.

The graph (16 nodes): two camera streams, each running color convert (BGR2GRAY), a Gaussian
pyramid, Harris corners (the points to track), a 7x7 Gaussian blur and FAST on it
(keypoints), pyramidal LK from the previous frame (delays of the pyramid and of the points)
and a homography estimate (a CPU-only user node calling cv2.findHomography with RANSAC); a
CPU-only user node combines the two homographies, and a GPU-only user node (a Warp
"detector" standing in for the thesis' deep-learning node) runs on camera L's gray image.
OpenCV runs single-threaded (``--cv-threads 1``): each CPU worker is one core, as calibrated.

Steps:

1. verify on two real consecutive frames (so LK is calibrated on real motion) and calibrate
   (node costs, transfer model, executor dispatch costs; cached per machine);
2. the GIL switch interval (``sys.setswitchinterval``): a few values are tried on the heft
   plan and the fastest is kept for the run (``--switch-interval S`` fixes it);
3. for each policy (baseline, heft, xeft, best), with costs calibrated node by node:
   schedule, run ``--frames`` frames one at a time (predicted vs measured makespan: the
   target is within 20%) and then pipelined (throughput), learn each node's cost in the
   running frames (StarPU-style history);
4. the same with the history costs (``costs="history"``);
5. the executor's per-node overhead with trivial nodes (target < 50 us: chains all on one
   CPU worker, all on the GPU role, and alternating CPU and GPU) and, with
   ``--soak N``, N frames pipelined with host RSS and GPU memory at start and end.

Writes ``gantt_<policy>.png`` (predicted above measured, history costs),
``gantt_<policy>_calibrated.png`` (calibrated costs), ``gantt_<policy>_pipelined.png``
(3 frames in flight), ``graph_bench.json`` and ``graph_bench.md`` (tables, per-node costs:
calibrated alone vs measured in the running frames).

Usage::

    python benchmarks/graph_bench.py                 # GPU machine: CUDA, 1280x720 cameras
    python benchmarks/graph_bench.py --quick         # anywhere: warp-cpu, 160x120, few frames
    python benchmarks/graph_bench.py --soak 10000
    python benchmarks/graph_bench.py --overhead-only # the overhead section alone: overhead.md

    python benchmarks/graph_bench.py --replay benchmarks/results/graph/graph_bench.json

Options: --out DIR, --frames N, --n-cpus N, --gpu cuda|cuda:N|warp-cpu, --size WxH,
--depth K, --soak N, --soak-seconds S, --cv-threads N, --switch-interval S, --spin S,
--recalibrate, --replay JSON, --overhead-only, --overhead-nodes N, --overhead-frames N.
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

import warpvx
from warpvx.backend import init_warp
from warpvx.graph import default_n_cpus
from warpvx.graph.diagnostics import executor_overhead, soak
from warpvx.runtime import executor

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


def run_frames(g, plan, frames):
    """Run ``frames`` one at a time; their FrameResults and wall times (ms)."""
    runs, walls = [], []
    for f in frames:
        t0 = time.perf_counter()
        g.process(f)
        walls.append((time.perf_counter() - t0) * 1e3)
        runs.append(plan.last_run[-1])
    return runs, walls


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


def run_policy(g, policy, frames, args, out_dir, *, costs, learn=False, charts=True,
               rounds: int = 1):
    """Schedule and run one policy. With ``costs="history"``, up to ``rounds`` rounds of
    schedule, run, learn, until the placement stops changing: costs measured under one
    placement mispredict another (other threads compete for the GIL and the cores), so the
    model is refined on the placement it predicts, as StarPU's history models are."""
    placements = []
    for _ in range(max(1, rounds)):
        plan = g.schedule(policy, n_cpus=args.n_cpus, gpu=args.gpu, costs=costs)
        placements.append(plan.placement)
        run_frames(g, plan, frames[:2])  # warm the threads and pools
        runs, walls = run_frames(g, plan, frames)
        if len(placements) > 1 and placements[-1] == placements[-2]:
            break  # learnt under this very placement: the prediction stands
        if costs == "history" or learn:
            g.learn(plan, runs=runs)
    spans = [r.makespan for r in runs]
    suffix = "" if costs == "history" else "_calibrated"
    if charts:
        plan.gantt(out_dir / f"gantt_{policy}{suffix}.png",
                   title=f"{g.name} ({policy}, {costs} costs)")
    t0 = time.perf_counter()
    n = 0
    for _ in g.stream(frames, depth=args.depth):
        n += 1
    stream_s = time.perf_counter() - t0
    if charts and costs == "history":
        plan.gantt(out_dir / f"gantt_{policy}_pipelined.png", frames=3,
                   title=f"{g.name} ({policy}, depth {args.depth})")
    predicted = plan.predicted_makespan
    measured = statistics.median(spans)
    return {
        "policy": policy,
        "costs": costs,
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
        "nodes": node_table(plan, runs),
        "copies": copies(runs),
        "edges": device_edges(plan),
        "rounds": len(placements),
        "transfer_scale": plan.calibration.transfer_scale,
    }


def replay_ms(row, edges, dispatch, n_cpus) -> float:
    """The model's makespan for a run's placement with each node's cost as measured in the
    running frames (GPU: the longer of device and host time) and its copies charged to it,
    as the executor makes them; edges carry the hand-off. Near the measured makespan when
    the model's structure is right, so a prediction's error is then the costs' error."""
    from warpvx.sched import cpu_gpu_dag
    from warpvx.sched import schedule as schedule_dag

    tasks = {}
    for node, t in row["nodes"].items():
        gpu = t["pe"] == "gpu"
        c = t["measured_ms"]
        if gpu and t["host_ms"] is not None:
            c = max(c, t["host_ms"] - t["transfer_ms"])
        c += t["transfer_ms"] + dispatch.get("gpu_gap" if gpu else "cpu_gap", 0.0)
        tasks[node] = (None, c) if gpu else (c, None)
    dag = cpu_gpu_dag(tasks, {e: dispatch.get("handoff", 0.0) for e in edges}, n_cpus)
    return schedule_dag(dag, "heft").makespan


def graph_edges(g) -> list:
    from warpvx.graph.data import Data

    return sorted({(ref.producer.name, n.name) for n in g.nodes.values()
                   for ref in n.inputs.values() if isinstance(ref, Data) and ref.producer is not None})


def replay_report(path: Path) -> str:
    """``--replay``: the replayed makespans of a saved ``graph_bench.json``, as markdown."""
    report = json.loads(Path(path).read_text())
    edges = graph_edges(build_graph(tuple(report["size"])))
    lines = [f"# Replay of {Path(path).name} ({report['machine']})", "",
             "The model (task DAG, HEFT) with each node's cost as measured in the running frames "
             "and its copies charged to the node (the executor copies on the consumer's "
             "processor); edges carry the executor's hand-off. It tests the model's structure "
             "apart from its costs.", "",
             "| policy | costs | measured ms | predicted ms | replayed ms | measured vs replayed |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]
    for row in report["policies"]:
        rep = replay_ms(row, edges, report["dispatch"], report["n_cpus"])
        lines.append(f"| {row['policy']} | {row['costs']} | {row['measured_ms']:.3f} | "
                     f"{row['predicted_ms']:.3f} | {rep:.3f} | "
                     f"{100 * (row['measured_ms'] - rep) / rep:+.1f}% |")
    return "\n".join(lines) + "\n"


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
        runs, _ = run_frames(g, plan, sample)
        return statistics.median(r.makespan for r in runs)

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


def _fmt(v, spec=".3f"):
    return "-" if v is None else format(v, spec)


def markdown(report) -> str:
    lines = [
        f"# Graph runtime benchmark ({report['mode']})",
        "",
        f"Machine: {report['machine']}; GPU role: {report['gpu']}; CPU workers: "
        f"{report['n_cpus']}; cameras {report['size'][0]}x{report['size'][1]}; "
        f"{report['frames']} frames per policy; {report['nodes']} nodes; OpenCV threads "
        f"{report['cv_threads']}; GIL switch interval {report['switch_interval']['chosen'] * 1e3:g} ms; "
        f"executor spin {report['switch_interval']['spin_chosen'] * 1e6:g} us.",
        "",
        "Predicted vs measured makespan of one frame (frames run one at a time; the target is "
        "within 20%). *calibrated*: node costs timed alone; *history*: costs the nodes showed "
        "in running frames (StarPU-style history model), refined over up to 3 rounds of "
        "schedule, run, learn until the placement is stable (*rounds*); copies scaled by what "
        "they took in running frames (*copy scale*). *replayed*: the model run with each "
        "node's measured in-frame cost and copies (see `--replay`): how far the model's "
        "structure, apart from its costs, is from the measurement.",
        "",
        "| policy | costs | rounds | predicted ms | measured ms (median) | error | replayed ms | "
        f"p90 ms | sequential FPS | pipelined FPS (depth {report['depth']}) | copy scale | GPU nodes |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in report["policies"]:
        name = r["policy"] + (f" ({r['chosen']})" if r["chosen"] != r["policy"] else "")
        scale = f"{r['transfer_scale']:.2f}" if r["costs"] == "history" else "-"
        lines.append(
            f"| {name} | {r['costs']} | {r['rounds']} | {r['predicted_ms']:.3f} | "
            f"{r['measured_ms']:.3f} | {r['error_pct']:+.1f}% | {_fmt(r.get('replayed_ms'))} | "
            f"{r['measured_p90_ms']:.3f} | "
            f"{r['sequential_fps']:.1f} | {r['pipelined_fps']:.1f} | {scale} | "
            f"{len(r['gpu_nodes'])}: {', '.join(r['gpu_nodes'])} |"
        )
    si = report["switch_interval"]
    if si["switch"]:
        lines += ["", "GIL switch interval (heft plan, median makespan): " + ", ".join(
            f"{float(k) * 1e3:g} ms -> {v:.3f} ms" for k, v in si["switch"].items()) + "."]
    if si["spin"]:
        lines += ["", "Executor spin before blocking (heft plan, median makespan): " + ", ".join(
            f"{float(k) * 1e6:g} us -> {v:.3f} ms" for k, v in si["spin"].items()) + "."]
    lines += ["", "Data movement per frame (medians) and edges by where data lives "
                  "(GPU->GPU edges stay on the device, no copy):", ""]
    for r in report["policies"]:
        c = r["copies"]
        lines.append(f"- {r['policy']} ({r['costs']}): uploads {c['h2d_bytes'] / 1e6:.2f} MB, "
                     f"downloads {c['d2h_bytes'] / 1e6:.2f} MB; edges "
                     + ", ".join(f"{k} {v}" for k, v in sorted(r["edges"].items())))
    lines += ["", "Per node, each policy's calibrated-costs run: cost timed alone vs in the "
                  "running frames (interval without transfers; GPU: device interval between "
                  "events; host: the GPU thread's time in the call), ms:", ""]
    for r in report["policies"]:
        if r["costs"] != "calibrated":
            continue
        lines += [f"{r['policy']}:", "",
                  "| node | on | alone | in frames | transfers | GPU host alone | GPU host in frames |",
                  "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
        for node, t in r["nodes"].items():
            lines.append(f"| {node} | {t['pe']} | {_fmt(t['calibrated_ms'])} | {_fmt(t['measured_ms'])} | "
                         f"{_fmt(t['transfer_ms'])} | {_fmt(t['calibrated_host_ms'])} | {_fmt(t['host_ms'])} |")
        lines.append("")
    lines += ["Calibrated node costs (ms; GPU: device interval, host time in brackets):", "",
              "| node | cpu | gpu |", "| --- | ---: | ---: |"]
    for node, t in report["calibration"].items():
        gpu = _fmt(t["gpu"])
        if t.get("gpu_host") is not None:
            gpu += f" ({t['gpu_host']:.3f})"
        lines.append(f"| {node} | {_fmt(t['cpu'])} | {gpu} |")
    tm = report["transfer"]
    d = report["dispatch"]
    lines += ["", f"Transfer model: h2d {tm['h2d_latency_ms'] * 1e3:.1f} us + "
                  f"{tm['h2d_gbps']:.2f} GB/s, d2h {tm['d2h_latency_ms'] * 1e3:.1f} us + "
                  f"{tm['d2h_gbps']:.2f} GB/s.",
              "", f"Executor dispatch costs in the model: CPU task {d.get('cpu_node', 0) * 1e3:.1f} us, "
                  f"GPU task {d.get('gpu_node', 0) * 1e3:.1f} us, CPU<->GPU hand-off "
                  f"{d.get('handoff', 0) * 1e3:.1f} us (beyond the copy), frame start "
                  f"{d.get('start', 0) * 1e3:.1f} us.", ""]
    lines += overhead_lines(report["overhead"])
    if report.get("soak"):
        s = report["soak"]
        gpu = ("n/a" if s["gpu_mem_start_mb"] is None else
               f"Warp mempool in use {s['gpu_mem_start_mb']:.1f} -> {s['gpu_mem_end_mb']:.1f} MB")
        smi = ("" if s.get("smi_start_mb") is None else
               f"; nvidia-smi (this process) {s['smi_start_mb']:.0f} -> {s['smi_end_mb']:.0f} MB")
        cut = "" if s["frames"] >= s.get("requested", s["frames"]) else \
            f" (of {s['requested']} asked: stopped at the time limit)"
        lines += ["", f"Soak: {s['frames']} frames{cut} pipelined (depth {s['depth']}) at "
                      f"{s['fps']:.1f} FPS; host RSS {s['rss_start_mb']:.1f} -> "
                      f"{s['rss_end_mb']:.1f} MB; GPU: {gpu}{smi}."]
        if s.get("samples"):
            lines += ["", "| frame | RSS MB | mempool MB | nvidia-smi MB |", "| ---: | ---: | ---: | ---: |"]
            for fr, rss, gm, sm in s["samples"]:
                lines.append(f"| {fr} | {rss:.1f} | {_fmt(gm, '.1f')} | {_fmt(sm, '.0f')} |")
    lines.append("")
    return "\n".join(lines)


CHAIN_TEXT = {"cpu": "one CPU worker", "gpu": "all on the GPU role", "mixed": "alternating CPU/GPU"}


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
    p.add_argument("--frames", type=int, default=None, help="frames per policy (default 50, quick 8)")
    p.add_argument("--n-cpus", type=int, default=None, help="CPU workers (default: cores - 1, max 4)")
    p.add_argument("--gpu", default=None, help="cuda, cuda:N or warp-cpu (default: cuda if present)")
    p.add_argument("--size", default=None, help="camera size WxH (default 1280x720, quick 160x120)")
    p.add_argument("--depth", type=int, default=3, help="frames in flight when pipelined")
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
    p.add_argument("--replay", type=Path, default=None,
                   help="only replay a saved graph_bench.json (writes replay.md beside it)")
    args = p.parse_args(argv)
    if args.replay is not None:
        text = replay_report(args.replay)
        (args.replay.parent / "replay.md").write_text(text)
        print(text)
        return None
    cv_threads_before = cv2.getNumThreads()
    switch_before = sys.getswitchinterval()
    spin_before = executor.SPIN_SECONDS
    cv2.setNumThreads(args.cv_threads)
    try:
        return overhead_only(args) if args.overhead_only else _run(args)
    finally:
        cv2.setNumThreads(cv_threads_before)
        sys.setswitchinterval(switch_before)
        executor.SPIN_SECONDS = spin_before


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
    t_start = time.perf_counter()

    frames = make_frames(size, max(n_frames, 2))
    g = build_graph(size, max_corners=200 if args.quick else 500)
    g.verify(frames[:2])
    cal = g.calibrate(gpu=args.gpu, recalibrate=args.recalibrate,
                      repeats=5 if args.quick else 11)
    print(f"calibrated {len(cal.nodes)} nodes on {cal.machine} ({len(cal.fresh)} measured now); "
          f"dispatch {({k: round(v * 1e3, 1) for k, v in cal.dispatch.items()})} us", flush=True)
    tm = cal.transfer
    print(f"transfer model: h2d {tm.h2d_latency * 1e3:.1f} us + {tm.bandwidth_gbps[0]:.2f} GB/s, "
          f"d2h {tm.d2h_latency * 1e3:.1f} us + {tm.bandwidth_gbps[1]:.2f} GB/s", flush=True)
    switch = choose_threading(g, frames, args)
    print(f"GIL switch interval {switch['chosen'] * 1e3:g} ms "
          f"(tried: {({k * 1e3: round(v, 3) for k, v in switch['switch'].items()})}); spin "
          f"{switch['spin_chosen'] * 1e6:g} us (tried: "
          f"{({k * 1e6: round(v, 3) for k, v in switch['spin'].items()})})", flush=True)

    rows = []
    for costs in ("calibrated", "history"):
        for policy in POLICIES:
            row = run_policy(g, policy, frames, args, out_dir, costs=costs,
                             learn=costs == "calibrated", rounds=3 if costs == "history" else 1)
            row["replayed_ms"] = replay_ms(row, graph_edges(g), cal.dispatch, args.n_cpus)
            rows.append(row)
            print(f"{policy:9s} {costs:10s} predicted {row['predicted_ms']:8.3f} ms  measured "
                  f"{row['measured_ms']:8.3f} ms  ({row['error_pct']:+6.1f}%)  replayed "
                  f"{row['replayed_ms']:8.3f} ms  pipelined "
                  f"{row['pipelined_fps']:7.1f} FPS  rounds {row['rounds']}  gpu: {row['gpu_nodes']}",
                  flush=True)
            if costs == "calibrated":
                for node, t in row["nodes"].items():
                    print(f"    {node:12s} {t['pe']:4s} alone {t['calibrated_ms']:7.3f}  in frames "
                          f"{t['measured_ms']:7.3f}  xfer {t['transfer_ms']:6.3f}  host "
                          f"{_fmt(t['host_ms'])} (alone {_fmt(t['calibrated_host_ms'])})  start "
                          f"{t['start_ms']:7.3f} (planned {t['planned_start_ms']:7.3f})")

    report = _report(args, cal, g, size, n_frames, switch, rows, [], None, t_start)
    _write(out_dir, report)  # so far, in case a later step is cut short

    overhead = measure_overhead(args)

    soak_report = None
    if args.soak:
        g.schedule("best", n_cpus=args.n_cpus, gpu=args.gpu, costs="history")
        soak_report = soak(g, lambda i: frames[i % len(frames)], args.soak, depth=args.depth,
                           report_every=max(1, args.soak // 10), max_seconds=args.soak_seconds)
        print(f"soak: {soak_report['frames']} frames, {soak_report['fps']:.1f} FPS, RSS "
              f"{soak_report['rss_start_mb']:.1f} -> {soak_report['rss_end_mb']:.1f} MB, GPU mempool "
              f"{soak_report['gpu_mem_start_mb']} -> {soak_report['gpu_mem_end_mb']} MB, nvidia-smi "
              f"{soak_report['smi_start_mb']} -> {soak_report['smi_end_mb']} MB", flush=True)
        for fr, rss, gm, sm in soak_report["samples"]:
            print(f"    frame {fr:6d}: RSS {rss:8.1f} MB, mempool {_fmt(gm, '.1f')} MB, "
                  f"nvidia-smi {_fmt(sm, '.0f')} MB")

    report = _report(args, cal, g, size, n_frames, switch, rows, overhead, soak_report, t_start)
    _write(out_dir, report)
    g.close()
    print(f"wrote {out_dir} in {report['seconds']:.1f} s")
    return report


def _report(args, cal, g, size, n_frames, switch, rows, overhead, soak_report, t_start) -> dict:
    up, down = cal.transfer.bandwidth_gbps
    return {
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
        "switch_interval": switch,
        "nodes": len(g.nodes),
        "policies": rows,
        "calibration": cal.nodes,
        "history": cal.history,
        "transfer": {"h2d_latency_ms": cal.transfer.h2d_latency, "h2d_gbps": up,
                     "d2h_latency_ms": cal.transfer.d2h_latency, "d2h_gbps": down},
        "dispatch": cal.dispatch,
        "overhead": overhead,
        "soak": soak_report,
        "seconds": time.perf_counter() - t_start,
    }


def _write(out_dir, report):
    (out_dir / "graph_bench.json").write_text(json.dumps(report, indent=1, default=str))
    (out_dir / "graph_bench.md").write_text(markdown(report))


if __name__ == "__main__":
    main()
