"""Executor overhead per node and pipelined frame rate, captured GPU segments against eager.

1. Trivial chains (identity user nodes, :func:`warpvx.graph.diagnostics.executor_overhead`):
   CPU-only, GPU-only (with the executor's default GPU timing, and with ``timing="bursts"``:
   one timing event per run of GPU tasks instead of one per task), alternating CPU/GPU; per
   node: wall time per frame minus the nodes' own time, over the nodes. These user nodes do
   not opt in to capture.
   Then the calls a frame makes on those chains, counted rather than timed (``Graph.process``;
   :mod:`native_counts`): Python function calls and native Warp calls (CUDA events, stream
   waits and syncs, copies, context and stream switches, by name), per node and per frame.
2. A GPU-only chain of primitive nodes (3x3 Gaussian blurs of a 16x16 gray image, which the
   runtime may capture), eager and captured: per node = the difference of the frame times of
   a long and a short chain over the difference of their lengths (what one more node costs:
   its kernel call on the host eagerly, its share of one graph launch when captured).
3. The 16-node two-camera graph of ``benchmarks/graph_bench.py`` (its builder and frames), at
   1280x720, baseline placement, pipelined with 3 and 8 frames in flight, eager and captured;
   the report names the captured segments and the GPU nodes that still run eagerly, and
   first checks that captured frames give the eager outputs bit for bit (16 frames).

4. With ``--ab TREE`` (another checkout of warpvx, e.g. the code before a change, or a git
   revision of this checkout, extracted into a temporary folder): the identity
   chains of section 1 run in fresh processes alternating between TREE and this tree
   (``--ab-pairs`` pairs, the order swapped every pair), so both see the same machine state;
   the table gives each tree's median and the change, and each tree's calls per node and per
   frame (counted once per tree, after its timings).

On Warp's CPU device (``--gpu warp-cpu``) "captured" rows replay Warp's CPU graphs (Warp 1.19
captures there too, ``capture=True``); on CUDA they are CUDA graphs (the default there).

Usage::

    PYTHONPATH=. python3 benchmarks/overhead_bench.py --gpu cuda --out $OUT/overhead   # GPU
    PYTHONPATH=. python benchmarks/overhead_bench.py --gpu warp-cpu --quick            # anywhere
    PYTHONPATH=. python3 benchmarks/overhead_bench.py --gpu cuda --out $OUT/o --ab REV  # A/B

Writes ``overhead_bench.md`` (its first line is the command), ``overhead_bench.json``, and ``overhead_profile_gpu.txt`` and ``overhead_profile_mixed.txt``: the
GPU-only and alternating chains under cProfile, every thread
(:func:`warpvx.graph.diagnostics.profile_overhead`).
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

import graph_bench  # noqa: E402 - the two-camera graph's builder and frames, next to this file
import native_counts  # noqa: E402 - calls per node and per frame, next to this file

import warpvx  # noqa: E402
from warpvx.backend import init_warp  # noqa: E402
from warpvx.graph.diagnostics import executor_overhead, profile_overhead  # noqa: E402

MODES = {"eager": False, "captured": True}


def chain_sizes(n: int) -> tuple:
    """The identity chains: (kind, nodes) each; the alternating one has half the nodes, as
    each of its rounds is two."""
    return (("gpu", n), ("mixed", n // 2), ("cpu", n))


def _chains(args) -> list:
    """Section 1: the identity chains (rows as executor_overhead returns them)."""
    n, frames = args.nodes, args.frames
    rows = [executor_overhead(n, frames),
            executor_overhead(n, frames, chain="gpu", gpu=args.gpu),
            executor_overhead(n, frames, chain="gpu", gpu=args.gpu, timing="bursts"),
            executor_overhead(n // 2, frames, chain="mixed", gpu=args.gpu)]
    for r in rows:
        print(f"  {_chain_label(r):5s} chain, {r['n_nodes']} identity nodes: "
              f"{r['per_node_us']:.1f} us/node process, {r['per_node_us_stream']:.1f} stream",
              flush=True)
    for chain, nodes in chain_sizes(n)[:2]:  # where the host time goes (not the CPU chain)
        try:
            text = profile_overhead(nodes, frames, chain=chain, gpu=args.gpu)
        except Exception as exc:  # noqa: BLE001 - a profiler clash must not lose the tables
            text = f"profile failed: {type(exc).__name__}: {exc}\n"
        (args.out / f"overhead_profile_{chain}.txt").write_text(text)
        print(f"  wrote overhead_profile_{chain}.txt", flush=True)
    return rows


#: One A/B run, in a fresh process importing warpvx from argv[1]: the identity chains timed
#: by this code whatever the tree (a tree's own diagnostics may differ), JSON on stdout.
_AB_RUN = """
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
sys.path.insert(1, sys.argv[6])
import cv2
import numpy as np
import warpvx
from warpvx.graph.diagnostics import _chain, _time_direct
import native_counts
if not warpvx.__file__.startswith(sys.argv[1]):
    raise SystemExit(f"imported {warpvx.__file__}, not the tree's")
