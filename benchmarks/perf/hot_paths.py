"""The two hot paths of the GPU machine, alone, for a profiler or a GIL switch-interval A/B.

    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb [--switch-interval S] [--rounds N]
    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py cap [--switch-interval S] [--rounds N]

``orb``: the ORB-SLAM front end, batched, monocular, default settings (what
``benchmarks/orbslam_bench.py`` times as ``batched_mono``: 600 rendered 1241x376 frames, B=16,
its pose pool). ``cap``: the two-camera graph (16 nodes, 1280x720, baseline placement) as a
captured stream, depth 3, after a reset (``benchmarks/perf/capture_stream.py``). Prints FPS per
round. Under py-spy (staged beside Warp by ``warp-pack ... py-spy``)::

    py-spy record -r 200 --threads --gil -f raw -o orb_gil.txt -- python3 benchmarks/perf/hot_paths.py orb

and ``benchmarks/perf/pyspy_summary.py orb_gil.txt`` for a per-thread summary.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))


def orb(rounds: int, switch, frames: int = 600):
    import orbslam_bench as bench

    from warpvx.apps import orbslam as o
    from warpvx.apps import orbslam_batch as ob

    size = (1241, 376)
    left, _right, K, _gt = bench.render_sequence(60, size, baseline=0.54, step=0.25, supersample=1)
    camera = o.Camera(K, size)
    feed = bench.replay([{"image": im} for im in left], frames)
    with ob.make_pool(None) as pool, tempfile.TemporaryDirectory() as out:
        for r in range(rounds):
            row, _ = bench.bench_frontend_batched(feed, camera, "cuda", Path(out), None, 16, pool,
                                                  switch=ob.SWITCH_INTERVAL if switch is None else switch)
            print(f"orb round {r}: {row['fps']:.1f} FPS", flush=True)


def cap(rounds: int, switch=None, frames: int = 1500):
    import capture_stream
    import graph_bench

    size = (1280, 720)
    images = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, max_corners=500)
    g.verify(images[:2])
    g.schedule("baseline", n_cpus=4, gpu="cuda")
    try:
        for r in range(rounds):
            fps, replays = capture_stream.stream_fps(g, images, True, 3, frames)[:2]
            print(f"cap round {r}: {fps:.1f} FPS ({replays} captured graphs launched)", flush=True)
    finally:
        g.close()


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("path", choices=("orb", "cap"))
    p.add_argument("--switch-interval", type=float, default=None,
                   help="GIL switch interval for the run, seconds (default: Python's, 0.005; orb: "
                        "the batched front end's own, orbslam_batch.SWITCH_INTERVAL)")
    p.add_argument("--rounds", type=int, default=2)
    args = p.parse_args(argv)
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    print(f"GIL switch interval {sys.getswitchinterval() * 1e3:g} ms, pid {os.getpid()}", flush=True)
    {"orb": orb, "cap": cap}[args.path](args.rounds, args.switch_interval)


if __name__ == "__main__":
    main()
