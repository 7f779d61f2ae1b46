"""The two-camera graph captured with its GPU segment on one lane (one stream: a chain of
kernels) against N lanes (the segment's independent branches on concurrent streams inside
the CUDA graph), in one run on the GPU machine.

    PYTHONPATH=. python3 benchmarks/perf/capture_lanes.py --out $OUT/lanes

Writes ``capture_lanes.md`` (the command on top) and ``capture_lanes.json``: per lane cap
(``Executor.max_lanes``), the lanes the captured segment uses, the pipelined FPS at depth 3
and 1 (runs after a ``reset``, lane caps alternated, median of ``--repeats``), one frame's
graph replay on the device (``wp.timing_begin(cuda_filter=wp.TIMING_GRAPH)``: the segment's
graph launch; all activities too), and whether every output of ``--check`` frames equals,
bit for bit, the eager run's and the one-lane run's.
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))

import capture_stream  # noqa: E402
import graph_bench  # noqa: E402


def host_leaves(value) -> list:
    """The arrays of an output (an array, a pyramid's list, Keypoints, Counted) on the host,
    in a fixed order."""
    if isinstance(value, (list, tuple)):
        return [a for v in value for a in host_leaves(v)]
    flat = getattr(value, "__warpvx_flatten__", None)
    if flat is not None:
        return host_leaves(list(flat()[0]))
    if hasattr(value, "numpy") and not isinstance(value, np.ndarray):
        return [value.numpy()]
    return [np.asarray(value)]


def outputs(g, frames, capture: bool) -> list:
    """Every output of ``frames`` run one at a time after a reset, on the host."""
    g.reset()
    return [{k: host_leaves(v) for k, v in g.process(f, capture=capture).items()} for f in frames]


def differences(ref: list, got: list) -> list:
    """``(frame, output)`` of every output of ``got`` unlike ``ref``'s (bit for bit)."""
    bad = []
    for i, (a, b) in enumerate(zip(ref, got)):
        for k in a:
            same = len(a[k]) == len(b[k]) and all(
                x.shape == y.shape and x.dtype == y.dtype and np.array_equal(x, y)
                for x, y in zip(a[k], b[k]))
            if not same:
                bad.append((i, k))
    return bad


def replay_times(g, frames, n: int = 20) -> tuple:
    """One captured frame on the device: (graph launch us, graph launches, all activities us),
    per frame over ``n`` frames after the captures."""
    import warp as wp

    # The captures (a buffer set per frame in flight, two at least) and a few replays.
    for i in range(8 + 3 * g.plan.executor().instances):
        g.process(frames[i % len(frames)], capture=True)
    per = {}
    for kind, flt in (("graph", wp.TIMING_GRAPH), ("all", wp.TIMING_ALL)):
        wp.timing_begin(cuda_filter=flt)
        for i in range(n):
            g.process(frames[i % len(frames)], capture=True)
        per[kind] = wp.timing_end()
    graph = per["graph"]
    return (sum(r.elapsed for r in graph) * 1e3 / n, len(graph) / n,
            sum(r.elapsed for r in per["all"]) * 1e3 / n)


def build(size, frames, gpu: str, max_lanes: int):
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(frames[:2])
    g.schedule("baseline", n_cpus=4, gpu=gpu)
    g.plan.executor().max_lanes = max_lanes
    return g


def lanes_used(g) -> tuple:
    """(lanes, tasks per lane in enqueue order) of the executor's captured segment graph;
    serial tasks (conditional graph nodes: every lane joined) listed after."""
    ex = g.plan.executor()
    found = [sg for states in ex._captured.values() for by_shape in states if by_shape
             for sg in by_shape.values() if sg is not None and sg.captured]
    if not found:
        return 0, ""
    sg = found[0]
    lanes, tasks = sg.lanes, sg.segment.tasks
    per = collections.defaultdict(list)
    for i in lanes.order:
        if i not in lanes.serial:
            per[lanes.of[i]].append(tasks[i].name)
    layout = "; ".join(f"{k}: {' '.join(v)}" for k, v in sorted(per.items()))
    serial = " ".join(tasks[i].name for i in lanes.order if i in lanes.serial)
    if serial:
        layout += f"; then on lane 0, every lane joined: {serial}"
    return lanes.count, layout


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for capture_lanes.md")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--lanes", default="1,4", help="lane caps to compare, the first the reference")
    ap.add_argument("--frames", type=int, default=300, help="timed frames per FPS run")
    ap.add_argument("--repeats", type=int, default=3, help="FPS runs per lane cap and depth")
    ap.add_argument("--check", type=int, default=24, help="frames compared bit for bit")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    args = ap.parse_args(argv)
    # Why a segment would run eagerly (a capture refused): printed, as it changes the result.
    logging.basicConfig(level=logging.WARNING, stream=sys.stdout)
    logging.getLogger("warpvx.capture").setLevel(logging.DEBUG)
    t_start = time.perf_counter()
    size = tuple(int(v) for v in args.size.split("x"))
    caps = [int(v) for v in args.lanes.split(",")]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = graph_bench.make_frames(size, 16)
    check = [frames[i % len(frames)] for i in range(args.check)]
    graphs = {}
    try:
        for cap in caps:
            print(f"building the graph, max_lanes={cap}", flush=True)
            graphs[cap] = build(size, frames, args.gpu, cap)
        print("outputs: eager, then captured per lane cap", flush=True)
        eager = outputs(graphs[caps[0]], check, capture=False)
        got = {cap: outputs(graphs[cap], check, capture=True) for cap in caps}
        fps = {(cap, d): [] for cap in caps for d in (1, 3)}
        for rep in range(args.repeats):  # lane caps alternated: drift hits both alike
            for depth in (3, 1):
                for cap in caps:
                    f, _, _ = capture_stream.stream_fps(graphs[cap], frames, True, depth,
                                                        args.frames)
                    fps[cap, depth].append(f)
                    print(f"repeat {rep + 1} max_lanes={cap} depth={depth}: {f:.1f} FPS",
                          flush=True)
        rows = []
        for cap in caps:
            graph_us, launches, all_us = replay_times(graphs[cap], frames)
            count, layout = lanes_used(graphs[cap])
            rows.append({
                "max_lanes": cap, "lanes": count, "layout": layout,
                "fps3": statistics.median(fps[cap, 3]), "fps3_all": fps[cap, 3],
                "fps1": statistics.median(fps[cap, 1]), "fps1_all": fps[cap, 1],
                "graph_us": graph_us, "graph_launches": launches, "device_us": all_us,
                "unlike_eager": differences(eager, got[cap]),
                "unlike_one_lane": differences(got[caps[0]], got[cap]),
            })
            print(rows[-1], flush=True)
    finally:
        for g in graphs.values():
            g.close()
    given = argv if argv is not None else sys.argv[1:]
    cmd = " ".join(["benchmarks/perf/capture_lanes.py", *given])
    lines = [f"<!-- PYTHONPATH=. python3 {cmd} -->",
             f"# Two-camera graph {size[0]}x{size[1]}, baseline placement, captured: its GPU "
             f"segment on one lane vs several ({args.gpu})", "",
             f"FPS: median of {args.repeats} pipelined runs of {args.frames} frames after a "
             "reset (all runs listed). Graph replay: the segment's graph launch per frame on "
             "the device (`wp.TIMING_GRAPH`); device activity: every kernel, copy and graph "
             f"per frame (sum over streams). Outputs: {args.check} frames, every output bit for "
             "bit against the eager run and the first lane cap's.", "",
             "| max_lanes | lanes used (0: not captured) | FPS depth 3 | FPS depth 1 "
             "| graph replay us/frame | graph launches/frame | device activity us/frame "
             f"| outputs = eager | outputs = max_lanes {caps[0]} |",
             "|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['max_lanes']} | {r['lanes']} | {r['fps3']:.1f} | {r['fps1']:.1f} | "
            f"{r['graph_us']:.0f} | {r['graph_launches']:.1f} | {r['device_us']:.0f} | "
            f"{'yes' if not r['unlike_eager'] else 'NO: ' + str(r['unlike_eager'][:5])} | "
            f"{'yes' if not r['unlike_one_lane'] else 'NO: ' + str(r['unlike_one_lane'][:5])} |")
    lines += ["", "FPS of every run (depth 3 / depth 1):", ""]
    lines += [f"- max_lanes {r['max_lanes']}: {', '.join(f'{v:.0f}' for v in r['fps3_all'])} / "
              f"{', '.join(f'{v:.0f}' for v in r['fps1_all'])}" for r in rows]
    lines += ["", "Lanes of the captured segment (lane: tasks in enqueue order; serial "
              "tasks insert conditional graph nodes, so Warp pauses the capture there and "
              "they run on lane 0 with every lane joined):", ""]
    lines += [f"- max_lanes {r['max_lanes']}: {r['layout']}" for r in rows]
    lines += ["", f"Run time {time.perf_counter() - t_start:.0f} s."]
    (out / "capture_lanes.md").write_text("\n".join(lines) + "\n")
    (out / "capture_lanes.json").write_text(json.dumps(rows, indent=1))
    print("\n".join(lines))
    print(f"wrote {out / 'capture_lanes.md'}")


if __name__ == "__main__":
    main()
