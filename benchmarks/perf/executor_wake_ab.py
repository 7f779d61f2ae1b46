"""A/B in one process on the GPU machine: ``Graph.process`` submitting its frame without waking
the executor's role threads (the caller runs the lone frame; the default since session 4)
against the old wake-at-submit, on the identity chains of
:func:`warpvx.graph.diagnostics.executor_overhead` (gpu per-task timing, gpu bursts, mixed,
cpu), in 5 interleaved rounds; prints per variant the median us/node over the rounds and the
frame's head/tail (us).

    PYTHONPATH=. python3 benchmarks/perf/executor_wake_ab.py
"""
import os, sys, statistics as st
sys.path.insert(0, os.getcwd())
from warpvx.graph.diagnostics import executor_overhead
from warpvx.runtime.executor import Executor
orig = Executor.submit
def forced(self, *a, wake=True, **k):
    return orig(self, *a, wake=True, **k)
res = {}
executor_overhead(64, 20, chain="gpu", gpu="cuda")
executor_overhead(32, 20, chain="mixed", gpu="cuda")
for r in range(5):
    for variant in ("nowake", "wake"):
        Executor.submit = orig if variant == "nowake" else forced
        for chain, n, timing in (("gpu", 64, None), ("gpu", 64, "bursts"), ("mixed", 32, None), ("cpu", 64, None)):
            o = executor_overhead(n, 200, chain=chain, gpu="cuda", timing=timing)
            key = (variant, chain, timing)
            res.setdefault(key, []).append((o["per_node_us"], o["breakdown"].get("frame_head"), o["breakdown"].get("frame_tail")))
    print("round", r, flush=True)
for k, v in sorted(res.items(), key=lambda kv: (kv[0][1], str(kv[0][2]), kv[0][0])):
    print(k, "us/node median", round(st.median(x[0] for x in v), 2), "all", [round(x[0], 1) for x in v],
          "head", round(st.median(x[1] for x in v), 1), "tail", round(st.median(x[2] for x in v), 1))