cv2.setNumThreads(1)
frames, gpu, count = int(sys.argv[3]), sys.argv[4], sys.argv[5] == "1"
x = np.arange(4, dtype=np.float32)
rows, calls = [], {}
for chain, nodes in json.loads(sys.argv[2]):
    g = _chain(nodes, chain)
    g.schedule("heft", n_cpus=1, gpu=False if chain == "cpu" else gpu)
    for _ in range(10):
        g.process({"x": x})
    wall = []
    for _ in range(frames):  # as a caller keeping no results
        t0 = time.perf_counter()
        g.process({"x": x})
        wall.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for _ in g.stream(({"x": x} for _ in range(frames)), depth=4):
        pass
    stream = (time.perf_counter() - t0) / frames
    g.close()
    t_call = _time_direct(nodes)
    rows.append({"chain": chain, "n_nodes": nodes,
                 "per_node_us": (statistics.median(wall) - t_call) / nodes * 1e6,
                 "per_node_us_stream": (stream - t_call) / nodes * 1e6})
    if count:  # after the timing: the counters slow every call
        calls[chain] = native_counts.chain_calls(_chain, chain, nodes, gpu)
print(json.dumps({"rows": rows, "calls": calls}))
"""


def _tree(ab: str) -> str:
    """``--ab``'s tree: a folder, or a git revision of this checkout extracted (git archive)
    into a temporary folder (not the results folder: what comes back is a few files)."""
    if Path(ab).is_dir():
        return str(Path(ab).resolve())
    dest = Path(tempfile.mkdtemp(prefix="warpvx-ab-")).resolve()
    archive = subprocess.run(["git", "-C", str(ROOT.parent), "archive", ab],
                             capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return str(dest)


def _ab_runs(args, trees: dict) -> dict:
    """tree name -> its runs (each a list of chain rows), ABBA order, fresh processes."""
    runs = {k: [] for k in trees}
    calls = {}
    for pair in range(args.ab_pairs):
        order = ("before", "after") if pair % 2 == 0 else ("after", "before")
        for k in order:
            count = "1" if pair == 0 else "0"  # the same every run: each tree's once
            out = subprocess.run([sys.executable, "-c", _AB_RUN, trees[k],
                                  json.dumps(chain_sizes(args.nodes)), str(args.frames), args.gpu,
                                  count, str(ROOT)],
                                 capture_output=True, text=True, timeout=300)
            if out.returncode:
                raise RuntimeError(f"{k} ({trees[k]}): {out.stderr.strip()[-2000:]}")
            got = json.loads(out.stdout.strip().splitlines()[-1])
            runs[k].append(got["rows"])
            if got["calls"]:
                calls[k] = got["calls"]
            print(f"  pair {pair + 1}/{args.ab_pairs} {k}: " + ", ".join(
                f"{r['chain']} {r['per_node_us']:.1f}" for r in runs[k][-1]) + " us/node",
                flush=True)
    return runs, calls


def _ab(args) -> list:
    """Section 4: the identity chains of ``args.ab`` (a tree) and of this tree, in fresh
    processes, alternating (ABBA...); rows of per-tree medians."""
    trees = {"before": _tree(args.ab), "after": str(ROOT.parent)}
    try:
        runs, calls = _ab_runs(args, trees)
    finally:
        if not Path(args.ab).is_dir():  # a revision, extracted for this run
            shutil.rmtree(trees["before"], ignore_errors=True)
    rows = []
    for i, first in enumerate(runs["after"][0]):
        row = {"chain": first["chain"], "n_nodes": first["n_nodes"], "pairs": args.ab_pairs}
        for k in trees:
            row[k] = {m: statistics.median(run[i][m] for run in runs[k])
                      for m in ("per_node_us", "per_node_us_stream")}
            row[k]["all"] = [round(run[i]["per_node_us"], 2) for run in runs[k]]
        rows.append(row)
    return [{"trees": trees, "rows": rows, "calls": calls}]


def _calls(args) -> list:
    """Section 1b: this tree's calls per node and per frame on the identity chains (counted;
    :mod:`native_counts`)."""
    from warpvx.graph.diagnostics import _chain

    out = {}
    for chain, nodes in chain_sizes(args.nodes):
        out[chain] = native_counts.chain_calls(_chain, chain, nodes, args.gpu)
        print(f"  {chain}: per node / per frame: python {out[chain]['python']}, native "
              f"{out[chain]['native']}", flush=True)
    return [{"trees": {"this tree": str(ROOT.parent)}, "calls": {"this tree": out}}]


def _calls_table(trees: dict, calls: dict) -> list:
    """Markdown lines: calls per node and per frame by chain, for each tree of ``calls``."""
    names = [k for k in ("before", "after", "this tree") if k in calls]
    if not names:
        return []
    head = " | ".join(f"{what} per {unit} ({k})" for what in ("python", "native")
                      for unit in ("node", "frame") for k in names)
    lines = ["", "## Calls per node and per frame, identity chains, `Graph.process` (counted)", "",
             "Trees: " + ", ".join(f"{k} = {trees[k]}" for k in names) + ".", "",
             f"| chain | {head} | native calls by name, per node / per frame ({names[-1]}) |",
             "|---|" + "---|" * (4 * len(names) + 1)]
    for chain in calls[names[-1]]:
        cells = [f"{calls[k][chain][what][i]:g}" if chain in calls[k] else "?"
                 for what in ("python", "native") for i in (0, 1) for k in names]
        by_name = calls[names[-1]][chain]["by_name"]
        named = ", ".join(f"{n} {a:g}/{b:g}" for n, (a, b) in by_name.items() if a or b)
        lines.append(f"| {chain} | " + " | ".join(cells) + f" | {named or 'none'} |")
    lines += ["", "Per node: what one more node adds (chains of n/2 and n nodes, the difference "
                  "over n/2); per frame: the rest. Python: cProfile's function calls on the "
                  "caller's thread (where a frame alone runs); native: calls into Warp's library "
                  "(CUDA events, stream waits and syncs, copies, context and stream switches), "
                  "through counting wrappers (benchmarks/native_counts.py)."]
    return lines


def _chain_label(row) -> str:
    """A chain row's name, with its GPU timing when not the executor's default."""
    return row["chain"] + (f", timing {row['timing']}" if row.get("timing") else "")


def _blur_chain(n: int, gpu: str) -> warpvx.Graph:
    g = warpvx.Graph(f"blur-chain-{n}")
    v = g.input("x", shape=(16, 16), dtype=np.uint8)
    for i in range(n):
        v = g.gaussian_blur(v, ksize=(3, 3), sigma=0.8, name=f"b{i}", target="gpu")
    g.output("y", v)
    g.verify({"x": np.zeros((16, 16), np.uint8)})
    g.schedule("baseline", n_cpus=1, gpu=gpu)
    return g


def _frame_seconds(g, x, frames: int, capture: bool, depth: int) -> tuple:
    """Median seconds per frame one at a time, and mean seconds per frame pipelined."""
    for _ in range(3):  # threads, kernels, the capture (second frame)
        g.process({"x": x}, capture=capture)
    wall = []
    for _ in range(frames):
        t0 = time.perf_counter()
        g.process({"x": x}, capture=capture)
        wall.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    for _ in g.stream(({"x": x} for _ in range(frames)), depth=depth, capture=capture):
        pass
    return statistics.median(wall), (time.perf_counter() - t0) / frames


def _primitive_chain(args) -> list:
    """Section 2: per-node cost of a GPU-only blur chain, eager and captured."""
    short, long_ = 2, args.nodes // 2
    x = (np.arange(256, dtype=np.uint32).reshape(16, 16) * 37 % 251).astype(np.uint8)
    graphs = {n: _blur_chain(n, args.gpu) for n in (short, long_)}
    rows = []
    try:
        for mode, capture in MODES.items():
            t = {n: _frame_seconds(g, x, args.frames, capture, 4) for n, g in graphs.items()}
            captures = graphs[long_].plan.executor().captures
            row = {"mode": mode, "nodes": [short, long_], "captures": captures,
                   "per_node_us": (t[long_][0] - t[short][0]) / (long_ - short) * 1e6,
                   "per_node_us_stream": (t[long_][1] - t[short][1]) / (long_ - short) * 1e6,
                   "frame_us": t[long_][0] * 1e6}
            rows.append(row)
            print(f"  blur chain {mode}: {row['per_node_us']:.1f} us/node process, "
                  f"{row['per_node_us_stream']:.1f} stream ({captures} captures)", flush=True)
    finally:
        for g in graphs.values():
            g.close()
    return rows


def _two_cameras(args) -> list:
    """Section 3: the 16-node graph pipelined, eager and captured, at each depth."""
    size = args.size
    frames = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, max_corners=200 if args.quick else 500)
    g.verify(frames[:2])
    t0 = time.perf_counter()
    g.schedule("baseline", n_cpus=args.n_cpus, gpu=args.gpu)
    print(f"  two-cameras {size[0]}x{size[1]}: scheduled in {time.perf_counter() - t0:.1f} s",
          flush=True)
    ex = g.plan.executor()
    segs = [[t.name for t in s.tasks] for s in ex._segments if s.captured]
    eager = [t.name for s in ex._segments if not s.captured for t in s.tasks]
    rows = []
    n = args.graph_frames
    try:
        same = _captured_equals_eager(g, frames)
        print(f"  captured == eager on {len(frames)} frames one at a time: {same or 'yes'}",
              flush=True)
        for depth in (3, 8):
            for mode, capture in MODES.items():
                g.reset()
                feed = (frames[i % len(frames)] for i in range(n + 2 * depth))
                stream = g.stream(feed, depth=depth, capture=capture)
                for _ in range(2 * depth):  # warm: threads, pools, the capture
                    next(stream)
                t0, c0 = time.perf_counter(), time.process_time()
                done = sum(1 for _ in stream)
                seconds = time.perf_counter() - t0
                cpu = time.process_time() - c0
                runs = list(g.plan.last_run)[-min(done, 32):]
                row = {"depth": depth, "mode": mode, "frames": done, "fps": done / seconds,
                       "frame_ms_median": statistics.median(r.makespan for r in runs),
                       "captures": ex.captures, "cpu_ms_per_frame": cpu / done * 1e3,
                       "gpu_host_ms_median": statistics.median(_gpu_host_ms(r) for r in runs)}
                rows.append(row)
                print(f"  depth {depth} {mode}: {row['fps']:.1f} FPS ({done} frames), median "
                      f"frame {row['frame_ms_median']:.2f} ms, CPU time "
                      f"{row['cpu_ms_per_frame']:.2f} ms/frame, captures so far {ex.captures}",
                      flush=True)
    finally:
        g.close()
    return [{"size": list(size), "segments": segs, "eager": eager, "rows": rows,
             "captured_equals_eager": same or "yes"}]


def _gpu_host_ms(run) -> float:
    """The GPU thread's host time in a frame (ms): its calls, or its replays (copies in,
    launch, copies out), summed (on warp-cpu these include the kernels)."""
    return _union_ms(sorted(run.host.values()))  # a replay's tasks tile its interval


def _union_ms(intervals) -> float:
    """Total length of sorted (start, end) intervals, overlaps counted once."""
    total, end = 0.0, float("-inf")
    for a, b in intervals:
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def _captured_equals_eager(g, frames) -> str:
    """"" when every output of ``frames`` run one at a time captured equals the eager run's
    (bit for bit; the graph's first frames capture its segments), else what differs."""
    g.reset()
    eager = [g.process(f, capture=False) for f in frames]
    g.reset()
    captured = [g.process(f, capture=True) for f in frames]
    differ = sorted({f"{k} (frame {i})" for i, (e, c) in enumerate(zip(eager, captured))
                     for k in e if not _same(e[k], c[k])})
    return "no: " + ", ".join(differ[:8]) if differ else ""


def _same(a, b) -> bool:
    flatten = getattr(a, "__warpvx_flatten__", None)
    if flatten is not None:
        return type(a) is type(b) and all(map(_same, flatten()[0], b.__warpvx_flatten__()[0]))
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)


