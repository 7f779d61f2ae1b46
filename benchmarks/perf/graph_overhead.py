"""Executor overhead per node on the GPU machine, before/after and copy variants, in one call.

Each variant runs in a fresh process with the working tree's package: ``after`` as committed,
``after_pinned_small_uploads`` with small uploads through pinned staging too. (The ``before``
column of benchmarks/results/graph/overhead.md came from a copy of the earlier executor; to
compare with a baseline commit again, run this script from a checkout of it.) Prints a table and writes
``$OUT/overhead_variants.{md,json}``.

    python3 benchmarks/perf/graph_overhead.py            # driver
    python3 benchmarks/perf/graph_overhead.py --variant after   # one variant, JSON line
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

VARIANTS = ("after", "after_pinned_small_uploads")


def one(variant: str, frames: int) -> dict:
    import numpy as np

    from warpvx.graph.diagnostics import executor_overhead
    from warpvx.runtime import Transfers, executor

    if variant == "after_pinned_small_uploads":
        Transfers.PINNED_MIN_BYTES = 1
    sys.setswitchinterval(5e-5)  # as the full benchmark chose on the H200
    gpu = "cuda"
    out = {"variant": variant, "executor": executor.__file__}
    # Correctness of the mixed chain when pipelined, with distinct inputs per frame.
    from warpvx.graph.diagnostics import _chain

    g = _chain(20, "mixed")
    g.schedule("heft", n_cpus=1, gpu=gpu)
    xs = [np.arange(4, dtype=np.float32) + 10 * i for i in range(30)]
    bad = sum(not np.array_equal(o["y"], x) for x, o in zip(xs, g.stream(({"x": x} for x in xs), depth=3)))
    g.close()
    out["wrong_frames"] = bad
    runs = [("cpu", 100, frames * 2, None), ("gpu", 100, frames * 2, None),
            ("mixed", 50, frames, 0.0), ("mixed", 50, frames, 3e-5)]
    for chain, n, f, spin in runs:
        r = executor_overhead(n, f, chain=chain, gpu=gpu, spin=spin)
        out[f"{chain}{'' if spin is None else f'_spin{spin * 1e6:g}'}"] = {
            k: r[k] for k in ("per_node_us", "per_node_us_stream", "frame_us", "breakdown") if k in r}
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--variant", choices=VARIANTS)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--variants", default=",".join(VARIANTS))
    args = p.parse_args()
    if args.variant:
        print("RESULT " + json.dumps(one(args.variant, args.frames)), flush=True)
        return
    results = []
    for v in args.variants.split(","):
        env = dict(os.environ)
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, __file__, "--variant", v, "--frames", str(args.frames)],
                             env=env, capture_output=True, text=True, timeout=75)
        line = [ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")]
        if res.returncode or not line:
            print(f"{v}: FAILED rc={res.returncode}\n{res.stdout[-1500:]}\n{res.stderr[-3000:]}", flush=True)
            continue
        r = json.loads(line[0][7:])
        r["seconds"] = time.perf_counter() - t0
        results.append(r)
        print(f"{v}: {time.perf_counter() - t0:.1f} s, executor {r['executor']}", flush=True)
    rows = ["| variant | CPU-only | GPU-only | mixed spin 0 | mixed spin 30 us | mixed stream | wrong frames |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in results:
        rows.append(f"| {r['variant']} | {r['cpu']['per_node_us']:.1f} | {r['gpu']['per_node_us']:.1f} | "
                    f"{r['mixed_spin0']['per_node_us']:.1f} | {r['mixed_spin30']['per_node_us']:.1f} | "
                    f"{r['mixed_spin0']['per_node_us_stream']:.1f} | {r['wrong_frames']} |")
    rows += ["", "Breakdowns (us, medians):", ""]
    for r in results:
        for k in ("gpu", "mixed_spin0", "mixed_spin30"):
            b = r[k].get("breakdown") or {}
            rows.append(f"- {r['variant']} {k}: " + ", ".join(
                f"{n} {v:.1f}" for n, v in b.items() if v is not None))
    text = "\n".join(rows)
    print(text)
    out = Path(os.environ.get("OUT", "/tmp"))
    (out / "overhead_variants.md").write_text(text + "\n")
    (out / "overhead_variants.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
