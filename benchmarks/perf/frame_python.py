"""Per-thread Python time per frame of the two-camera graph's pipelined, captured stream, with
the device work left out: what bounds the stream on the GPU machine (issue 11: host-bound,
three threads under one GIL), measured without a GPU.

    PYTHONPATH=. python3 benchmarks/perf/frame_python.py --out DIR [--before REV|TREE] [--reps 3]

The graph of ``benchmarks/graph_bench.py`` (``build_graph``: 16 nodes, two cameras) at
``--size`` (320x240), baseline placement on 4 CPU workers and Warp's CPU device as the GPU role,
``capture=True`` (its GPU segment captured and replayed, as on CUDA) and
``Executor.STAGE_ON_HOST`` (the staged downloads' code, without a DMA), pipelined ``depth``
3 after a reset and a warm-up; ``--frames`` frames profiled with yappi (CPU clock, per thread).

How the device work is left out: on Warp's CPU device the replay (``capture_launch``) runs the
kernels on the calling thread, and the copies are memcpy. A thread's *Python time* is the self
time of the functions defined in Python source (the interpreter running our code), less
``capture_launch``'s (the kernels); the time in C functions (NumPy, OpenCV, locks, builtins) is
reported apart as *native*. Native calls made through ctypes (Warp's memcpy, event calls) are
not seen by the profiler: they count in their Python caller (memcpy of a few KB: small at this
size). yappi's per-call instrumentation inflates Python time (about 2x): compare trees in one
run, not with host times measured unprofiled on the GPU machine. Thread CPU times vary by 10-20%
between runs on a shared machine; the Python function calls per frame (the profiler's count,
device work excluded) do not, and go with the time. The caller's blocked wait for a frame
polls every 20 ms (``Executor.wait``: ``Flag.wait``, ``Thread.is_alive``): on Warp's CPU device,
where a frame's kernels take ~0.2 s, that polling is part of its Python time; on the GPU machine
a frame takes a few ms. The garbage collector's time (every thread's, ``gc.callbacks``) is
reported apart; it counts in the Python time of whatever function allocated.

Each repetition runs in a fresh process per tree (``--before``: a git revision, exported, or
another checkout's folder; this tree is "after"), the trees alternating; the table
gives medians over ``--reps``. Writes ``DIR/frame_python.md`` (the command on top) and
``DIR/frame_python.json`` (the command, then every repetition with each thread's top
functions).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[2]

#: The functions whose self time is the device's work on Warp's CPU device (the kernels).
DEVICE_WORK = ("capture_launch",)
#: Top functions kept per thread (by self time).
TOP = 15


def _role(name: str) -> str:
    """The executor's thread names end with their processor; the caller is MainThread."""
    if name == "MainThread":
        return "caller"
    return name.rsplit("-", 1)[-1]


def one(tree: Path, size, frames: int, depth: int, warm: int) -> dict:
    """One repetition in this process of ``tree``'s graph benchmark and package (its
    ``graph_bench`` puts its own tree first on ``sys.path``): per-thread times per frame."""
    sys.path.insert(0, str(tree / "benchmarks"))
    import cv2
    import yappi

    import graph_bench
    import warpvx
    from warpvx.runtime import Executor

    if Path(warpvx.__file__).resolve().parents[1] != tree.resolve():
        raise RuntimeError(f"warpvx of {warpvx.__file__}, not of {tree}")

    cv2.setNumThreads(1)  # as the graph benchmark: one core per worker
    Executor.STAGE_ON_HOST = True
    images = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(images[:2])
    g.schedule("baseline", n_cpus=4, gpu="warp-cpu")
    ex = g.plan.executor()
    g.reset()
    feed = (images[i % len(images)] for i in range(warm + frames))
    stream = g.stream(feed, depth=depth, capture=True)
    for _ in range(warm):
        next(stream)
    replays, fresh = ex.replays, ex.fresh_buffers
    collected = {"s": 0.0, "n": [0, 0, 0]}  # the garbage collector's time, every thread's

    def timed(phase, info, started=[0.0]):  # noqa: B006 - the start of the running collection
        if phase == "start":
            started[0] = time.perf_counter()
        else:
            collected["s"] += time.perf_counter() - started[0]
            collected["n"][info["generation"]] += 1

    gc.callbacks.append(timed)
    yappi.clear_stats()
    yappi.set_clock_type("cpu")
    yappi.start(builtins=True, profile_threads=True)
    t0 = time.perf_counter()
    done = sum(1 for _ in stream)
    wall = time.perf_counter() - t0
    yappi.stop()
    gc.callbacks.remove(timed)
    names = {t.ident: t.name for t in threading.enumerate()}
    threads = {}
    for th in yappi.get_thread_stats():
        stats = list(yappi.get_func_stats(filter={"ctx_id": th.id}))
        py = [f for f in stats if f.module.endswith(".py")]
        device = sum(f.tsub for f in py if f.name in DEVICE_WORK)
        python = sum(f.tsub for f in py) - device
        native = sum(f.tsub for f in stats if not f.module.endswith(".py"))
        if python <= 0:
            continue
        top = sorted((f for f in py if f.name not in DEVICE_WORK), key=lambda f: -f.tsub)[:TOP]
        role = _role(names.get(th.tid, f"{th.name}-{th.id}"))
        threads[role] = {
            "python_us": python / done * 1e6, "native_us": native / done * 1e6,
            "calls": sum(f.ncall for f in py) / done,
            "device_us": device / done * 1e6, "cpu_us": th.ttot / done * 1e6,
            "top": [(f"{f.name} ({Path(f.module).name}:{f.lineno})", f.tsub / done * 1e6,
                     f.ncall / done) for f in top]}
    g.close()
    return {"tree": str(tree), "frames": done, "wall_s": wall, "replays": ex.replays - replays,
            "gc_us": collected["s"] / done * 1e6, "collections": collected["n"],
            "fresh_buffers": ex.fresh_buffers - fresh, "threads": threads}


