"""Why later rounds of the graph bench run slower than its training rounds.

Two checks:

``analyse``: offline, on recorded ``graph_bench.json`` runs (no frames run). Per graph, size
and policy, the median makespan of each interleaved round of ``--block`` frames in the
order they ran (rounds 1-2: the training rounds, run beside each other before the model's
probe and best's trial; rounds 3+: the later rounds), each over the policy's own median;
the *round index* (the mean of baseline, heft and xeft per round: what moved every policy
alike, the machine at that time), and the heavy OpenCV nodes' time per CPU worker in the
training frames against the later frames (a node that runs at two speeds shows here).
Writes ``drift.md`` and, with matplotlib, ``drift.png``.

``soak``: runs one graph on this machine with one placement for many frames, in rounds,
and records what could grow with frames in our process: frame time, RSS, live objects
(``len(gc.get_objects())``), gc collections and the time they took (``gc.callbacks``),
threads, the GPU-timing event pool, ``cv2.getNumThreads()``, the plan's ``last_run``
(the soak keeps no FrameResult itself);
with ``--probe`` the bench's probes (``Graph.measure_probes``: the contention probe and the
GIL shares) run half-way, as the bench once ran them between the training and the later
rounds (it runs them before the training since session 6). Writes ``soak.md``/``soak.json``.

Usage::

    python benchmarks/drift_check.py analyse \\
        benchmarks/results/graph/h100-2026-11-24-s6b/graph_bench.json.gz --out /tmp/drift
    python benchmarks/drift_check.py soak --graph two-cameras-cv --size 640x360 --frames 300 \\
        --policy baseline --probe --out /tmp/drift
"""

from __future__ import annotations

import argparse
import gc
import json
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from model_replay import load  # noqa: E402 - a graph_bench.json(.gz)

#: The rounds of each policy's makespans that trained the model (graph_bench: fit frames
#: 1-20 in rounds of 10; best joins later and has none).
FIT_ROUNDS = 2
#: Rounds right after training that the near error is taken on (graph_bench.NEAR_ROUNDS).
NEAR_ROUNDS = 2
POLICIES = ("baseline", "heft", "xeft", "best")
#: Nodes whose per-worker time is compared (long single-threaded OpenCV calls).
HEAVY = ("denoiseL", "denoiseR", "edgesL", "edgesR")


def round_medians(makespans, block: int) -> list:
    """Median makespan of each round of ``block`` frames, in the order they ran."""
    return [statistics.median(makespans[i:i + block]) for i in range(0, len(makespans), block)]


def shape(report: dict) -> list:
    """Per experiment: each policy's round medians over its own median, the round index
    (mean of the scheduler policies per round), the training-policy step (later over
    training rounds) and the heavy nodes' ms per worker, training vs later frames."""
    block = report.get("block", 10)
    out = []
    for e in report["experiments"]:
        rows, nodes = {}, []
        for p in e["policies"]:
            meds = round_medians(p["makespans"], block)
            mid = statistics.median(p["makespans"])
            rows[p["policy"]] = [m / mid for m in meds]
            if p["policy"] == "best":
                continue
            for n in HEAVY:
                if n in p.get("fit_nodes", {}) and n in p["nodes"]:
                    nodes.append((p["policy"], n, p["nodes"][n]["pe"],
                                  p["fit_nodes"][n]["measured_ms"], p["nodes"][n]["measured_ms"]))
        scheds = [rows[p] for p in rows if p != "best"]
        index = [statistics.mean(c) for c in zip(*scheds)]
        steps = {p["policy"]: statistics.median(p["makespans"][FIT_ROUNDS * block:])
                 / statistics.median(p["makespans"][:FIT_ROUNDS * block])
                 for p in e["policies"] if p["policy"] != "best"}
        # The recorded out-of-sample prediction against the rounds right after training
        # (graph_bench's NEAR_ROUNDS; best joined there: its first rounds).
        # and with the training policy's drift taken out (graph_bench's error_dedrift_pct).
        near = {}
        train = steps[e.get("train", "baseline")]
        for p in e["policies"]:
            lo = 0 if p["policy"] == "best" else FIT_ROUNDS * block
            meas = statistics.median(p["makespans"][lo:lo + NEAR_ROUNDS * block])
            near[p["policy"]] = (p["error_out_pct"], 100 * (p["pred_out_ms"] / meas - 1),
                                 100 * (p["pred_out_ms"] * train / p["measured_out_ms"] - 1))
        out.append({"tag": e["tag"], "rounds": rows, "index": index, "steps": steps,
                    "heavy": nodes, "near": near})
    return out


