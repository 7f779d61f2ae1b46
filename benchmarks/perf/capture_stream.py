"""The two-camera graph's pipelined stream on the GPU machine: eager against captured, with
captured segments' buffer sets per frame in flight on and off (frames overlapping on the
device), frames in pageable against pinned host memory, and where one frame's device time goes.

    PYTHONPATH=. python3 benchmarks/perf/capture_stream.py --out $OUT/cs

Writes ``capture_stream.md`` (the command on top): FPS per run, each after a ``reset``, for
``Executor.instances`` (1: every frame's copies in, replay and copies out on the executor's
one stream, in order; K: frames go round K buffer sets and graphs, each set on a stream of its
own) and ``Executor.linked`` (a frame's tasks reading the previous frame's delayed values wait
for those inside the graph, not the whole frame for the previous one), frames in pageable
memory (staged through pinned buffers on the host first) or in pinned memory
(``warpvx.runtime.pinned_array``: one DMA); the captured graphs launched per run; how the
last frames' device intervals (a captured segment's start and end events, on its set's
stream) overlap: their sum over the time the device had one or more of them (1.0: one after
the other); the GPU role's thread's host time per frame (its calls for the frame's GPU work:
copies in and their staging, launch, copies out); the downloads per frame; one frame's
activities on the device
(``wp.timing_begin``: kernels, copies, graph launches), eager and captured, each with its
stream.
"""

from __future__ import annotations

import argparse
import collections
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import graph_bench  # noqa: E402

from warpvx.runtime import Executor, Transfers, pinned_copy, tree_map  # noqa: E402

#: Downloads so far: staged (the GPU role's copy stream, pinned) and synchronous (the reader's).
COUNTS = collections.Counter()


def _count_downloads():
    """Count the downloads of each kind (instrumentation of this benchmark only)."""
    stage, download = Transfers.stage_download, Transfers._download_array
    rows_copy = Transfers._counted_rows_copy

    def staged(self, value, event=None, **kw):
        got = stage(self, value, event, **kw)
        if got is not None:
            COUNTS["staged"] += len(got.copies)
            COUNTS["staged bytes"] += got.nbytes
        return got

    def synchronous(self, a, event):
        out = download(self, a, event)
        COUNTS["synchronous"] += 1
        COUNTS["synchronous bytes"] += out.nbytes
        return out

    def rows(self, block, n, count):  # a large Counted's rows past its staged prefix, copied
        out = rows_copy(self, block, n, count)  # when read: the reader waits
        COUNTS["synchronous"] += 1
        sizes = []
        tree_map(lambda a: sizes.append(a.nbytes) or a, out)
        COUNTS["synchronous bytes"] += sum(sizes)
        return out

    Transfers.stage_download, Transfers._download_array = staged, synchronous
    Transfers._counted_rows_copy = rows


def stream_of(name: str) -> str:
    """Where an activity of ``wp.timing`` ran (Warp does not say: by what queued it):
    device-to-host copies on copy streams (the GPU role's, and the reader's for a large
    Counted's rows, into pinned memory), everything else on the compute stream (the
    executor's, or with buffer sets per frame the set's)."""
    return "copy" if name.startswith("memcpy DtoH") else "compute"


def stream_fps(g, frames, capture: bool, depth: int, n: int) -> tuple:
    """FPS of ``n`` frames pipelined after a reset (the first frames not timed: the sets'
    captures), the captured graphs launched meanwhile, the frames timed, their downloads per
    frame and :func:`overlap` of the last ones."""
    ex = g.plan.executor()
    g.reset()
    warm = 2 * depth + 3 * ex.instances
    feed = (frames[i % len(frames)] for i in range(n + warm))
    stream = g.stream(feed, depth=depth, capture=capture)
    for _ in range(warm):
        next(stream)
    replays = ex.replays
    before = COUNTS.copy()
    t0 = time.perf_counter()
    done = sum(1 for _ in stream)
    fps = done / (time.perf_counter() - t0)
    moved = {k: (COUNTS[k] - before[k]) / max(done, 1) for k in
             ("staged", "staged bytes", "synchronous", "synchronous bytes")}
    return fps, ex.replays - replays, done, moved, overlap(g)


def overlap(g) -> tuple:
    """The last frames' GPU work: (median device interval ms (their GPU tasks' earliest start
    to latest finish, on the device's clock: nan off CUDA), the intervals' sum over the time
    covered by one or more of them (1.0: one after the other; nan off CUDA), median host ms
    the GPU role's thread spent on them (its calls: enqueue, copies in, staging))."""
    ex = g.plan.executor()
    gpu = {t.name for seg in ex._segments for t in seg.tasks}
    spans, host = [], []
    for r in list(g.plan.last_run)[-48:]:
        names = [n for n in gpu if n in r.timeline]
        if names:
            ts = [r.timeline[n] for n in names]
            t0 = r.t0 * 1e3
            spans.append((t0 + min(t.start for t in ts), t0 + max(t.finish for t in ts)))
            hs = [r.host[n] for n in names if n in r.host]
            if hs:
                host.append(max(b for _, b in hs) - min(a for a, _ in hs))
    host_ms = statistics.median(host) if host else float("nan")
    if not spans or not ex.cuda:
        return float("nan"), float("nan"), host_ms
    spans.sort()
    covered, end = 0.0, -float("inf")
    for a, b in spans:
        if b > end:
            covered += b - max(a, end)
            end = b
    total = sum(b - a for a, b in spans)
    return (statistics.median(b - a for a, b in spans),
            total / covered if covered > 0 else float("nan"), host_ms)


