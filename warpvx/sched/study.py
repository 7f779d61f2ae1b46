"""Synthetic scheduling study: XEFT against HEFT (and HEFT against the baseline) on random DAGs.

The thesis' study (§5.3, Fig. 5.4-5.5) schedules ~40,000 generated DAGs (20 to 250 tasks, classes
*Tree* and *Linear*, 2-5 CPUs + 1 GPU) and relates XEFT's gain over HEFT to HEFT's idle time and
XO efficiency. This module does the same over the parameter sets of the thesis authors'
generator (SPEC §7): P(single implementation) 0.2/0.5/0.8, P(CPU-only | single) 0.2/0.5/0.8,
CPU times in [10,90]/[10,50]/[50,90], GPU speed-ups 1-4x/4-9x/0.5-2x, each DAG drawing one value
of each independently. Every DAG is scheduled with baseline, HEFT, XEFT and best; every schedule
is validated.

Outputs in ``out_dir``: ``per_dag.csv`` (one row per DAG), ``summary.json`` and ``summary.md``
(mean/min/max gains, XEFT's win/tie/loss shares, per class, per parameter value and per
HEFT idle/XO-efficiency quadrant), and PNG plots: ``fig_tree.png`` / ``fig_linear.png`` (as
thesis Fig. 5.4 / 5.5: HEFT's XO efficiency against HEFT's idle time, a circle where XEFT wins
and a cross where it loses, sized by the gain), ``gain_vs_heft_metrics.png``,
``ratio_hist.png`` (XEFT/HEFT makespan ratios) and ``heft_vs_baseline_hist.png``.

Command line: ``warpvx sched-study --n-dags 4000`` (writes a new
``./warpvx-results/sched-study-<YYYYmmdd-HHMMSS>/``; ``--out benchmarks/results/sched_study``
replaces the recorded study) or ``python -m warpvx.sched.study ...``.
"""

from __future__ import annotations

import csv
import json
import math
import multiprocessing
import os
import random
import statistics
import sys
import time

from ..check import check_int
from ..errors import WarpvxValueError
from .generator import CLASSES, random_dag
from .metrics import metrics
from .policies import _heft_order, _place_eft, _to_schedule, _xeft_order, baseline
from .dag import prepare
from .validate import validate_schedule

# The thesis authors' generator sets (SPEC §7).
P_SINGLE = (0.2, 0.5, 0.8)
P_CPU_ONLY = (0.2, 0.5, 0.8)
CPU_RANGES = ((10.0, 90.0), (10.0, 50.0), (50.0, 90.0))
GPU_SPEEDUPS = ((1.0, 4.0), (4.0, 9.0), (0.5, 2.0))
COMM_RANGE = (0.0, 10.0)

FIELDS = [
    "dag", "cls", "n_nodes", "n_edges", "avg_degree", "depth", "n_cpus", "p_single",
    "p_cpu_only", "cpu_range", "gpu_speedup", "share_cpu_only", "share_gpu_only",
    "baseline", "heft", "xeft", "best", "best_chosen",
    "gain_xeft_vs_heft", "ratio_xeft_heft", "gain_heft_vs_baseline", "gain_xeft_vs_baseline",
    "gain_best_vs_heft", "max_xo",
    "heft_xo", "xeft_xo", "heft_xo_eff", "xeft_xo_eff", "heft_idle", "xeft_idle",
    "heft_overlap", "xeft_overlap", "heft_slr", "xeft_slr", "heft_speedup", "xeft_speedup",
    "baseline_slr",
]


def _gain(old: float, new: float) -> float:
    """Relative improvement of ``new`` over ``old`` (thesis Table 5.1: 1 - new / old)."""
    return 1.0 - new / old if old > 0 else 0.0


def _depth(problem) -> int:
    level = [1] * len(problem.names)
    for v in problem.topo:
        for q, _ in problem.succs[v]:
            if level[v] + 1 > level[q]:
                level[q] = level[v] + 1
    return max(level)