def analyse_markdown(named: dict) -> str:
    lines = [f"Regenerate: `python benchmarks/drift_check.py {' '.join(sys.argv[1:])}`", "",
             "# Drift of the graph bench's rounds", "",
             "Per run and experiment: the round index (mean over baseline, heft, xeft of each "
             "round's median makespan over the policy's own median; rounds 1-2 trained the "
             "model, then the probe and best's trial ran, then rounds 3-10), and each "
             "policy's later rounds over its training rounds (median makespans).", "",
             "| run | experiment | round index 1 2 \\| 3 ... 10 | later / training: baseline, "
             "heft, xeft |",
             "| --- | --- | --- | --- |"]
    for run, exps in named.items():
        for x in exps:
            idx = " ".join(f"{v:.2f}" for v in x["index"][:FIT_ROUNDS]) + " \\| " + \
                " ".join(f"{v:.2f}" for v in x["index"][FIT_ROUNDS:])
            steps = ", ".join(f"{x['steps'][p]:.2f}" for p in ("baseline", "heft", "xeft")
                              if p in x["steps"])
            lines.append(f"| {run} | {x['tag']} | {idx} | {steps} |")
    lines += ["", "The recorded out-of-sample error (training model against frames 21-100), "
              f"the same prediction against the {NEAR_ROUNDS} rounds right after training "
              "(nearest in time; best: its first rounds), and against frames 21-100 with the "
              "training policy's drift (later over training rounds) taken out of the "
              "prediction (that policy as the reference clock: trivially small for itself), "
              "per policy; the count of cells within 20% leaves the training policy out.", "",
              "| run | experiment | " + " | ".join(f"{p}: all / near / drift out" for p in POLICIES)
              + " | within 20% (others): all / near / drift out |",
              "| --- | --- |" + " ---: |" * (len(POLICIES) + 1)]
    totals = {}
    for run, exps in named.items():
        for x in exps:
            cells = [x["near"].get(p) for p in POLICIES]
            others = [x["near"][p] for p in POLICIES[1:] if p in x["near"]]
            ok = [sum(abs(c[i]) <= 20 for c in others) for i in range(3)]
            t = totals.setdefault(run, [0, 0, 0, 0])
            t[:3] = [a + b for a, b in zip(t[:3], ok)]
            t[3] += len(others)
            lines.append(f"| {run} | {x['tag']} | " + " | ".join(
                " / ".join(f"{v:+.1f}%" for v in c) if c else "-" for c in cells)
                + " | " + " / ".join(map(str, ok)) + " |")
    lines += [""] + [f"{run}: within 20%, heft/xeft/best: {t[0]}/{t[3]} as recorded, {t[1]}/{t[3]} "
                     f"against the nearest rounds, {t[2]}/{t[3]} with the drift taken out."
                     for run, t in totals.items()]
    lines += ["", "Heavy OpenCV nodes (one OpenCV thread each), median ms per frame: training "
              "frames -> later frames, per policy and worker.", "",
              "| run | experiment | policy | node | worker | training | later | later/training |",
              "| --- | --- | --- | --- | --- | ---: | ---: | ---: |"]
    for run, exps in named.items():
        for x in exps:
            for policy, n, pe, a, b in x["heavy"]:
                lines.append(f"| {run} | {x['tag']} | {policy} | {n} | {pe} | {a:.1f} | {b:.1f} "
                             f"| {b / a:.2f} |")
    return "\n".join(lines) + "\n"


def analyse_plot(named: dict, path: Path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # the table has the same numbers
        return None
    runs = list(named)
    n_exp = max(len(v) for v in named.values())
    fig, axes = plt.subplots(len(runs), n_exp, figsize=(4 * n_exp, 2.6 * len(runs)),
                             squeeze=False, sharey=True)
    for i, run in enumerate(runs):
        for j, x in enumerate(named[run]):
            ax = axes[i][j]
            for policy, vals in x["rounds"].items():
                start = 0 if policy != "best" else FIT_ROUNDS
                ax.plot(range(start + 1, start + len(vals) + 1), vals, marker=".", label=policy)
            ax.axvline(FIT_ROUNDS + 0.5, color="k", lw=0.8, ls="--")
            ax.axhline(1.0, color="grey", lw=0.5)
            ax.set_title(f"{run} {x['tag']}", fontsize=8)
            ax.set_xlabel("round (time order)", fontsize=7)
            if j == 0:
                ax.set_ylabel("round median / policy median", fontsize=7)
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)
    return path


def analyse_main(args):
    named = {}
    for p in args.paths:
        name = Path(p).parent.name.replace("h100-2026-11-24-", "") or Path(p).stem
        named[name] = shape(load(p))
    args.out.mkdir(parents=True, exist_ok=True)
    text = analyse_markdown(named)
    (args.out / "drift.md").write_text(text)
    analyse_plot(named, args.out / "drift.png")
    print(text)


