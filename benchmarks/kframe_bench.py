"""Frames in flight: the one-frame plan pipelined against the K-frame schedule run cyclically.

For ``warpvx.orb_graph`` cells (cameras x DL node, ``--cpus`` CPU workers + the GPU) and each
policy: the one-frame plan (``g.schedule(policy)``) streamed with ``--depth`` frames in flight
(every frame with the same placement), and the K-frame plan (``g.schedule(policy,
frames=K)``: the DAG unrolled over K frames with the delays' edges, scheduled frame-major;
frame i runs with the placement of frame i mod K) streamed the same way. Reports the
predicted one-frame makespan and K-frame period, the measured period (wall time over the
streamed frames, after a warm-up of ``--depth`` frames), the median frame latency (submission
to last task, ms) and how many nodes the K-frame schedule places differently in some frame
than in frame 0. At most about 3.5 minutes on one H100 (no cell starts after ``--budget-s``)::

    PYTHONPATH=. python3 benchmarks/kframe_bench.py --out $OUT/kframe

Writes ``kframe_bench.md`` (its first line is the command) and ``kframe_bench.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from table51 import _camera_frames  # noqa: E402 - real frames, as Table 5.1 streams them


def stream_period(g, frames, depth: int) -> tuple[float, float]:
    """(ms per frame over ``frames``, median latency ms) of the graph's current plan, after
    a warm-up of ``depth`` frames (its executor is new)."""
    sum(1 for _ in g.stream(frames[:depth], depth=depth))
    t0 = time.perf_counter()
    n = sum(1 for _ in g.stream(frames, depth=depth))
    period = (time.perf_counter() - t0) * 1e3 / n
    return period, statistics.median(g.plan.measured_makespans())


def cell(g, frames, args, policy) -> dict:
    one = g.schedule(policy, n_cpus=args.cpus, gpu=args.gpu)
    row = {"policy": policy, "predicted_makespan_ms": one.schedule.makespan}
    row["one_period_ms"], row["one_latency_ms"] = stream_period(g, frames, args.depth)
    t0 = time.perf_counter()
    kplan = g.schedule(policy, n_cpus=args.cpus, gpu=args.gpu, frames=args.k)
    row["schedule_s"] = time.perf_counter() - t0
    ks = kplan.frame_schedule
    row["predicted_period_ms"] = ks.info["period"]
    row["moved_nodes"] = sum(any(ks.tasks[v, f].processor != ks.tasks[v, 0].processor
                                 for f in range(args.k)) for v in g.nodes)
    row["k_period_ms"], row["k_latency_ms"] = stream_period(g, frames, args.depth)
    return row


def markdown(rows, args, command) -> str:
    lines = [f"Command: `{command}`", "",
             f"K = {args.k} frames in flight, {args.cpus} CPU workers + GPU ({args.gpu or 'auto'}), "
             f"{args.width}x{args.height}, {args.stream_frames} frames streamed with depth "
             f"{args.depth}. one: the one-frame plan pipelined (same placement every frame); "
             "K: the K-frame schedule run cyclically. moved: nodes placed differently in some "
             "frame of the K-frame schedule than in frame 0. Latency: submission to last task.",
             "", "| cameras | DL ms | policy | predicted makespan | predicted K period | "
             "one: period | one: latency | K: period | K: latency | moved | K schedule s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['cameras']} | {r['dl_ms'] or '-'} | {r['policy']} | "
                     f"{r['predicted_makespan_ms']:.2f} | {r['predicted_period_ms']:.2f} | "
                     f"{r['one_period_ms']:.2f} | {r['one_latency_ms']:.2f} | "
                     f"{r['k_period_ms']:.2f} | {r['k_latency_ms']:.2f} | {r['moved_nodes']} | "
                     f"{r['schedule_s']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    import cv2

    import warpvx

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.environ.get("OUT", "benchmarks/results/kframe"))
    ap.add_argument("--cameras", default="1,2,8")
    ap.add_argument("--dl", default="none,20")
    ap.add_argument("--policies", default="heft,xeft")
    ap.add_argument("--cpus", type=int, default=4)
    ap.add_argument("--k", type=int, default=8, help="frames in flight of the K-frame schedule")
    ap.add_argument("--depth", type=int, default=8, help="frames in flight of both streams")
    ap.add_argument("--stream-frames", type=int, default=16)
    ap.add_argument("--width", type=int, default=1241)
    ap.add_argument("--height", type=int, default=376)
    ap.add_argument("--gpu", default=None, help="'cuda', 'warp-cpu' or none (CUDA if present)")
    ap.add_argument("--budget-s", type=float, default=150.0,
                    help="no new cell starts after this many seconds (8 cameras: ~0.4 s a frame)")
    args = ap.parse_args(argv)
    command = "PYTHONPATH=. python3 benchmarks/kframe_bench.py " + \
        " ".join(sys.argv[1:] if argv is None else argv)
    cv2.setNumThreads(1)  # one core per CPU worker, as calibration assumes
    os.makedirs(args.out, exist_ok=True)
    rows, started = [], time.perf_counter()
    for n_cams in map(int, args.cameras.split(",")):
        frames = _camera_frames(n_cams, args.width, args.height, args.stream_frames)
        for dl in [None if d == "none" else float(d) for d in args.dl.split(",")]:
            if time.perf_counter() - started > args.budget_s:
                print(f"budget: skipping cameras={n_cams} dl={dl}", flush=True)
                continue
            g = warpvx.orb_graph(n_cams, dl_node_ms=dl, width=args.width, height=args.height)
            g.calibrate(frames[0], gpu=args.gpu)
            for policy in args.policies.split(","):
                if time.perf_counter() - started > args.budget_s:
                    print(f"budget: skipping cameras={n_cams} dl={dl} {policy}", flush=True)
                    continue
                row = {"cameras": n_cams, "dl_ms": dl, **cell(g, frames, args, policy)}
                rows.append(row)
                print(json.dumps(row), flush=True)
            g.close()
    with open(os.path.join(args.out, "kframe_bench.json"), "w") as f:
        json.dump({"argv": sys.argv[1:], "rows": rows}, f, indent=1)
    with open(os.path.join(args.out, "kframe_bench.md"), "w") as f:
        f.write(markdown(rows, args, command))
    print(f"ran in {time.perf_counter() - started:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
