"""Where the pipelined two-camera stream's time goes, per thread: FPS per placement with the
CPU time each thread spent per frame (``/proc/self/task/*/stat``: user + system in clock
ticks of 10 ms, so time long runs; it includes CUDA's spin-waits), and the CPU tasks' compute
and transfer-wait medians.

    PYTHONPATH=. python3 benchmarks/perf/pipeline_threads.py --out $OUT/pt

1280x720 (``--size``), pinned frames, depth 3, captured, 3 linked buffer sets, OpenCV on one
thread (``--cv-threads``, as ``graph_bench.py``)
(``capture_stream.py``'s fastest configuration); placements: ``baseline`` (the CPU-only nodes, the two homographies
and ``fuse``, all on one CPU worker), ``split`` (the baseline with ``homographyR`` on a
second worker) and any policy name (``heft``, ...), run in interleaved rounds. Writes
``pipeline_threads.md`` (the command on top).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))

import graph_bench  # noqa: E402
from perf_common import baseline_moving, add_cv_threads, frame_size, opencv_threads, positive  # noqa: E402

from warpvx.runtime import pinned_copy  # noqa: E402


def split(dag):
    """The baseline placement with ``homographyR`` on a second CPU worker."""
    return baseline_moving(dag, "homographyR", "cpu1", "baseline-split")


def cpu_seconds_by_thread() -> dict:
    """native thread id -> (CPU seconds so far, Python thread name or "?" (OpenCV's, Warp's))."""
    clk = os.sysconf("SC_CLK_TCK")
    names = {t.native_id: t.name for t in threading.enumerate()}
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended
            continue
        out[int(tid)] = ((int(fields[11]) + int(fields[12])) / clk, names.get(int(tid), "?"))
    return out


def stream_round(g, plan, frames, n: int, warm: int = 20) -> dict:
    """``n`` frames streamed through ``plan`` after a reset: FPS, the frame period's median,
    each thread's CPU ms per frame and the CPU tasks' compute / transfer medians (ms)."""
    g.use_plan(plan)
    ex = plan.executor()
    ex.instances, ex.linked = 3, True
    g.reset()
    st = g.stream((frames[i % len(frames)] for i in range(n + warm)), depth=3, capture=True)
    for _ in range(warm):
        next(st)
    a = cpu_seconds_by_thread()
    t0 = time.perf_counter()
    done = sum(1 for _ in st)
    dt = time.perf_counter() - t0
    b = cpu_seconds_by_thread()
    threads = sorted(((b[t][0] - a.get(t, (0.0, ""))[0]) / done * 1e3, b[t][1]) for t in b)[::-1]
    runs = list(plan.last_run)[-48:]
    cpu_nodes = [node for node, p in plan.placement.items() if p != "gpu"]
    tasks = {node: (statistics.median(r.compute_ms(node) for r in runs if node in r.timeline),
                    statistics.median(r.transfers.get(node, 0.0) for r in runs
                                      if node in r.timeline))
             for node in cpu_nodes}
    starts = sorted(r.t0 for r in runs)
    period = statistics.median(y - x for x, y in zip(starts, starts[1:])) * 1e3
    return {"fps": done / dt, "period_ms": period, "threads": threads, "tasks": tasks}


#: Placements a run may name: the scheduler's policies (placed on the graph's calibrated
#: costs) and :func:`split`.
PLACEMENTS = (*graph_bench.SCHEDULERS, "split")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for pipeline_threads.md")
    ap.add_argument("--frames", type=positive, default=1200, help="timed frames per run")
    ap.add_argument("--rounds", type=positive, default=3)
    ap.add_argument("--policies", default="baseline,split",
                    help=f"comma-separated, of {', '.join(PLACEMENTS)}")
    ap.add_argument("--size", type=frame_size, default=(1280, 720), help="WxH")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    add_cv_threads(ap)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    names = args.policies.split(",")
    unknown = [n for n in names if n not in PLACEMENTS]
    if unknown:
        ap.error(f"--policies: unknown {', '.join(map(repr, unknown))}; "
                 f"expected some of {', '.join(PLACEMENTS)}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with opencv_threads(args.cv_threads):
        _run(args, argv, names, out)


def _run(args, argv, names, out):
    size = args.size
    frames = graph_bench.make_frames(size, 16)
    if args.gpu.startswith("cuda"):
        frames = [{k: pinned_copy(v) for k, v in f.items()} for f in frames]
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(frames[:2])
    plans = {}
    for name in names:
        g.schedule(split if name == "split" else name, n_cpus=4, gpu=args.gpu)
        plans[name] = g.plan
    lines = [f"<!-- PYTHONPATH=. python3 benchmarks/perf/pipeline_threads.py {' '.join(argv)} -->",
             f"# Two-camera graph {size[0]}x{size[1]} pipelined (pinned, depth 3, captured, 3 linked sets): "
             "per-thread CPU ms per frame", "",
             f"OpenCV threads: {cv2.getNumThreads()}.", "",
             "Placements (CPU nodes): " + "; ".join(
                 f"{k}: " + ", ".join(f"{n} {p}" for n, p in pl.placement.items() if p != "gpu")
                 for k, pl in plans.items()), "",
             "| round | placement | FPS | frame period ms (median) | thread CPU ms / frame | "
             "CPU tasks: compute / transfer wait ms (median) |", "|---:|---|---:|---:|---|---|"]
    try:
        for r in range(args.rounds):
            for name, plan in plans.items():
                res = stream_round(g, plan, frames, args.frames)
                threads = ", ".join(f"{n} {ms:.3f}" for ms, n in res["threads"] if ms > 0.01)
                tasks = ", ".join(f"{n} {c:.3f} / {w:.3f}" for n, (c, w) in res["tasks"].items())
                row = f"| {r} | {name} | {res['fps']:.1f} | {res['period_ms']:.3f} | {threads} | {tasks} |"
                lines.append(row)
                print(row, flush=True)
    finally:
        g.close()
    (out / "pipeline_threads.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'pipeline_threads.md'}")


if __name__ == "__main__":
    main()