# --------------------------------------------------------------------------- soak


class GcTimer:
    """Collections per generation and the time spent in them, from ``gc.callbacks``."""

    def __init__(self):
        self.count = [0, 0, 0]
        self.seconds = 0.0
        self._t0 = 0.0

    def __call__(self, phase, info):
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            self.seconds += time.perf_counter() - self._t0
            self.count[info["generation"]] += 1

    def __enter__(self):
        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc):
        gc.callbacks.remove(self)


def state(g, gct: GcTimer) -> dict:
    """What could grow in the process, now."""
    import cv2

    from warpvx.graph.diagnostics import host_rss_bytes
    from warpvx.runtime.timeline import EventPool

    pools = [o for o in gc.get_objects() if isinstance(o, EventPool)]
    return {"rss_mb": host_rss_bytes() / 2 ** 20, "objects": len(gc.get_objects()),
            "threads": threading.active_count(), "gc_counts": list(gct.count),
            "gc_ms": gct.seconds * 1e3, "cv_threads": cv2.getNumThreads(),
            "event_pool": sum(len(p) for p in pools),
            "last_run": len(g.plan.last_run) if g.plan is not None else 0}


def soak_main(args):
    import cv2

    import graph_bench as gb
    from warpvx.backend import init_warp

    init_warp()
    cv2.setNumThreads(1)
    w, h = (int(v) for v in args.size.split("x"))
    frames = gb.make_frames((w, h), 8)
    g = gb.build_graph((w, h), max_corners=200, cpu_heavy=args.graph == "two-cameras-cv")
    g.verify(frames[:2])
    g.calibrate(gpu=args.gpu, repeats=3)
    plan = g.schedule(args.policy, n_cpus=args.n_cpus, gpu=args.gpu)
    samples = []
    n_rounds = -(-args.frames // args.block)
    with GcTimer() as gct:
        t_start = time.perf_counter()
        for r in range(n_rounds):
            if args.probe and r == n_rounds // 2:
                t = time.perf_counter()
                g.measure_probes(plan, gil=True)
                print(f"probe: {time.perf_counter() - t:.1f} s", flush=True)
            runs = gb.run_frames(g, plan, [frames[(r * args.block + i) % len(frames)]
                                           for i in range(args.block)])
            s = state(g, gct)
            s.update({"round": r + 1, "t_s": time.perf_counter() - t_start,
                      "median_ms": statistics.median(x.makespan for x in runs)})
            samples.append(s)  # the FrameResults are dropped: what stays alive is the library's
            print(" ".join(f"{k}={v:.1f}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in s.items()), flush=True)
    g.close()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "soak.json").write_text(json.dumps(samples, indent=1))
    keys = ["round", "t_s", "median_ms", "rss_mb", "objects", "threads", "gc_counts", "gc_ms",
            "event_pool", "cv_threads", "last_run"]
    lines = [f"Regenerate: `python benchmarks/drift_check.py {' '.join(sys.argv[1:])}`", "",
             f"# Soak: {args.graph} {args.size}, {args.policy}, {args.frames} frames in rounds of "
             f"{args.block}{', the model probe half-way' if args.probe else ''}", "",
             "| " + " | ".join(keys) + " |", "|" + " --- |" * len(keys)]
    for s in samples:
        lines.append("| " + " | ".join(f"{s[k]:.1f}" if isinstance(s[k], float) else str(s[k])
                                       for k in keys) + " |")
    (args.out / "soak.md").write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out / 'soak.md'}")
    return samples


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("analyse", help="the drift's shape in recorded graph_bench.json(.gz) runs")
    a.add_argument("paths", nargs="+")
    a.add_argument("--out", type=Path, default=Path("/tmp/drift"))
    s = sub.add_parser("soak", help="one placement for many frames here, with growth counters")
    s.add_argument("--graph", default="two-cameras-cv", choices=("two-cameras", "two-cameras-cv"))
    s.add_argument("--size", default="640x360")
    s.add_argument("--policy", default="baseline")
    s.add_argument("--frames", type=int, default=300)
    s.add_argument("--block", type=int, default=10)
    s.add_argument("--n-cpus", type=int, default=None)
    s.add_argument("--gpu", default="warp-cpu")
    s.add_argument("--probe", action="store_true", help="run the model's probe half-way")
    s.add_argument("--out", type=Path, default=Path("/tmp/drift"))
    args = p.parse_args(argv)
    if args.cmd == "soak" and args.n_cpus is None:
        from warpvx.graph import default_n_cpus
        args.n_cpus = default_n_cpus()
    return analyse_main(args) if args.cmd == "analyse" else soak_main(args)


if __name__ == "__main__":
    main()
