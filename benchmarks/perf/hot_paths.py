"""The two hot paths of the GPU machine, alone, for a profiler or an A/B of one setting.

    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb [--switch-interval S] [--rounds N] [--chain-in-process]
    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py cap [--switch-interval S] [--rounds N]
    PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb-ab [--pairs 3] [--experiment E[,E...]] [--out DIR]

``orb``: the ORB-SLAM front end, batched, monocular, default settings (what
``benchmarks/orbslam_bench.py`` times as ``batched_mono``: 600 rendered 1241x376 frames, B=16,
its chain process and pose pool; ``--chain-in-process``: the chain in this process, with the
pose pool alone; ``--workers``, ``--nice``: the pose pool's processes and their niceness).
``orb-ab``: an interleaved A/B of one setting (:data:`EXPERIMENTS`: ``chain``, the chain in
this process vs in its own; ``batch``, B=16 vs 32; ``nice``, the pose processes at niceness 0,
5, 10; ``workers``, the default pool vs 3 and 5 processes fewer; ``direct``, the pool's jobs
written by the dispatching thread vs through multiprocessing's task thread; ``look_ahead``,
the chain's core look-ahead from the pose processes vs 6 frames and 16), ``--pairs``
rounds, each a fresh process (``orb-round``) running every arm once (a pool of its own each,
a warm-up run, then the timed one), the frames rendered once, before; prints a markdown table
(FPS wall and steady, the chain's wall, CPU and waits per batch; medians) with the command at
its top and writes it to ``DIR/<experiment>-ab.md`` (``chain-process-ab.md`` for ``chain``;
default ``$OUT``, else the current folder). ``cap``: the two-camera graph (16 nodes, 1280x720,
baseline placement) as a captured stream, depth 3, after a reset
(``benchmarks/perf/capture_stream.py``). Prints FPS per
round. Under py-spy (staged beside Warp by ``warp-pack ... py-spy``)::

    py-spy record -r 200 --threads --gil -f raw -o orb_gil.txt -- python3 benchmarks/perf/hot_paths.py orb

and ``benchmarks/perf/pyspy_summary.py orb_gil.txt`` for a per-thread summary (``orb`` runs the
chain in a process of its own: add ``--subprocesses`` to sample it, or profile
``--chain-in-process``).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # this tree's warpvx, not an installed one
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


def _arm_row(row) -> dict:
    """An ``orb`` run's numbers: FPS (wall, steady) and the chain's ms per batch (wall, CPU,
    waits for the frame jobs and for keyframe cores; see ``orbslam_bench.pool_per_batch``)."""
    per = row.get("pool_per_batch", {})
    return {"fps": row["fps"], "steady_fps": row["steady_fps"],
            **{k: per.get(f"chain_{k}_ms") for k in ("wall", "cpu", "wait_ahead", "wait_keyframe")}}


def orb(rounds: int, switch, frames: int = 600, chain_process: bool = True, cache=None, backend="cuda",
        batch: int = 16, workers=None, nice: int = 0, tag: str = "orb round", settings=None):
    """``rounds`` timed runs on one pool (``workers`` pose processes at niceness ``nice``;
    ``settings``: the pool's attributes for the runs, see ``orbslam_bench.bench_frontend_batched``),
    each printed as ``{tag} {r}: {FPS} FPS {json of _arm_row}``; returns the last run's row."""
    import orbslam_bench as bench

    from warpvx.apps import orbslam as o
    from warpvx.apps import orbslam_batch as ob

    left, K = _rendered(cache)
    camera = o.Camera(K, (1241, 376))
    feed = bench.replay([{"image": im} for im in left], frames)
    with ob.make_pool(workers, chain_process=chain_process, nice=nice) as pool, \
            tempfile.TemporaryDirectory() as out:
        for r in range(rounds):
            row, _ = bench.bench_frontend_batched(feed, camera, backend, Path(out), None, batch, pool,
                                                  settings=settings,
                                                  switch=ob.SWITCH_INTERVAL if switch is None else switch)
            print(f"{tag} {r}: {row['fps']:.1f} FPS {json.dumps(_arm_row(row))}", flush=True)
    return row


def _workers_arms():
    """The ``workers`` experiment's arms: the default pool and two smaller ones."""
    from warpvx.apps.orbslam_pool import default_workers

    n = default_workers()
    return tuple((f"{w} pose processes{' (default)' if w == n else ''}", {"workers": w})
                 for w in dict.fromkeys((n, max(2, n - 3), max(2, n - 5))))


#: orb-ab's experiments: name -> (title, its arms: label, keyword arguments of :func:`orb`; or
#: a function of no argument returning them); the first arm is the reference.
EXPERIMENTS = {
    "chain": ("the chain in this process vs in its own process",
              (("chain in this process (before)", {"chain_process": False}),
               ("chain in its own process (default)", {}))),
    "batch": ("16 frames per batch (default) vs 32", (("B=16 (default)", {}), ("B=32", {"batch": 32}))),
    "nice": ("the pose processes at the caller's priority (default) vs niceness 5 and 10",
             (("nice 0 (default)", {}), ("nice 5", {"nice": 5}), ("nice 10", {"nice": 10}))),
    "workers": ("fewer pose processes (their cores compete with the chain's)", _workers_arms),
    "direct": ("jobs written to the pose processes by the thread that dispatches them (default) vs "
               "through multiprocessing's task thread (before)",
               (("direct (default)", {}), ("task thread (before)", {"settings": {"direct": False}}))),
    "look_ahead": ("the chain's core look-ahead from the pose processes (default) vs 6 frames (before) and 16",
                   (("from the processes (default)", {}), ("6 frames (before)", {"settings": {"look_ahead": 6}}),
                    ("16 frames", {"settings": {"look_ahead": 16}}))),
}


def _arms(experiment):
    arms = EXPERIMENTS[experiment][1]
    return arms() if callable(arms) else arms


def orb_round(experiment: str, rotate: int, frames: int, cache, backend):
    """One round of ``orb-ab``: each arm of ``experiment`` once in this process (a pool of its
    own each), in order from arm ``rotate`` on; prints ``arm {i}: ... {json}`` per arm."""
    arms = _arms(experiment)
    for i in [*range(len(arms))][rotate % len(arms):] + [*range(len(arms))][:rotate % len(arms)]:
        orb(1, None, frames, cache=cache, backend=backend, tag=f"arm {i}", **arms[i][1])


def _median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else float("nan")


def orb_ab(pairs: int, out: str, frames: int = 600, backend="cuda", experiment: str = "chain"):
    """An interleaved A/B(/C) of the batched front end (``EXPERIMENTS[experiment]``, see the
    module's docstring): ``pairs`` rounds, each a fresh process that runs every arm once (a
    pool of its own each), the arms' order rotated by round; written to
    ``out/<experiment>-ab.md``; returns the markdown lines."""
    title = EXPERIMENTS[experiment][0]
    arms = _arms(experiment)
    command = (f"PYTHONPATH=. python3 benchmarks/perf/hot_paths.py orb-ab --pairs {pairs}"
               + (f" --experiment {experiment}" if experiment != "chain" else "")
               + (f" --frames {frames}" if frames != 600 else "") + (f" --backend {backend}" if backend != "cuda" else ""))
    runs = [[] for _ in arms]
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "frames.npz")
        t = time.perf_counter()
        _rendered(cache)
        print(f"rendered in {time.perf_counter() - t:.1f} s", flush=True)
        for r in range(pairs):
            t = time.perf_counter()
            run = subprocess.run([sys.executable, __file__, "orb-round", "--experiment", experiment, "--rotate", str(r),
                                  "--frames-cache", cache, "--frames", str(frames), "--backend", backend],
                                 capture_output=True, text=True, timeout=300)
            found = re.findall(r"arm (\d+) 0: [0-9.]+ FPS (\{.*\})", run.stdout)
            if len(found) != len(arms):
                raise RuntimeError(f"round {r + 1}: {len(found)} of {len(arms)} arms (exit {run.returncode}):\n"
                                   f"{run.stdout}\n{run.stderr}")
            for i, row in found:
                runs[int(i)].append(json.loads(row))
            fps = "; ".join(f"{label}: {rows[-1]['fps']:.1f} FPS" for (label, _), rows in zip(arms, runs))
            print(f"round {r + 1} ({time.perf_counter() - t:.0f} s): {fps}", flush=True)
    ref = _median(row["fps"] for row in runs[0])
    lines = [f"Regenerate (H100, one call): `{command}`",
             f"(On {backend}, {pairs} rounds, each a fresh process running every arm once, the order rotated by "
             f"round; per arm: its pose pool (and chain process) started, a warm-up, then {frames} frames timed; "
             "the frames rendered once, before. Chain columns: ms per 16-frame batch in the chain process, "
             "medians.)", "",
             f"# ORB-SLAM batched front end (mono, default settings, 1241x376): {title}, interleaved", "",
             "| arm | FPS (wall) per round | FPS (wall), median | FPS (steady), median | chain wall | chain CPU "
             "| chain waits, frame jobs | chain waits, keyframe cores |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for (label, _), rows in zip(arms, runs):
        m = _median(row["fps"] for row in rows)
        chain = " | ".join(f"{_median(row[k] for row in rows):.2f}" for k in ("wall", "cpu", "wait_ahead",
                                                                              "wait_keyframe"))
        per_round = " / ".join(f"{row['fps']:.1f}" for row in rows)
        lines.append(f"| {label} | {per_round} | {m:.1f} ({100 * (m / ref - 1):+.1f}%) | "
                     f"{_median(row['steady_fps'] for row in rows):.1f} | {chain} |")
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
    p.add_argument("path", choices=("orb", "cap", "orb-ab", "orb-round"))
    p.add_argument("--switch-interval", type=float, default=None,
                   help="GIL switch interval for the run, seconds (default: Python's, 0.005; orb: "
                        "the batched front end's own, orbslam_batch.SWITCH_INTERVAL)")
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--chain-in-process", action="store_true", help="orb: the chain in this process (the path before)")
    p.add_argument("--frames-cache", default=None, help="orb: the rendered frames' .npz (made when missing)")
    p.add_argument("--frames", type=int, default=600, help="orb, orb-ab: frames timed")
    p.add_argument("--backend", default="cuda", help="orb, orb-ab: the batched front end's backend")
    p.add_argument("--pairs", type=int, default=3, help="orb-ab: pairs of runs")
    p.add_argument("--experiment", default="chain",
                   help=f"orb-ab: which A/B, or several, comma-separated ({', '.join(EXPERIMENTS)})")
    p.add_argument("--workers", type=int, default=None, help="orb: pose processes (default: make_pool's)")
    p.add_argument("--nice", type=int, default=0, help="orb: the pose processes' niceness increment")
    p.add_argument("--rotate", type=int, default=0, help="orb-round (orb-ab's): the arm to start with")
    p.add_argument("--batch", type=int, default=16, help="orb: frames per batch")
    p.add_argument("--out", default=os.environ.get("OUT") or ".", help="orb-ab: output folder (default $OUT)")
    args = p.parse_args(argv)
    if args.path == "orb-ab":
        experiments = args.experiment.split(",")
        unknown = [e for e in experiments if e not in EXPERIMENTS]
        if unknown:
            p.error(f"--experiment: unknown {', '.join(unknown)} (choose from {', '.join(EXPERIMENTS)})")
        for experiment in experiments:
            orb_ab(args.pairs, args.out, args.frames, args.backend, experiment)
        return
    if args.path == "orb-round":
        orb_round(args.experiment, args.rotate, args.frames, args.frames_cache, args.backend)
        return
    if args.switch_interval is not None:
        sys.setswitchinterval(args.switch_interval)
    print(f"GIL switch interval {sys.getswitchinterval() * 1e3:g} ms, pid {os.getpid()}", flush=True)
    if args.path == "orb":
        orb(args.rounds, args.switch_interval, args.frames, not args.chain_in_process, args.frames_cache, args.backend,
            args.batch, args.workers, args.nice)
    else:
        cap(args.rounds, args.switch_interval)


if __name__ == "__main__":
    main()