def evaluate_dag(job: dict) -> dict:
    """Generate one DAG from ``job``, schedule it with every policy, validate, measure.

    The study's "xeft" is the thesis' Algorithm 1 as published: HEFT's mean-cost ranking
    reordered to cluster exclusive nodes. :func:`warpvx.sched.xeft` also tries the same
    reordering of a best-cost ranking and keeps the shorter, so on some DAGs it is shorter than
    the study's column; the study measures the thesis' algorithm, not the library's refinement.
    """
    dag = random_dag(
        job["n_nodes"], job["cls"], p_single=job["p_single"], p_cpu_only=job["p_cpu_only"],
        cpu_range=job["cpu_range"], gpu_speedup=job["gpu_speedup"], comm_range=job["comm_range"],
        n_cpus=job["n_cpus"], seed=job["seed"],
    )
    problem = prepare(dag)
    order_h = _heft_order(problem)
    order_x = _xeft_order(problem, order_h)
    sh = _to_schedule(problem, *_place_eft(problem, order_h), "heft", order_h)
    sx = _to_schedule(problem, *_place_eft(problem, order_x), "xeft", order_x)
    sb = baseline(dag)
    for s in (sh, sx, sb):
        validate_schedule(dag, s)
    mh, mx, mb = metrics(dag, sh), metrics(dag, sx), metrics(dag, sb)
    h, x, b = mh["makespan"], mx["makespan"], mb["makespan"]
    chosen = "xeft" if x < h else "heft"
    best_span = min(h, x)
    n = len(problem.names)
    e = dag.number_of_edges()
    excl = problem.excl
    return {
        "dag": job["dag"], "cls": job["cls"], "n_nodes": n, "n_edges": e,
        "avg_degree": 2.0 * e / n, "depth": _depth(problem), "n_cpus": job["n_cpus"],
        "p_single": job["p_single"], "p_cpu_only": job["p_cpu_only"],
        "cpu_range": "%g-%g" % job["cpu_range"], "gpu_speedup": "%g-%g" % job["gpu_speedup"],
        "share_cpu_only": sum(1 for k in excl if k >= 0 and problem.kinds[k] == "host") / n,
        "share_gpu_only": sum(1 for k in excl if k >= 0 and problem.kinds[k] == "device") / n,
        "baseline": b, "heft": h, "xeft": x, "best": best_span, "best_chosen": chosen,
        "gain_xeft_vs_heft": _gain(h, x), "ratio_xeft_heft": x / h if h > 0 else 1.0,
        "gain_heft_vs_baseline": _gain(b, h), "gain_xeft_vs_baseline": _gain(b, x),
        "gain_best_vs_heft": _gain(h, best_span), "max_xo": mh["max_exclusive_overlap"],
        "heft_xo": mh["exclusive_overlap"], "xeft_xo": mx["exclusive_overlap"],
        "heft_xo_eff": mh["xo_efficiency"], "xeft_xo_eff": mx["xo_efficiency"],
        "heft_idle": mh["idle_fraction"], "xeft_idle": mx["idle_fraction"],
        "heft_overlap": mh["overlap"], "xeft_overlap": mx["overlap"],
        "heft_slr": mh["slr"], "xeft_slr": mx["slr"],
        "heft_speedup": mh["speedup"], "xeft_speedup": mx["speedup"], "baseline_slr": mb["slr"],
    }


def make_jobs(n_dags, sizes=(20, 250), classes=CLASSES, n_cpus_range=(2, 5), seed=0,
              comm_range=COMM_RANGE) -> list:
    """Draw the parameters of ``n_dags`` DAGs: classes in turn, everything else at random."""
    rng = random.Random(seed)
    jobs = []
    for i in range(n_dags):
        jobs.append({
            "dag": i,
            "cls": classes[i % len(classes)],
            "n_nodes": rng.randint(sizes[0], sizes[1]),
            "n_cpus": rng.randint(n_cpus_range[0], n_cpus_range[1]),
            "p_single": rng.choice(P_SINGLE),
            "p_cpu_only": rng.choice(P_CPU_ONLY),
            "cpu_range": rng.choice(CPU_RANGES),
            "gpu_speedup": rng.choice(GPU_SPEEDUPS),
            "comm_range": tuple(comm_range),
            "seed": rng.getrandbits(63),
        })
    return jobs


def _stats(values) -> dict:
    vals = [v for v in values if not (isinstance(v, float) and math.isnan(v))]
    if not vals:
        return {"n": 0}
    return {
        "n": len(vals), "mean": statistics.fmean(vals), "median": statistics.median(vals),
        "min": min(vals), "max": max(vals),
    }


