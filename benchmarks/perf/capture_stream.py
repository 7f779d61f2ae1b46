"""The two-camera graph's pipelined stream on the GPU machine, eager against captured, with a
reset between runs (a new video: the case where a captured segment used to turn eager for
good), and where one frame's device time goes, kernel by kernel.

    PYTHONPATH=. python3 benchmarks/perf/capture_stream.py --out $OUT/capture_stream

Writes ``capture_stream.md`` (the command on top): FPS per (capture, depth) run, each after a
``reset``; the captured graphs launched per captured run (``Executor.replays``: frames - 1
after a reset, the first frame reading the delays' initial values); one frame's activities on
the device (``wp.timing_begin``: kernels, copies, graph launches), eager and captured.
"""

from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import graph_bench  # noqa: E402


def stream_fps(g, frames, capture: bool, depth: int, n: int) -> tuple:
    """FPS of ``n`` frames pipelined after a reset (the first ``2 * depth`` not timed), and
    the captured graphs launched meanwhile."""
    ex = g.plan.executor()
    g.reset()
    feed = (frames[i % len(frames)] for i in range(n + 2 * depth))
    stream = g.stream(feed, depth=depth, capture=capture)
    for _ in range(2 * depth):
        next(stream)
    replays = ex.replays
    t0 = time.perf_counter()
    done = sum(1 for _ in stream)
    return done / (time.perf_counter() - t0), ex.replays - replays, done


def device_activities(g, frames, capture: bool, n: int = 10) -> list:
    """One frame's device activities (name, launches per frame, us per frame), most first."""
    import warp as wp

    for i in range(8):  # warm, and the captures
        g.process(frames[i % len(frames)], capture=capture)
    wp.timing_begin(cuda_filter=wp.TIMING_ALL)
    for i in range(n):
        g.process(frames[i % len(frames)], capture=capture)
    agg = collections.defaultdict(lambda: [0, 0.0])
    for r in wp.timing_end():
        a = agg[r.name]
        a[0] += 1
        a[1] += r.elapsed
    return sorted(((name, c / n, ms / n * 1e3) for name, (c, ms) in agg.items()),
                  key=lambda row: -row[2])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for capture_stream.md")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--frames", type=int, default=300, help="timed frames per run")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(frames[:2])
    g.schedule("baseline", n_cpus=4, gpu=args.gpu)
    lines = [f"<!-- PYTHONPATH=. python3 {' '.join(['benchmarks/perf/capture_stream.py', *sys.argv[1:]])} -->",
             f"# Two-camera graph {size[0]}x{size[1]}, baseline placement: pipelined stream "
             "after a reset, eager vs captured", "",
             "| run | capture | depth | FPS | captured graphs launched | frames |",
             "|---:|---|---:|---:|---:|---:|"]
    try:
        for k, (capture, depth) in enumerate([(False, 1), (False, 3), (True, 1), (True, 3)] * 2):
            fps, replays, done = stream_fps(g, frames, capture, depth, args.frames)
            lines.append(f"| {k + 1} | {capture} | {depth} | {fps:.1f} | {replays} | {done} |")
            print(lines[-1], flush=True)
        for capture in (False, True):
            acts = device_activities(g, frames, capture)
            total = sum(us for _, _, us in acts)
            lines += ["", f"One {'captured' if capture else 'eager'} frame on the device: "
                      f"{total:.0f} us of activity (sum over streams; copies may overlap "
                      "kernels)", "", "| activity | per frame | us per frame |", "|---|---:|---:|"]
            lines += [f"| {name[:80]} | {c:.1f} | {us:.1f} |" for name, c, us in acts[:20]]
    finally:
        g.close()
    (out / "capture_stream.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'capture_stream.md'}")


if __name__ == "__main__":
    main()