#: (instances, linked) configurations of the captured runs: one stream (before), sets on
#: streams of their own, each frame's whole run waiting for the previous one, and linked.
CONFIGS = ((1, False), (3, False), (3, True), (6, True))


def device_activities(g, frames, capture: bool, n: int = 10) -> list:
    """One frame's device activities (name, launches per frame, us per frame), most first."""
    import warp as wp

    for i in range(8 + 3 * g.plan.executor().instances):  # warm, and every set's capture
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
    ap.add_argument("--frames", type=int, default=600, help="timed frames per run")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    _count_downloads()
    cuda = args.gpu.startswith("cuda")
    if not cuda:  # the staged path's code, without the DMA; and captures asked for
        Executor.STAGE_ON_HOST = True
    t_start = time.perf_counter()
    frames = graph_bench.make_frames(size, 16)
    memories = {"pageable": frames,
                "pinned": [{k: pinned_copy(v) for k, v in f.items()} for f in frames]}
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(frames[:2])
    g.schedule("baseline", n_cpus=4, gpu=args.gpu)
    ex = g.plan.executor()
    print(f"graph ready in {time.perf_counter() - t_start:.0f} s", flush=True)
    lines = [f"<!-- PYTHONPATH=. python3 {' '.join(['benchmarks/perf/capture_stream.py', *sys.argv[1:]])} -->",
             f"# Two-camera graph {size[0]}x{size[1]}, baseline placement: pipelined stream "
             "after a reset, eager vs captured, buffer sets per frame in flight, pageable vs "
             "pinned frames", "",
             "| run | capture | depth | instances | linked | frames in | FPS | captured graphs "
             "launched | frames | frame's GPU interval (ms, median) | overlap (sum / covered) | "
             "GPU thread host ms / frame (median) | "
             "staged downloads / frame (KB) | synchronous downloads / frame (KB) |",
             "|---:|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    runs = [(False, 3, 1, False, "pageable")]
    runs += [(True, depth, k, linked, mem) for mem in memories for depth in (3, 6)
             for k, linked in CONFIGS]
    try:
        for capture, depth, k, linked, mem in runs:
            ex.instances, ex.linked = k, linked
            row = f"| {len(lines) - 4} | {capture} | {depth} | {k} | {linked} | {mem} | "
            try:
                fps, replays, done, moved, (span, lap, host) = stream_fps(
                    g, memories[mem], capture, depth, args.frames)
                row += (f"{fps:.1f} | {replays} | {done} | {span:.3f} | {lap:.2f} | {host:.3f} | "
                        f"{moved['staged']:.1f} ({moved['staged bytes'] / 1e3:.0f}) | "
                        f"{moved['synchronous']:.1f} ({moved['synchronous bytes'] / 1e3:.0f}) |")
            except Exception as exc:  # noqa: BLE001 - a failed configuration is a result too
                row += f"failed: {type(exc).__name__}: {str(exc)[:120]} | | | | | | | |"
            lines.append(row)
            print(row, flush=True)
        acts = {}
        ex.instances, ex.linked = None, True
        for capture in (False, True) if cuda else ():
            acts[capture] = device_activities(g, frames, capture)
            print(f"device activities: capture={capture}", flush=True)
        for capture, rows in acts.items():
            total = sum(us for _, _, us in rows)
            lines += ["", f"One {'captured' if capture else 'eager'} frame on the device, "
                      f"(one frame at a time, `Graph.process`, instances {ex.instances}): "
                      f"{total:.0f} us of activity (sum over streams)", "",
                      "| activity | stream | per frame | us per frame |", "|---|---|---:|---:|"]
            lines += [f"| {name[:80]} | {stream_of(name)} | {c:.1f} | {us:.1f} |"
                      for name, c, us in rows[:20]]
            per = collections.defaultdict(float)
            for name, _, us in rows:
                per[stream_of(name)] += us
            lines += ["", "Per stream: " + ", ".join(f"{k} {v:.0f} us" for k, v in per.items())]
    finally:
        g.close()
    lines += ["", f"Total {time.perf_counter() - t_start:.0f} s."]
    (out / "capture_stream.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'capture_stream.md'}")


if __name__ == "__main__":
    main()
