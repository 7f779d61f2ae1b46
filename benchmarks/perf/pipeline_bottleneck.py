"""Which resource bounds the pipelined two-camera stream? Its frame rate with parts of the
work taken away, in interleaved rounds: if taking a part away does not raise the rate, that
part was not the bound.

    PYTHONPATH=. python3 benchmarks/perf/pipeline_bottleneck.py --out $OUT/pb

Variants of ``graph_bench.build_graph`` (baseline placement; pinned frames, depth 3,
captured, 3 linked buffer sets, as ``pipeline_threads.py``):

- ``as-is``: the graph;
- ``no-ransac``: the homographies (the CPU worker's work) reduced to their input conversion,
  no ``cv2.findHomography`` (identity);
- ``no-detector``: without ``detectorL`` (8 smoothing passes on the device, ~0.16 ms of the
  device's frame at 1280x720, and its 3.7 MB score map downloaded every frame);
- ``neither``: both taken away;
- ``ransac-in-process``: nothing taken away, the homographies run in a worker process
  (``Graph.user(..., process=True)``: off this process's GIL, a pickled round trip a call).

Writes ``pipeline_bottleneck.md`` (the command on top): FPS per variant and round, with each
thread's CPU ms per frame.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))

import graph_bench  # noqa: E402
import pipeline_threads  # noqa: E402
from perf_common import add_cv_threads, frame_size, opencv_threads, positive  # noqa: E402

from warpvx.runtime import pinned_copy  # noqa: E402


def homography_without_ransac(prev_pts, next_pts, status):
    """:func:`graph_bench.homography`'s input conversion, then the identity (no RANSAC)."""
    ok = np.asarray(status).reshape(-1) == 1
    np.asarray(prev_pts, np.float32).reshape(-1, 2)[ok]
    np.asarray(next_pts, np.float32).reshape(-1, 2)[ok]
    return np.eye(3)


#: variant -> build_graph's keyword arguments.
VARIANTS = {
    "as-is": {},
    "no-ransac": {"homography_fn": homography_without_ransac},
    "no-detector": {"detector": False},
    "neither": {"homography_fn": homography_without_ransac, "detector": False},
    "ransac-in-process": {"homography_process": True},
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for pipeline_bottleneck.md")
    ap.add_argument("--frames", type=positive, default=1200, help="timed frames per run")
    ap.add_argument("--rounds", type=positive, default=3)
    ap.add_argument("--size", type=frame_size, default=(1280, 720), help="WxH")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    add_cv_threads(ap)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    with opencv_threads(args.cv_threads):
        _run(args, argv)


def _run(args, argv):
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    frames = graph_bench.make_frames(args.size, 16)
    if args.gpu.startswith("cuda"):
        frames = [{k: pinned_copy(v) for k, v in f.items()} for f in frames]
    graphs = {}
    fps = {name: [] for name in VARIANTS}
    lines = [f"<!-- PYTHONPATH=. python3 benchmarks/perf/pipeline_bottleneck.py {' '.join(argv)} -->",
             f"# Two-camera graph {args.size[0]}x{args.size[1]} pipelined, parts taken away "
             "(baseline placement, pinned frames on CUDA, depth 3, captured, 3 linked sets)", "",
             f"OpenCV threads: {cv2.getNumThreads()}.", "",
             "| round | variant | FPS | frame period ms (median) | thread CPU ms / frame |",
             "|---:|---|---:|---:|---|"]
    try:
        for name, kwargs in VARIANTS.items():
            g = graph_bench.build_graph(args.size, max_corners=500, **kwargs)
            graphs[name] = g
            g.verify(frames[:2])
            g.schedule("baseline", n_cpus=4, gpu=args.gpu)
        for r in range(args.rounds):
            for name, g in graphs.items():
                res = pipeline_threads.stream_round(g, g.plan, frames, args.frames)
                fps[name].append(res["fps"])
                threads = ", ".join(f"{n} {ms:.3f}" for ms, n in res["threads"] if ms > 0.01)
                row = f"| {r} | {name} | {res['fps']:.1f} | {res['period_ms']:.3f} | {threads} |"
                lines.append(row)
                print(row, flush=True)
    finally:
        for g in graphs.values():
            g.close()
    base = statistics.median(fps["as-is"])
    lines += ["", "Medians over the rounds: " + "; ".join(
        f"{name} {statistics.median(v):.1f} FPS ({statistics.median(v) / base - 1:+.0%})"
        for name, v in fps.items()) + "."]
    (out / "pipeline_bottleneck.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {out / 'pipeline_bottleneck.md'}")


if __name__ == "__main__":
    main()
