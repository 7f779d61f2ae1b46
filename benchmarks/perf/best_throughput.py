"""``schedule("best")`` for one frame's makespan against for a stream's frame rate, on the GPU
machine: which placement each keeps, and how fast each streams.

    PYTHONPATH=. python3 benchmarks/perf/best_throughput.py --out $OUT/bt

The two-camera graph (benchmarks/graph_bench.py, 16 nodes; ``--cpu-heavy``: 21) at
``--size``: a model fitted on 20 frames of the baseline (``Graph.fit_model``), then
``schedule("best", model=..., trial_inputs=...)`` with ``objective="latency"`` (the default:
its trial runs frames one at a time) and with ``objective="throughput"`` (its trial streams
them, 3 in flight). The kept plans and the baseline are then measured in interleaved
rounds, both ways: median makespan of frames one at a time (``Graph.measure_plans``) and
median frame rate streamed (``Graph.measure_streams``). Writes ``best_throughput.md`` (this
command on top).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import graph_bench  # noqa: E402  (benchmarks/graph_bench.py)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="a new folder for best_throughput.md")
    ap.add_argument("--size", default="1280x720")
    ap.add_argument("--gpu", default="cuda", help="the GPU role's device (warp-cpu: a smoke test)")
    ap.add_argument("--cpu-heavy", action="store_true", help="the 21-node graph")
    ap.add_argument("--n-cpus", type=int, default=4)
    ap.add_argument("--rounds", type=int, default=4, help="rounds of each trial and of the final measure")
    ap.add_argument("--frames", type=int, default=30, help="frames per plan and round")
    ap.add_argument("--margin", type=float, default=None,
                    help="the trials' trial_margin (default the library's): candidates "
                         "predicted within this fraction of the fastest are measured")
    argv = sys.argv[1:] if argv is None else list(argv)
    args = ap.parse_args(argv)
    import cv2

    cv2.setNumThreads(1)  # one core per CPU worker, as graph_bench
    size = tuple(int(v) for v in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    frames = graph_bench.make_frames(size, 16)
    g = graph_bench.build_graph(size, cpu_heavy=args.cpu_heavy)
    g.verify(frames[:2])
    base = g.schedule("baseline", n_cpus=args.n_cpus, gpu=args.gpu)
    for f in frames[:4]:
        g.process(f)
    runs = []
    for i in range(20):
        g.process(frames[i % len(frames)])
        runs.append(base.last_run[-1])
    model = g.fit_model(base, runs=runs)
    kept = {}
    for objective in ("latency", "throughput"):
        plan = g.schedule("best", n_cpus=args.n_cpus, gpu=args.gpu, model=model,
                          trial_inputs=frames, trial_frames=args.frames if objective == "throughput"
                          else 5, trial_rounds=args.rounds, objective=objective,
                          **({} if args.margin is None else {"trial_margin": args.margin}))
        kept[objective] = plan
        print(f"best for {objective}: {plan.schedule.info['chosen']}", flush=True)
    plans = [base, kept["latency"], kept["throughput"]]
    names = ["baseline", "best (latency)", "best (throughput)"]
    ms = g.measure_plans(plans, frames, rounds=args.rounds, frames=args.frames)
    fps = g.measure_streams(plans, frames, rounds=args.rounds, frames=args.frames * 4)
    lines = [f"<!-- PYTHONPATH=. python3 {' '.join(['benchmarks/perf/best_throughput.py', *argv])} -->",
             f"# best for latency vs best for throughput: {g.name} {size[0]}x{size[1]}, "
             f"{args.n_cpus} CPU workers, GPU role {args.gpu}", "",
             "| plan | kept candidate | trial (median per candidate) | GPU nodes | makespan ms (one at a time, median) | FPS (streamed, 3 in flight, median) |",
             "|---|---|---|---|---:|---:|"]
    for name, plan, m, f in zip(names, plans, ms, fps):
        info = plan.schedule.info
        trial = info.get("trial_fps") or info.get("trial_ms") or {}
        unit = "FPS" if "trial_fps" in info else "ms"
        tried = ", ".join(f"{k} {v:.1f} {unit}" for k, v in trial.items()) or "-"
        gpu = sorted(t for t, p in plan.placement.items() if p == "gpu")
        lines.append(f"| {name} | {info.get('chosen', '-')} | {tried} | {len(gpu)} | "
                     f"{statistics.median(r.makespan for r in m):.3f} | {statistics.median(f):.1f} |")
    lines += ["", "Placements off the GPU: " + "; ".join(
        f"{n}: " + ", ".join(f"{t} {p}" for t, p in sorted(plan.placement.items()) if p != "gpu")
        for n, plan in zip(names, plans)), "", f"Total {time.perf_counter() - t0:.0f} s."]
    g.close()
    (out / "best_throughput.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
