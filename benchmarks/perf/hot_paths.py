"""The two hot paths of the GPU machine, alone, for a profiler or an A/B of one setting.

    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb [--switch-interval S] [--rounds N] [--chain-in-process]
    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py cap [--switch-interval S] [--rounds N]
    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb-ab [--pairs 3] [--out DIR]   # < 4 min on the H100

``orb``: the ORB-SLAM front end, batched, monocular, default settings (what
``benchmarks/orbslam_bench.py`` times as ``batched_mono``: 600 rendered 1241x376 frames, B=16,
its chain process and pose pool; ``--chain-in-process``: the chain in this process, with the
pose pool alone). ``orb-ab``: the chain in this process against the chain in its own process,
interleaved, a fresh ``orb`` process per run (the frames rendered once, before), ``--pairs``
pairs; prints a markdown table with the medians and the command at its top and writes it to
``DIR/chain-process-ab.md`` (default ``$OUT``, else the current folder). ``cap``: the two-camera graph (16 nodes, 1280x720, baseline placement) as a
captured stream, depth 3, after a reset (``benchmarks/perf/capture_stream.py``). Prints FPS per
round. Under py-spy (staged beside Warp by ``warp-pack ... py-spy``)::

    py-spy record -r 200 --threads --gil -f raw -o orb_gil.txt -- python3 benchmarks/perf/hot_paths.py orb

and ``benchmarks/perf/pyspy_summary.py orb_gil.txt`` for a per-thread summary (``orb`` runs the
chain in a process of its own: add ``--subprocesses`` to sample it, or profile
``--chain-in-process``).
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "benchmarks" / "perf"))


def _rendered(cache):
    """The bench's 60 rendered 1241x376 frames and K: from ``cache`` (an .npz) when it exists,
    else rendered (and saved there when given)."""
    import numpy as np

    if cache is not None and os.path.exists(cache):
        with np.load(cache) as z:
            return list(z["left"]), z["K"]
    import orbslam_bench as bench

    left, _right, K, _gt = bench.render_sequence(60, (1241, 376), baseline=0.54, step=0.25, supersample=1)
    if cache is not None:
        np.savez(cache, left=np.stack(left), K=K)
    return left, K


def orb(rounds: int, switch, frames: int = 600, chain_process: bool = True, cache=None, backend="cuda",
        batch: int = 16):
    import orbslam_bench as bench

    from warpvx.apps import orbslam as o
    from warpvx.apps import orbslam_batch as ob

    left, K = _rendered(cache)
    camera = o.Camera(K, (1241, 376))
    feed = bench.replay([{"image": im} for im in left], frames)
    with ob.make_pool(None, chain_process=chain_process) as pool, tempfile.TemporaryDirectory() as out:
        for r in range(rounds):
            row, _ = bench.bench_frontend_batched(feed, camera, backend, Path(out), None, batch, pool,
                                                  switch=ob.SWITCH_INTERVAL if switch is None else switch)
            print(f"orb round {r}: {row['fps']:.1f} FPS", flush=True)


#: orb-ab's experiments: name -> (title, its two arms: label, extra arguments of ``orb``).
EXPERIMENTS = {
    "chain": ("the chain in this process vs in its own process",
              (("chain in this process (before)", ["--chain-in-process"]),
               ("chain in its own process (default)", []))),
    "batch": ("16 frames per batch (default) vs 32",
              (("B=16 (default)", []), ("B=32", ["--batch", "32"]))),
}


def orb_ab(pairs: int, out: str, frames: int = 600, backend="cuda", experiment: str = "chain"):
    """An interleaved A/B of the batched front end (``EXPERIMENTS[experiment]``, see the
    module's docstring), written to ``out/<experiment>-ab.md``; returns the markdown lines."""
    title, arms = EXPERIMENTS[experiment]
    command = (f"PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb-ab --pairs {pairs}"
               + (f" --experiment {experiment}" if experiment != "chain" else "")
               + (f" --frames {frames}" if frames != 600 else "") + (f" --backend {backend}" if backend != "cuda" else ""))
    fps = {label: [] for label, _ in arms}
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "frames.npz")
        t = time.perf_counter()
        _rendered(cache)
        print(f"rendered in {time.perf_counter() - t:.1f} s", flush=True)
        for pair in range(1, pairs + 1):
            for label, extra in arms:
                run = subprocess.run([sys.executable, __file__, "orb", "--rounds", "1", "--frames-cache", cache,
                                      "--frames", str(frames), "--backend", backend, *extra], capture_output=True, text=True, timeout=240)
                found = re.search(r"orb round 0: ([0-9.]+) FPS", run.stdout)
                if found is None:
                    raise RuntimeError(f"{label}: no FPS (exit {run.returncode}):\n{run.stdout}\n{run.stderr}")
                fps[label].append(float(found.group(1)))
                print(f"pair {pair}, {label}: {fps[label][-1]:.1f} FPS", flush=True)
    (a, fa), (b, fb) = fps.items()
    ma, mb = statistics.median(fa), statistics.median(fb)
    lines = [f"Regenerate (H100, one call): `{command}`",
             f"(A fresh process per run on {backend}: pose pool (and chain process) start, warm-up, then {frames} "
             "frames timed; the "
             "frames rendered once, before.)", "",
             f"# ORB-SLAM batched front end (mono, default settings, 1241x376): {title}, interleaved", "",
             f"| pair | {a} FPS | {b} FPS |", "|---:|---:|---:|"]
    lines += [f"| {i} | {x:.1f} | {y:.1f} |" for i, (x, y) in enumerate(zip(fa, fb), 1)]
    lines += [f"| median | {ma:.1f} | {mb:.1f} ({100 * (mb / ma - 1):+.1f}%) |", "",
              f"{b} ahead in {sum(y > x for x, y in zip(fa, fb))} of {pairs} pairs."]
    os.makedirs(out, exist_ok=True)
    Path(out, "chain-process-ab.md" if experiment == "chain" else f"{experiment}-ab.md").write_text(
        "\n".join(lines) + "\n")
    print("\n".join(lines), flush=True)
    return lines


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
    p.add_argument("path", choices=("orb", "cap", "orb-ab"))
    p.add_argument("--switch-interval", type=float, default=None,
                   help="GIL switch interval for the run, seconds (default: Python's, 0.005; orb: "
                        "the batched front end's own, orbslam_batch.SWITCH_INTERVAL)")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--chain-in-process", action="store_true", help="orb: the chain in this process (the path before)")
    p.add_argument("--frames-cache", default=None, help="orb: the rendered frames' .npz (made when missing)")
    p.add_argument("--frames", type=int, default=600, help="orb, orb-ab: frames timed")
    p.add_argument("--backend", default="cuda", help="orb, orb-ab: the batched front end's backend")
    p.add_argument("--pairs", type=int, default=3, help="orb-ab: pairs of runs")
    p.add_argument("--experiment", default="chain", choices=sorted(EXPERIMENTS), help="orb-ab: which A/B")
    p.add_argument("--batch", type=int, default=16, help="orb: frames per batch")
    p.add_argument("--out", default=os.environ.get("OUT") or ".", help="orb-ab: output folder (default $OUT)")
    args = p.parse_args(argv)
    if args.path == "orb-ab":
        orb_ab(args.pairs, args.out, args.frames, args.backend, args.experiment)
        return
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    print(f"GIL switch interval {sys.getswitchinterval() * 1e3:g} ms, pid {os.getpid()}", flush=True)
    if args.path == "orb":
        orb(args.rounds, args.switch_interval, args.frames, not args.chain_in_process, args.frames_cache, args.backend,
            args.batch)
    else:
        cap(args.rounds, args.switch_interval)


if __name__ == "__main__":
    main()