def markdown(report) -> str:
    cpu_note = " (Warp CPU graphs)" if report["gpu"] == "warp-cpu" else ""
    lines = [report["command"], "",
             f"# Executor overhead and pipelined FPS, captured vs eager ({report['machine']})", "",
             f"GPU role: {report['gpu']}; {report['n_cpus']} CPU workers; Python "
             f"{report['python']}, Warp {report['warp']}; OpenCV threads 1; "
             f"{report['seconds']:.0f} s.", "",
             "## Identity chains (user nodes, not captured)", "",
             "| chain | nodes | us/node (process) | us/node (stream, 4 in flight) | "
             "breakdown, process (median us) | units short enough to run inline |",
             "|---|---|---|---|---|---|"]
    for r in report["chains"]:
        parts = ", ".join(f"{k} {v:.1f}" for k, v in r.get("breakdown", {}).items() if v is not None)
        lines.append(f"| {_chain_label(r)} | {r['n_nodes']} | {r['per_node_us']:.1f} | "
                     f"{r['per_node_us_stream']:.1f} | {parts} | {r.get('inline_units', '')} |")
    lines += ["", "Targets (issue 11): < 5 us/node on the GPU-only chain, < 20 on the alternating "
              "one. GPU timing (CUDA): by default an event per GPU task for a frame alone "
              "(process: what the cost model learns from) and per run of GPU tasks between "
              "hand-offs behind frames in flight (stream); 'timing bursts' forces the latter "
              "(Executor timing=). Breakdown (executor_overhead): mixed, one CPU -> GPU -> CPU round: the GPU "
              "call's host time (gpu_task), a CPU task with its download (cpu_task), the "
              "hand-offs; gpu: a task's host time and the gap to the next; every chain: a "
              "frame's host time before its first task (frame_head) and after its last "
              "(frame_tail: wait, outputs, result). Where the host time goes: "
              "overhead_profile_gpu.txt, overhead_profile_mixed.txt (cProfile, every thread)."]
    n0, n1 = report["primitive_chain"][0]["nodes"] if report["primitive_chain"] else ("?", "?")
    lines += ["", f"## GPU-only chain of 3x3 blurs (16x16 uint8): cost of one more node "
                  f"(chains of {n0} and {n1})", "",
              "| mode | us/node (process) | us/node (stream, 4 in flight) | frame of the long "
              "chain (us) | captures |", "|---|---|---|---|---|"]
    for r in report["primitive_chain"]:
        mode = r["mode"] + (cpu_note if r["mode"] == "captured" else "")
        lines.append(f"| {mode} | {r['per_node_us']:.1f} | {r['per_node_us_stream']:.1f} | "
                     f"{r['frame_us']:.0f} | {r['captures']} |")
    for e in report["two_cameras"]:
        w, h = e["size"]
        lines += ["", f"## Two-camera graph (16 nodes), {w}x{h}, baseline placement, pipelined", "",
                  "Captured segments: " + ("; ".join(" + ".join(s) for s in e["segments"])
                                           or "none") + ".",
                  "GPU nodes run eagerly (not capturable): " + (", ".join(e.get("eager", []))
                                                                or "none") + ".",
                  "Captured outputs equal the eager run's, bit for bit, on 16 frames one at a "
                  f"time: {e.get('captured_equals_eager', '?')}.", "",
                  "| frames in flight | mode | FPS | median frame (ms) | GPU thread host time "
                  "per frame (ms, median) | process CPU time per frame (ms, all threads) | "
                  "frames timed |",
                  "|---|---|---|---|---|---|---|"]
        for r in e["rows"]:
            mode = r["mode"] + (cpu_note if r["mode"] == "captured" else "")
            lines.append(f"| {r['depth']} | {mode} | {r['fps']:.1f} | {r['frame_ms_median']:.2f} | "
                         f"{r.get('gpu_host_ms_median', float('nan')):.3f} | "
                         f"{r.get('cpu_ms_per_frame', float('nan')):.2f} | {r['frames']} |")
        lines += ["", "GPU thread host time: its calls (eager) or its replay (copies in, launch, "
                  "copies out; captured), from the frames' host timelines. CPU time: the "
                  "process's over the timed frames (every thread, CPU nodes included). On "
                  "warp-cpu both include the kernels; on CUDA the CPU time includes any spin "
                  "in a synchronisation."]
    for e in report.get("ab", []):
        lines += ["", f"## A/B, identity chains, fresh processes alternating: before = "
                      f"{e['trees']['before']}, after = {e['trees']['after']}", "",
                  "| chain | nodes | us/node before | after | change | stream before | after | "
                  "runs before | runs after |", "|---|---|---|---|---|---|---|---|---|"]
        for r in e["rows"]:
            b, a = r["before"], r["after"]
            change = (a["per_node_us"] / b["per_node_us"] - 1) * 100 if b["per_node_us"] else 0.0
            lines.append(f"| {r['chain']} | {r['n_nodes']} | {b['per_node_us']:.1f} | "
                         f"{a['per_node_us']:.1f} | {change:+.0f}% | {b['per_node_us_stream']:.1f} | "
                         f"{a['per_node_us_stream']:.1f} | {b['all']} | {a['all']} |")
        lines += ["", f"Medians of {e['rows'][0]['pairs'] if e['rows'] else 0} runs per tree, each "
                      "a fresh process timing both trees with the same code: process (one frame "
                      "at a time, no result kept: as a caller) and stream (4 in flight) us/node, "
                      "the nodes' own time taken off."]
    for e in report.get("calls", []) + report.get("ab", []):
        lines += _calls_table(e["trees"], e.get("calls", {}))
    for key, err in report["errors"].items():
        lines += ["", f"**{key} failed**: {err}"]
    return "\n".join(lines) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--gpu", default=None, help="cuda, cuda:N or warp-cpu (default: cuda if present)")
    p.add_argument("--out", type=Path, default=None,
                   help="results folder (default ./warpvx-results/overhead-<time>)")
    p.add_argument("--quick", action="store_true", help="few frames, 160x120 camera frames")
    p.add_argument("--size", default=None, help="camera size WxH (default 1280x720; quick 160x120)")
    p.add_argument("--nodes", type=int, default=None, help="chain length (default 64; quick 16)")
    p.add_argument("--frames", type=int, default=None, help="frames per chain (default 200; quick 20)")
    p.add_argument("--graph-frames", type=int, default=None,
                   help="timed frames per two-camera row (default 300; quick 16)")
    p.add_argument("--n-cpus", type=int, default=None, help="CPU workers (default: cores - 1, max 4)")
    p.add_argument("--ab", default=None,
                   help="another warpvx tree (a folder, or a git revision of this checkout): "
                        "its identity chains and this tree's, alternating in fresh processes")
    p.add_argument("--ab-pairs", type=int, default=5, help="A/B runs per tree (default 5)")
    args = p.parse_args(argv)
    command = "PYTHONPATH=. python3 benchmarks/overhead_bench.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    init_warp()
    args.gpu = args.gpu or ("cuda" if warpvx.cuda_available() else "warp-cpu")
    args.size = tuple(int(v) for v in (args.size or ("160x120" if args.quick else "1280x720")).split("x"))
    args.nodes = args.nodes or (16 if args.quick else 64)
    args.frames = args.frames or (20 if args.quick else 200)
    args.graph_frames = args.graph_frames or (16 if args.quick else 300)
    if args.n_cpus is None:
        args.n_cpus = warpvx.graph.default_n_cpus()
    out_dir = args.out or Path("warpvx-results") / time.strftime("overhead-%Y%m%d-%H%M%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    args.out = out_dir
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)  # one core per CPU worker, as the graph benchmark
    t_start = time.perf_counter()
    sections, errors = {}, {}
    try:
        for key, title, run in (("chains", "identity chains", _chains),
                                ("calls", "calls per node and per frame (counted)", _calls),
                                ("primitive_chain", "primitive chain", _primitive_chain),
                                ("two_cameras", "two-camera graph", _two_cameras),
                                ("ab", "A/B of the identity chains", _ab)):
            if (key == "ab" and not args.ab) or (key == "calls" and args.ab):
                continue  # (with --ab, the A/B counts both trees)
            print(title, flush=True)
            try:
                sections[key] = run(args)
            except Exception as exc:  # noqa: BLE001 - the other sections still run and report
                errors[key] = f"{type(exc).__name__}: {exc}"
                sections[key] = []
                traceback.print_exc()
    finally:
        cv2.setNumThreads(threads)
    wp = init_warp()
    report = {"command": command, "machine": f"{platform.node()}|{graph_bench._gpu_name(args.gpu)}",
              "platform": platform.platform(), "python": sys.version.split()[0],
              "warp": wp.config.version, "gpu": args.gpu, "n_cpus": args.n_cpus, **sections,
              "errors": errors, "seconds": time.perf_counter() - t_start}
    (out_dir / "overhead_bench.json").write_text(json.dumps(report, indent=1, default=str))
    (out_dir / "overhead_bench.md").write_text(markdown(report))
    print(f"wrote {out_dir / 'overhead_bench.md'} in {report['seconds']:.1f} s", flush=True)
    return report


if __name__ == "__main__":
    main()
