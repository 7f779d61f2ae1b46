"""The two-camera graph's pipelined stream on the GPU machine, eager against captured, with a
reset between runs (a new video: the case where a captured segment used to turn eager for
good), downloads staged (pinned, on the GPU role's copy stream) against synchronous, and
where one frame's device time goes, kernel by kernel, and on which stream.

    PYTHONPATH=. python3 benchmarks/perf/capture_stream.py --out $OUT/cs

Writes ``capture_stream.md`` (the command on top): FPS per (capture, depth, staged) run, each
after a ``reset``; the captured graphs launched per captured run (``Executor.replays``: frames
- 1 after a reset, the first frame reading the delays' initial values); the downloads per
frame, staged (queued on the GPU role's copy stream into pinned buffers, as soon as their
producer is enqueued) or synchronous (on the reader's thread's stream, pageable); one frame's
activities on the device (``wp.timing_begin``: kernels, copies, graph launches), eager and
captured, each with its stream. The runs without staging come last: they close the
executor's host pool (``HostPool.close``: every download then takes the synchronous path).
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

from warpvx.runtime import Executor, Transfers, tree_map  # noqa: E402

#: Downloads so far: staged (the GPU role's copy stream, pinned) and synchronous (the reader's).
COUNTS = collections.Counter()


def _count_downloads():
    """Count the downloads of each kind (instrumentation of this benchmark only)."""
    stage, download = Transfers.stage_download, Transfers._download_array
    counted_rows = Transfers.counted_rows

    def staged(self, value, event=None):
        got = stage(self, value, event)
        if got is not None:
            COUNTS["staged"] += len(got.copies)
            COUNTS["staged bytes"] += got.nbytes
        return got

    def synchronous(self, a, event):
        out = download(self, a, event)
        COUNTS["synchronous"] += 1
        COUNTS["synchronous bytes"] += out.nbytes
        return out

    def rows(self, c, count):  # a large Counted's rows, copied when read: the reader waits
        out = counted_rows(self, c, count)
        COUNTS["synchronous"] += 1
        sizes = []
        tree_map(lambda a: sizes.append(a.nbytes) or a, out)
        COUNTS["synchronous bytes"] += sum(sizes)
        return out

    Transfers.stage_download, Transfers._download_array = staged, synchronous
    Transfers.counted_rows = rows


def stream_of(name: str, staged: bool) -> str:
    """Where an activity of ``wp.timing`` ran (Warp does not say: by what queued it):
    device-to-host copies on copy streams (staged: the GPU role's, and the reader's for a
    large Counted's rows, into pinned memory; else the reader's, pageable), everything else
    on the compute stream."""
    if name.startswith("memcpy DtoH"):
        return "copy, pinned" if staged else "copy, pageable"
    return "compute"


def stream_fps(g, frames, capture: bool, depth: int, n: int) -> tuple:
    """FPS of ``n`` frames pipelined after a reset (the first ``2 * depth`` not timed), the
    captured graphs launched meanwhile, the frames timed and their downloads per frame."""
    ex = g.plan.executor()
    g.reset()
    feed = (frames[i % len(frames)] for i in range(n + 2 * depth))
    stream = g.stream(feed, depth=depth, capture=capture)
    for _ in range(2 * depth):
        next(stream)
    replays = ex.replays
    before = COUNTS.copy()
    t0 = time.perf_counter()
    done = sum(1 for _ in stream)
    fps = done / (time.perf_counter() - t0)
    moved = {k: (COUNTS[k] - before[k]) / max(done, 1) for k in
             ("staged", "staged bytes", "synchronous", "synchronous bytes")}
    return fps, ex.replays - replays, done, moved


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
    _count_downloads()
    if not args.gpu.startswith("cuda"):  # the staged path's code, without the DMA
        Executor.STAGE_ON_HOST = True
    t_start = time.perf_counter()
    frames = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(frames[:2])
    g.schedule("baseline", n_cpus=4, gpu=args.gpu)
    print(f"graph ready in {time.perf_counter() - t_start:.0f} s", flush=True)
    lines = [f"<!-- PYTHONPATH=. python3 {' '.join(['benchmarks/perf/capture_stream.py', *sys.argv[1:]])} -->",
             f"# Two-camera graph {size[0]}x{size[1]}, baseline placement: pipelined stream "
             "after a reset, eager vs captured, downloads staged vs synchronous", "",
             "| run | capture | depth | staged | FPS | captured graphs launched | frames | "
             "staged downloads / frame (KB) | synchronous downloads / frame (KB) |",
             "|---:|---|---:|---|---:|---:|---:|---:|---:|"]
    runs = [(False, 1), (False, 3), (True, 1), (True, 3), (True, 6), (True, 3)]
    try:
        acts = {}
        for staged in (True, False):
            if not staged:
                pool = g.plan.executor()._host_pool
                if pool is not None:
                    pool.close()
            for capture, depth in runs if staged else runs[2:5]:
                fps, replays, done, moved = stream_fps(g, frames, capture, depth, args.frames)
                lines.append(
                    f"| {len(lines) - 4} | {capture} | {depth} | {staged} | {fps:.1f} | {replays} "
                    f"| {done} | {moved['staged']:.1f} ({moved['staged bytes'] / 1e3:.0f}) | "
                    f"{moved['synchronous']:.1f} ({moved['synchronous bytes'] / 1e3:.0f}) |")
                print(lines[-1], flush=True)
            for capture in (False, True) if args.gpu.startswith("cuda") else ():
                acts[capture, staged] = device_activities(g, frames, capture)
                print(f"device activities: capture={capture} staged={staged}", flush=True)
        for (capture, staged), rows in acts.items():
            total = sum(us for _, _, us in rows)
            lines += ["", f"One {'captured' if capture else 'eager'} frame on the device, "
                      f"downloads {'staged' if staged else 'synchronous'} (one frame at a time, "
                      f"`Graph.process`): {total:.0f} us of activity (sum over streams)", "",
                      "| activity | stream | per frame | us per frame |", "|---|---|---:|---:|"]
            lines += [f"| {name[:80]} | {stream_of(name, staged)} | {c:.1f} | {us:.1f} |"
                      for name, c, us in rows[:20]]
            per = collections.defaultdict(float)
            for name, _, us in rows:
                per[stream_of(name, staged)] += us
            lines += ["", "Per stream: " + ", ".join(f"{k} {v:.0f} us" for k, v in per.items())]
    finally:
        g.close()
    lines += ["", f"Total {time.perf_counter() - t_start:.0f} s."]
    (out / "capture_stream.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'capture_stream.md'}")


if __name__ == "__main__":
    main()
