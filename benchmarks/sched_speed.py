"""Time HEFT + XEFT on 250-node DAGs with 5 CPUs + 1 GPU (SPEC §9 target: under 20 ms).

Usage::

    python benchmarks/sched_speed.py [--dags 20] [--nodes 250] [--cpus 5] [--repeats 30]
                                     [--out benchmarks/results/sched_study/sched_speed.json]

Generates ``--dags`` random DAGs (half *tree*, half *linear*, default generator parameters but
P(single implementation) 0.5), then times ``heft(dag)`` followed by ``xeft(dag)`` (each call
validates and flattens the networkx graph itself, as a user's call would) ``--repeats`` times per
DAG after one warm-up, and reports medians; ``best(dag)`` (both, sharing the ranking) is timed
too. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

from warpvx.sched import best, heft, random_dag, xeft

TARGET_MS = 20.0


def time_calls(fn, repeats):
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dags", type=int, default=20)
    ap.add_argument("--nodes", type=int, default=250)
    ap.add_argument("--cpus", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=os.path.join("benchmarks", "results", "sched_study", "sched_speed.json"))
    args = ap.parse_args(argv)

    both, h_only, x_only, b_only, rows = [], [], [], [], []
    for i in range(args.dags):
        kind = ("tree", "linear")[i % 2]
        dag = random_dag(args.nodes, kind, n_cpus=args.cpus, seed=args.seed + i)
        heft(dag), xeft(dag)  # warm-up
        hx = time_calls(lambda: (heft(dag), xeft(dag)), args.repeats)
        h = time_calls(lambda: heft(dag), args.repeats)
        x = time_calls(lambda: xeft(dag), args.repeats)
        b = time_calls(lambda: best(dag), args.repeats)
        both += hx
        h_only += h
        x_only += x
        b_only += b
        rows.append({"dag": i, "class": kind, "edges": dag.number_of_edges(),
                     "heft_xeft_ms": statistics.median(hx), "heft_ms": statistics.median(h),
                     "xeft_ms": statistics.median(x), "best_ms": statistics.median(b)})

    def q(vals, p):
        vals = sorted(vals)
        return vals[min(len(vals) - 1, int(p * len(vals)))]

    result = {
        "what": f"heft(dag) + xeft(dag), {args.nodes} tasks, {args.cpus} CPUs + 1 GPU",
        "target_ms": TARGET_MS,
        "median_ms": statistics.median(both),
        "p90_ms": q(both, 0.9),
        "max_dag_median_ms": max(r["heft_xeft_ms"] for r in rows),
        "heft_median_ms": statistics.median(h_only),
        "xeft_median_ms": statistics.median(x_only),
        "best_median_ms": statistics.median(b_only),
        "samples": len(both),
        "meets_target": statistics.median(both) < TARGET_MS,
        "python": sys.version.split()[0],
        "machine": f"{platform.machine()} {platform.processor() or ''} ({os.cpu_count()} cores)".strip(),
        "per_dag": rows,
    }
    print(f"{'dag':>4} {'class':>7} {'edges':>6} {'heft+xeft':>10} {'heft':>7} {'xeft':>7} {'best':>7}  (ms)")
    for r in rows:
        print(f"{r['dag']:>4} {r['class']:>7} {r['edges']:>6} {r['heft_xeft_ms']:>10.2f} "
              f"{r['heft_ms']:>7.2f} {r['xeft_ms']:>7.2f} {r['best_ms']:>7.2f}")
    verdict = "met" if result["meets_target"] else "NOT met"
    print(f"heft+xeft: median {result['median_ms']:.2f} ms, p90 {result['p90_ms']:.2f} ms over "
          f"{len(both)} runs (target < {TARGET_MS:.0f} ms: {verdict}); "
          f"best(): median {result['best_median_ms']:.2f} ms")
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=2)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