def _wtl(gains, tol=1e-9) -> dict:
    n = len(gains)
    if n == 0:
        return {"wins": 0.0, "ties": 0.0, "losses": 0.0}
    wins = sum(1 for g in gains if g > tol)
    losses = sum(1 for g in gains if g < -tol)
    return {"wins": wins / n, "ties": (n - wins - losses) / n, "losses": losses / n}


def _group_summary(recs) -> dict:
    g = [r["gain_xeft_vs_heft"] for r in recs]
    return {
        "n_dags": len(recs),
        "xeft_vs_heft": {**_stats(g), **_wtl(g)},
        "heft_vs_baseline": {**_stats([r["gain_heft_vs_baseline"] for r in recs]),
                             **_wtl([r["gain_heft_vs_baseline"] for r in recs])},
        "xeft_vs_baseline": _stats([r["gain_xeft_vs_baseline"] for r in recs]),
        "best_vs_heft": {**_stats([r["gain_best_vs_heft"] for r in recs]),
                         "share_xeft_chosen": (sum(r["best_chosen"] == "xeft" for r in recs) / len(recs))
                         if recs else 0.0},
        "heft_idle": _stats([r["heft_idle"] for r in recs]),
        "heft_xo_eff": _stats([r["heft_xo_eff"] for r in recs]),
        "xeft_xo_eff": _stats([r["xeft_xo_eff"] for r in recs]),
    }


def summarize(records: list) -> dict:
    """Summary statistics of per-DAG records (gains as fractions: 0.1 = 10% shorter)."""
    out = {"all": _group_summary(records), "by_class": {}, "by_param": {}, "by_quadrant": {}}
    for cls in sorted({r["cls"] for r in records}):
        out["by_class"][cls] = _group_summary([r for r in records if r["cls"] == cls])
    for key in ("p_single", "p_cpu_only", "cpu_range", "gpu_speedup", "n_cpus"):
        groups = {}
        for r in records:
            groups.setdefault(str(r[key]), []).append(r["gain_xeft_vs_heft"])
        out["by_param"][key] = {
            k: {"n": len(v), "mean": statistics.fmean(v), **_wtl(v)} for k, v in sorted(groups.items())
        }
    # Thesis claim: XEFT wins where HEFT idles a lot and has a low XO efficiency.
    for cls in sorted({r["cls"] for r in records}):
        recs = [r for r in records if r["cls"] == cls and not math.isnan(r["heft_xo_eff"])]
        if not recs:
            continue
        idle_med = statistics.median(r["heft_idle"] for r in recs)
        eff_med = statistics.median(r["heft_xo_eff"] for r in recs)
        quads = {}
        for r in recs:
            name = ("high idle" if r["heft_idle"] > idle_med else "low idle") + ", " + (
                "low XO eff" if r["heft_xo_eff"] <= eff_med else "high XO eff")
            quads.setdefault(name, []).append(r["gain_xeft_vs_heft"])
        out["by_quadrant"][cls] = {
            "median_heft_idle": idle_med, "median_heft_xo_eff": eff_med,
            **{k: {"n": len(v), "mean": statistics.fmean(v), **_wtl(v)} for k, v in sorted(quads.items())},
        }
    return out


def _pct(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:+.1f}%"


def _share(x) -> str:
    return f"{100 * x:.1f}%"