def _tree(before: str) -> Path:
    """``before``: a folder holding another tree, else a git revision of this repository,
    exported into a temporary folder (removed at exit)."""
    path = Path(before)
    if path.is_dir():
        return path.resolve()
    import atexit
    import shutil
    import tempfile

    out = Path(tempfile.mkdtemp(prefix="frame_python_"))
    atexit.register(shutil.rmtree, out, ignore_errors=True)
    archive = subprocess.run(["git", "archive", before], cwd=ROOT, check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(out)], input=archive, check=True)
    return out


def _child(tree: Path, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    cmd = [sys.executable, str(HERE), "--one", str(tree), "--size", args.size,
           "--frames", str(args.frames),
           "--depth", str(args.depth), "--warm", str(args.warm)]
    out = subprocess.run(cmd, env=env, cwd=str(tree), check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _table(runs: dict) -> list:
    """Medians per tree and thread: Python, native and device us per frame."""
    roles = sorted({r for reps in runs.values() for rep in reps for r in rep["threads"]},
                   key=lambda r: (r != "caller", r != "gpu", r))
    lines = ["| tree | thread | Python us / frame | Python calls / frame | native us / frame | "
             "device (kernels) us / frame | reps |", "|---|---|---:|---:|---:|---:|---:|"]
    for tree, reps in runs.items():
        for role in roles:
            got = [rep["threads"][role] for rep in reps if role in rep["threads"]]
            if not got:
                continue
            med = {k: statistics.median(t[k] for t in got)
                   for k in ("python_us", "calls", "native_us", "device_us")}
            spread = ", ".join(f"{t['python_us']:.0f}" for t in got)
            lines.append(f"| {tree} | {role} | {med['python_us']:.0f} ({spread}) | "
                         f"{med['calls']:.0f} | {med['native_us']:.0f} | "
                         f"{med['device_us']:.0f} | {len(got)} |")
    lines.append("")
    lines.append("| tree | replays / frame | fresh device buffers (timed frames) | garbage "
                 "collection us / frame (collections of generation 0, 1, 2) |")
    lines.append("|---|---:|---:|---|")
    for tree, reps in runs.items():
        lines.append(f"| {tree} | " + ", ".join(f"{r['replays'] / r['frames']:.2f}" for r in reps)
                     + " | " + ", ".join(str(r["fresh_buffers"]) for r in reps) + " | "
                     + ", ".join(f"{r['gc_us']:.0f} ({'/'.join(map(str, r['collections']))})"
                                 for r in reps) + " |")
    return lines


def _tops(runs: dict) -> list:
    """Each tree's top Python functions per thread (self us per frame, calls per frame), from
    its median repetition by the GPU thread's Python time."""
    lines = []
    for tree, reps in runs.items():
        rep = sorted(reps, key=lambda r: r["threads"].get("gpu", {}).get("python_us", 0))[
            len(reps) // 2]
        for role, t in rep["threads"].items():
            lines += ["", f"{tree}, {role}: top Python functions (self us / frame, calls / frame)",
                      "", "| function | self us | calls |", "|---|---:|---:|"]
            lines += [f"| {name} | {us:.1f} | {calls:.1f} |" for name, us, calls in t["top"]]
    return lines


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", help="a folder for frame_python.md and .json")
    ap.add_argument("--before", help="another tree to compare with: its folder (repo root) or "
                    "a git revision of this repository")
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--frames", type=int, default=60, help="profiled frames per repetition")
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--warm", type=int, default=20, help="frames before profiling (captures)")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--one", metavar="TREE", help="one repetition here of TREE, a JSON line")
    args = ap.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    if args.one:
        print(json.dumps(one(Path(args.one), size, args.frames, args.depth, args.warm)))
        return
    trees = {"after": ROOT}
    if args.before:
        trees = {"before": _tree(args.before), **trees}
    runs = {t: [] for t in trees}
    for rep in range(args.reps):
        for tree, path in trees.items():  # alternating: drifts of the machine hit both
            runs[tree].append(_child(path, args))
            print(f"rep {rep} {tree}: " + ", ".join(
                f"{r} {t['python_us']:.0f} us" for r, t in runs[tree][-1]["threads"].items()),
                flush=True)
    cmd = " ".join(["PYTHONPATH=. python3 benchmarks/perf/frame_python.py", *(sys.argv[1:] if argv is None else argv)])
    lines = [f"<!-- {cmd} -->",
             f"# Python time per frame and thread: two-camera graph {args.size}, warp-cpu, "
             f"captured, staged on host, pipelined depth {args.depth}, {args.frames} frames per "
             f"rep (yappi CPU clock; medians, each rep in parentheses)", "",
             "Python: self time of functions in Python source, less the replay's kernels "
             "(`capture_launch`); native: C functions (NumPy, OpenCV, locks). See the script's "
             "docstring.", "", *_table(runs), *_tops(runs)]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "frame_python.md").write_text(text)
        (out / "frame_python.json").write_text(json.dumps({"command": cmd, "runs": runs},
                                                          indent=1))


if __name__ == "__main__":
    main()
