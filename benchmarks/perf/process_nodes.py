"""CPU nodes in worker processes (``Graph.user(..., process=True)``) against the same nodes
in this process, where the GIL is contended: runs on the CPU alone, any machine.

    PYTHONPATH=. python3 benchmarks/perf/process_nodes.py --out $OUT/pn

Two graphs, each streamed ``--depth`` frames in flight with its nodes on two CPU workers, the
process and thread placements in interleaved rounds:

- ``python``: two nodes of pure Python (``--python-ms`` of a loop each, holding the GIL), one
  per worker. In this process the two serialise on the GIL; in worker processes they run
  side by side.
- ``ransac``: a RANSAC homography (``cv2.findHomography`` on 500 point pairs, a quarter
  outliers: a native call that lets the GIL go, beside a little NumPy) beside one such Python
  node; only the RANSAC node moves to a worker process. Its thread still takes the GIL back
  to receive the result, behind the Python node's thread: expect no gain.

Writes ``process_nodes.md`` (the command on top): frames per second and the moved node's time
per frame (its interval on its worker: the round trip for a process node).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))

import warpvx  # noqa: E402
from perf_common import baseline_moving, opencv_threads, positive, positive_float  # noqa: E402

#: Loop iterations of :func:`python_work` per millisecond, measured once by :func:`_calibrate`.
_ITERS_PER_MS = None


def ransac(pts0, pts1):
    """A RANSAC homography from point pairs (N, 2) float32 (OpenCV; identity when it fails)."""
    H, _ = cv2.findHomography(pts0, pts1, cv2.RANSAC, 3.0)
    return np.eye(3) if H is None else H


def python_work(pts0, iters):
    """Pure Python for ``iters`` loop steps (holds the GIL), returning a checksum."""
    s = 0
    for i in range(int(iters[0])):
        s += i * i
    return np.array([s % 1000003 + float(pts0[0, 0])])


def _calibrate() -> float:
    n = 200_000
    t0 = time.perf_counter()
    python_work(np.zeros((1, 2), np.float32), np.array([n]))
    return n / ((time.perf_counter() - t0) * 1e3)


def point_pairs(n_frames: int, n: int = 500, seed: int = 0) -> list:
    """Per frame, ``n`` point pairs of a known homography (a slow pan and zoom), 1 px noise and
    a quarter outliers."""
    rng = np.random.default_rng(seed)
    out = []
    for f in range(n_frames):
        p0 = rng.uniform(0, 640, (n, 2)).astype(np.float32)
        H = np.array([[1.0 + 0.001 * f, 0.01, 3.0 + f], [-0.01, 1.0, 2.0], [1e-5, 0.0, 1.0]])
        q = np.c_[p0, np.ones(n)] @ H.T
        p1 = (q[:, :2] / q[:, 2:]).astype(np.float32) + rng.normal(0, 1, (n, 2)).astype(np.float32)
        bad = rng.random(n) < 0.25
        p1[bad] = rng.uniform(0, 640, (int(bad.sum()), 2)).astype(np.float32)
        out.append((p0, p1))
    return out


def build_graph(kind: str, process: bool) -> warpvx.Graph:
    """``kind`` "python" (two Python nodes, both moved) or "ransac" (RANSAC beside a Python
    node, the RANSAC moved); ``process``: the moved nodes in worker processes."""
    g = warpvx.Graph(f"process-nodes-{kind}-{'process' if process else 'thread'}")
    p0 = g.input("pts0", shape=(500, 2), dtype=np.float32)
    p1 = g.input("pts1", shape=(500, 2), dtype=np.float32)
    iters = g.input("iters", shape=(1,), dtype=np.int64)
    if kind == "ransac":
        g.output("H", g.user(ransac, [p0, p1], "H", name="moved", process=process))
    else:
        g.output("work2", g.user(python_work, [p1, iters], "work", name="moved",
                                 process=process))
    g.output("work", g.user(python_work, [p0, iters], "work", name="python",
                            process=process and kind == "python"))
    return g


def side_by_side(dag):
    """The baseline placement (every node on cpu0) with the moved node on cpu1."""
    return baseline_moving(dag, "moved", "cpu1", "side-by-side")


def stream_round(g, feeds, depth: int) -> tuple:
    """(frames per second, the moved node's median ms per frame) of one streamed round."""
    t0 = time.perf_counter()
    n = sum(1 for _ in g.stream(feeds, depth=depth))
    fps = n / (time.perf_counter() - t0)
    runs = list(g.plan.last_run)[-min(len(feeds), 48):]
    return fps, statistics.median(r.compute_ms("moved") for r in runs)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for process_nodes.md")
    ap.add_argument("--frames", type=positive, default=200, help="frames per round")
    ap.add_argument("--rounds", type=positive, default=3)
    ap.add_argument("--depth", type=positive, default=3, help="frames in flight")
    ap.add_argument("--python-ms", type=positive_float, default=2.0,
                    help="the Python node's time per frame (ms)")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    with opencv_threads(1):
        _run(args, argv)


def _run(args, argv):
    global _ITERS_PER_MS
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if _ITERS_PER_MS is None:
        _ITERS_PER_MS = _calibrate()
    iters = np.array([int(args.python_ms * _ITERS_PER_MS)], np.int64)
    pairs = point_pairs(args.frames)
    feeds = [{"pts0": a, "pts1": b, "iters": iters} for a, b in pairs]
    alone = statistics.median(_timed(ransac, *pairs[i % len(pairs)]) for i in range(50))
    placements = [(kind, process) for kind in ("python", "ransac") for process in (False, True)]
    graphs = {}
    rows = {p: [] for p in placements}
    lines = [f"<!-- PYTHONPATH=. python3 benchmarks/perf/process_nodes.py {' '.join(argv)} -->",
             "# CPU nodes in this process or in worker processes, pipelined, GIL contended", "",
             f"Depth {args.depth}; each Python node {args.python_ms} ms a frame; OpenCV on one "
             f"thread; RANSAC alone (called directly): {alone:.3f} ms.", "",
             "| round | graph | moved node(s) | FPS | moved node ms / frame (median) |",
             "|---:|---|---|---:|---:|"]
    same = {}
    try:
        for kind, process in placements:
            g = graphs[kind, process] = build_graph(kind, process)
            g.verify(feeds[0])
            g.schedule(side_by_side, n_cpus=2, gpu=False)
            stream_round(g, feeds[:10], args.depth)  # warm: the workers' processes start
        for r in range(args.rounds):
            for (kind, process), g in graphs.items():
                fps, ms = stream_round(g, feeds, args.depth)
                rows[kind, process].append(fps)
                where = "in worker processes" if process else "in this process"
                lines.append(f"| {r} | {kind} | {where} | {fps:.1f} | {ms:.3f} |")
                print(lines[-1], flush=True)
        for kind in ("python", "ransac"):
            a, b = (graphs[kind, p].process(feeds[1]) for p in (False, True))
            same[kind] = all(np.array_equal(a[k], b[k]) for k in a)
    finally:
        for g in graphs.values():
            g.close()
    lines.append("")
    for kind in ("python", "ransac"):
        t, p = (statistics.median(rows[kind, q]) for q in (False, True))
        lines.append(f"{kind}: medians {t:.1f} FPS in this process, {p:.1f} in worker processes "
                     f"(x{p / t:.2f}); outputs equal bit for bit: {'yes' if same[kind] else 'NO'}.")
    (out / "process_nodes.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'process_nodes.md'}")


def _timed(fn, *args) -> float:
    t0 = time.perf_counter()
    fn(*args)
    return (time.perf_counter() - t0) * 1e3


if __name__ == "__main__":
    main()