def summary_markdown(summary: dict, meta: dict) -> str:
    """The summary as a markdown report."""
    lines = [
        "# Synthetic scheduling study: XEFT vs HEFT vs baseline",
        "",
        f"{meta['n_dags']} DAGs, {meta['sizes'][0]}-{meta['sizes'][1]} tasks, classes "
        f"{', '.join(meta['classes'])}, {meta['n_cpus_range'][0]}-{meta['n_cpus_range'][1]} CPUs + 1 GPU, "
        f"transfers in [{meta['comm_range'][0]:g}, {meta['comm_range'][1]:g}], seed {meta['seed']}; "
        f"{meta['seconds']:.0f} s on {meta['workers']} worker(s). Every schedule validated.",
        "",
        "Gain = 1 - new/old makespan (positive: shorter). Tie: equal makespans.",
        "",
        "## XEFT vs HEFT",
        "",
        "| class | DAGs | mean | median | min | max | XEFT wins | ties | XEFT loses "
        "| best vs HEFT (mean) | best picks XEFT |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    groups = [("all", summary["all"])] + list(summary["by_class"].items())
    for name, g in groups:
        x = g["xeft_vs_heft"]
        lines.append(
            f"| {name} | {g['n_dags']} | {_pct(x.get('mean'))} | {_pct(x.get('median'))} | "
            f"{_pct(x.get('min'))} | {_pct(x.get('max'))} | {_share(x['wins'])} | {_share(x['ties'])} | "
            f"{_share(x['losses'])} | {_pct(g['best_vs_heft'].get('mean'))} | "
            f"{_share(g['best_vs_heft']['share_xeft_chosen'])} |"
        )
    lines += [
        "",
        "## HEFT (and XEFT) vs baseline (VisionWorks policy)",
        "",
        "| class | HEFT mean | HEFT min | HEFT max | HEFT better in | XEFT mean | XEFT min | XEFT max |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name, g in groups:
        hb, xb = g["heft_vs_baseline"], g["xeft_vs_baseline"]
        lines.append(
            f"| {name} | {_pct(hb.get('mean'))} | {_pct(hb.get('min'))} | {_pct(hb.get('max'))} | "
            f"{_share(hb['wins'])} | {_pct(xb.get('mean'))} | {_pct(xb.get('min'))} | {_pct(xb.get('max'))} |"
        )
    lines += [
        "",
        "## XEFT vs HEFT by HEFT's idle time and XO efficiency (split at the class medians)",
        "",
        "| class | quadrant | DAGs | mean gain | XEFT wins | XEFT loses |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for cls, q in summary["by_quadrant"].items():
        for name, v in q.items():
            if isinstance(v, dict):
                lines.append(f"| {cls} | {name} | {v['n']} | {_pct(v['mean'])} | {_share(v['wins'])} | "
                             f"{_share(v['losses'])} |")
        lines.append(f"| {cls} | (medians: idle {_share(q['median_heft_idle'])}, XO eff "
                     f"{_share(q['median_heft_xo_eff'])}) | | | | |")
    lines += [
        "",
        "## XEFT vs HEFT by generator parameter",
        "",
        "| parameter | value | DAGs | mean gain | XEFT wins | XEFT loses |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for key, vals in summary["by_param"].items():
        for val, v in vals.items():
            lines.append(f"| {key} | {val} | {v['n']} | {_pct(v['mean'])} | {_share(v['wins'])} | "
                         f"{_share(v['losses'])} |")
    lines.append("")
    return "\n".join(lines)


def _json_safe(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    return x


def plot_study(records: list, out_dir: str) -> list:
    """Write the study's PNG plots; returns their paths (needs matplotlib)."""
    from .gantt import _pyplot

    plt = _pyplot()
    paths = []
    classes = sorted({r["cls"] for r in records})
    thesis_fig = {"tree": "5.4", "linear": "5.5"}
    for cls in classes:
        recs = [r for r in records if r["cls"] == cls and not math.isnan(r["heft_xo_eff"])]
        fig, ax = plt.subplots(figsize=(7, 5.5))
        for sign, marker, color, label in ((1, "o", "tab:green", "XEFT faster"),
                                           (-1, "x", "tab:red", "XEFT slower")):
            sel = [r for r in recs if sign * r["gain_xeft_vs_heft"] > 1e-9]
            style = {"facecolors": "none", "edgecolors": color} if marker == "o" else {"color": color}
            ax.scatter(
                [100 * r["heft_xo_eff"] for r in sel], [100 * r["heft_idle"] for r in sel],
                s=[4 + 600 * abs(r["gain_xeft_vs_heft"]) for r in sel], marker=marker,
                linewidths=0.7, alpha=0.6, label=f"{label} ({len(sel)})", **style,
            )
        ties = [r for r in recs if abs(r["gain_xeft_vs_heft"]) <= 1e-9]
        ax.scatter([100 * r["heft_xo_eff"] for r in ties], [100 * r["heft_idle"] for r in ties], s=2,
                   color="0.6", label=f"tie ({len(ties)})")
        ax.set_xlabel("HEFT XO efficiency, XO / max XO (%)")
        ax.set_ylabel("HEFT idle time (% of processor time)")
        ax.set_title(f"{cls.capitalize()} DAGs: XEFT vs HEFT (cf. thesis Fig. {thesis_fig.get(cls, '')}); "
                     "size = |gain|", fontsize=9)
        ax.legend(fontsize=8, loc="best")
        fig.tight_layout()
        p = os.path.join(out_dir, f"fig_{cls}.png")
        fig.savefig(p, dpi=120)
        plt.close(fig)
        paths.append(p)

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    colors = {"tree": "tab:blue", "linear": "tab:orange"}
    for cls in classes:
        recs = [r for r in records if r["cls"] == cls]
        g = [100 * r["gain_xeft_vs_heft"] for r in recs]
        axes[0].scatter([100 * r["heft_xo_eff"] for r in recs], g, s=4, alpha=0.4,
                        color=colors.get(cls), label=cls)
        axes[1].scatter([100 * r["heft_idle"] for r in recs], g, s=4, alpha=0.4, color=colors.get(cls),
                        label=cls)
    axes[0].set_xlabel("HEFT XO efficiency (%)")
    axes[1].set_xlabel("HEFT idle time (%)")
    axes[0].set_ylabel("XEFT gain over HEFT (%)")
    for ax in axes:
        ax.axhline(0, color="black", lw=0.6)
        ax.legend(fontsize=8, markerscale=3)
        ax.grid(alpha=0.3)
    fig.suptitle("XEFT's gain over HEFT against HEFT's XO efficiency and idle time", fontsize=10)
    fig.tight_layout()
    p = os.path.join(out_dir, "gain_vs_heft_metrics.png")
    fig.savefig(p, dpi=120)
    plt.close(fig)
    paths.append(p)

    for key, fname, xlabel, title in (
        ("ratio_xeft_heft", "ratio_hist.png", "XEFT makespan / HEFT makespan",
         "XEFT/HEFT makespan ratio (< 1: XEFT faster)"),
        ("gain_heft_vs_baseline", "heft_vs_baseline_hist.png", "HEFT gain over baseline (%)",
         "HEFT vs the VisionWorks baseline"),
    ):
        fig, ax = plt.subplots(figsize=(7, 4.5))
        scale = 100.0 if key.startswith("gain") else 1.0
        for cls in classes:
            vals = [scale * r[key] for r in records if r["cls"] == cls]
            ax.hist(vals, bins=60, alpha=0.55, color=colors.get(cls), label=f"{cls} ({len(vals)})")
        if key == "ratio_xeft_heft":
            ax.axvline(1.0, color="black", lw=0.8)
            ax.set_yscale("log")  # the tie spike at 1.0 would hide the tails
        ax.set_xlabel(xlabel)
        ax.set_ylabel("DAGs")
        ax.set_title(title, fontsize=10)
        ax.legend(fontsize=8)
        fig.tight_layout()
        p = os.path.join(out_dir, fname)
        fig.savefig(p, dpi=120)
        plt.close(fig)
        paths.append(p)
    return paths


def run_study(
    n_dags: int = 4000,
    sizes=(20, 250),
    classes=CLASSES,
    n_cpus_range=(2, 5),
    seed: int = 0,
    out_dir=None,
    *,
    workers=None,
    comm_range=COMM_RANGE,
    plots: bool = True,
    progress: bool = True,
) -> dict:
    """Run the study and write its results to ``out_dir`` (see the module docstring).

    Parameters
    ----------
    n_dags : int
        Number of DAGs; classes alternate, the rest is drawn at random from the sets.
    sizes : (int, int)
        Task count range (inclusive).
    classes : sequence of {"tree", "linear"}
    n_cpus_range : (int, int)
        CPU worker count range (inclusive), beside one GPU.
    seed : int
        Makes the whole study reproducible.
    out_dir : str or path, optional
        Created if missing; ``None`` (the default) writes nothing.
    workers : int, optional
        Worker processes (default: the CPU count, at most 8); 1 runs in this process.
    comm_range : (float, float)
        Host-device transfer time range per edge.
    plots : bool
        Draw the PNGs (needs matplotlib).
    progress : bool
        Show a tqdm progress bar.

    Returns
    -------
    dict
        ``{"meta": ..., "summary": ..., "records": [...]}``.
    """
    n_dags = check_int(n_dags, "n_dags", min_value=1)
    lo, hi = (check_int(s, "sizes", min_value=2) for s in sizes)
    if hi < lo:
        raise WarpvxValueError(f"sizes: expected (low, high) with low <= high, got {sizes!r}")
    classes = tuple(classes)
    bad = [c for c in classes if c not in CLASSES]
    if not classes or bad:
        raise WarpvxValueError(f"classes: expected a non-empty subset of {CLASSES}, got {classes!r}")
    c_lo, c_hi = (check_int(c, "n_cpus_range", min_value=1) for c in n_cpus_range)
    if c_hi < c_lo:
        raise WarpvxValueError(f"n_cpus_range: expected (low, high) with low <= high, got {n_cpus_range!r}")
    if workers is None:
        workers = min(os.cpu_count() or 1, 8)
    workers = check_int(workers, "workers", min_value=1)
    jobs = make_jobs(n_dags, (lo, hi), classes, (c_lo, c_hi), seed, comm_range)
    from tqdm import tqdm

    t0 = time.perf_counter()
    records = []
    with tqdm(total=n_dags, desc="sched-study", unit="dag", disable=not progress) as bar:
        if workers == 1:
            for job in jobs:
                records.append(evaluate_dag(job))
                bar.update()
        else:
            with multiprocessing.get_context().Pool(workers) as pool:
                for rec in pool.imap(evaluate_dag, jobs, chunksize=8):
                    records.append(rec)
                    bar.update()
    seconds = time.perf_counter() - t0
    meta = {
        "n_dags": n_dags, "sizes": [lo, hi], "classes": list(classes), "n_cpus_range": [c_lo, c_hi],
        "seed": seed, "comm_range": list(comm_range), "workers": workers, "seconds": seconds,
        "sets": {"p_single": P_SINGLE, "p_cpu_only": P_CPU_ONLY, "cpu_range": CPU_RANGES,
                 "gpu_speedup": GPU_SPEEDUPS},
    }
    summary = summarize(records)
    if out_dir is not None:
        out_dir = os.fspath(out_dir)
        os.makedirs(out_dir, exist_ok=True)
        with open(os.path.join(out_dir, "per_dag.csv"), "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=FIELDS)
            writer.writeheader()
            for r in records:
                writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        with open(os.path.join(out_dir, "summary.json"), "w") as f:
            json.dump(_json_safe({"meta": meta, "summary": summary}), f, indent=2)
        with open(os.path.join(out_dir, "summary.md"), "w") as f:
            f.write(summary_markdown(summary, meta))
        if plots:
            plot_study(records, out_dir)
    return {"meta": meta, "summary": summary, "records": records}


def main(argv=None) -> int:
    """Command line: ``warpvx sched-study [--n-dags N] [--sizes 20-250] ...``; bad arguments
    exit with status 2 and a one-line message."""
    from ..cli import ArgumentParser, comma_list, fresh_results_dir, positive_int, value_range

    ap = ArgumentParser(
        prog="warpvx sched-study",
        description="Schedule thousands of random CPU/GPU DAGs with baseline, HEFT, XEFT and best; "
        "write per-DAG CSV, summary (markdown + JSON) and plots (thesis Fig. 5.4-5.5).",
    )
    ap.add_argument("--n-dags", type=positive_int, default=4000, help="number of DAGs")
    ap.add_argument("--sizes", type=value_range(int, 2), default=(20, 250), metavar="LOW-HIGH",
                    help="task count range (default: 20-250)")
    ap.add_argument("--classes", type=comma_list(choices=CLASSES), default=list(CLASSES),
                    metavar="NAMES", help=f"comma-separated DAG classes from {', '.join(CLASSES)} "
                    f"(default: {','.join(CLASSES)})")
    ap.add_argument("--cpus", type=value_range(int, 1), default=(2, 5), metavar="LOW-HIGH",
                    help="CPU worker range beside the GPU (default: 2-5)")
    ap.add_argument("--comm", type=value_range(float, 0.0), default=COMM_RANGE, metavar="LOW-HIGH",
                    help="per-edge transfer time range (default: 0-10)")
    ap.add_argument("--seed", type=int, default=0, help="random seed")
    ap.add_argument("--out", default=None,
                    help="output folder, e.g. benchmarks/results/sched_study to replace the recorded "
                         "study (default: a new ./warpvx-results/sched-study-<YYYYmmdd-HHMMSS>/)")
    ap.add_argument("--workers", type=positive_int, default=None,
                    help="processes (default: the CPU count, at most 8)")
    ap.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    out = args.out if args.out is not None else fresh_results_dir("sched-study")
    result = run_study(
        args.n_dags, args.sizes, args.classes, args.cpus, args.seed, out, workers=args.workers,
        comm_range=args.comm, plots=not args.no_plots, progress=not args.quiet,
    )
    print(summary_markdown(result["summary"], result["meta"]))
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
