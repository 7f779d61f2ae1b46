"""Executor overhead (a measurement, not a timed assertion), the soak run, and the GPU-machine
benchmark script in its --quick form."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

import warpvx
from warpvx.graph.diagnostics import executor_overhead, host_rss_bytes, soak

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("mixed", [False, True], ids=["cpu", "cpu+gpu"])
def test_executor_overhead_reports_per_node_time(mixed):
    r = executor_overhead(20, 5, mixed=mixed, gpu="warp-cpu")
    assert r["n_nodes"] == 20 and r["mixed"] is mixed
    for key in ("frame_us", "per_node_us", "per_node_us_stream"):
        assert math.isfinite(r[key]) and r[key] >= 0
    # Values, not only finiteness: a frame of 20 nodes costs something per node, the overhead
    # (frame time less the bare calls) fits inside the frame, and a frame of 20 identity nodes
    # on 4 floats takes well under a second on any machine.
    assert 0 < r["per_node_us"] * r["n_nodes"] <= r["frame_us"] < 1e6
    assert 0 < r["per_node_us_stream"] * r["n_nodes"] < 1e6
    if mixed:
        assert set(r["breakdown"]) == {"gpu_task", "cpu_task", "cpu_to_gpu", "gpu_to_cpu"}
        assert all(0 <= v < r["frame_us"] for v in r["breakdown"].values())
    print(f"\nexecutor overhead ({'mixed' if mixed else 'cpu'}): {r['per_node_us']:.1f} us/node")


def test_soak_reports_memory_at_start_and_end(frames):
    g = warpvx.Graph("soak")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", target="gpu")
    g.output("kps", g.fast_corners(gray, threshold=20))
    g.schedule("best", n_cpus=2, gpu="warp-cpu")
    r = soak(g, lambda i: {"frame": frames[i % len(frames)]}, 40, depth=3, report_every=20)
    assert r["frames"] == 40 and r["fps"] > 0
    assert r["rss_start_mb"] > 0 and r["rss_end_mb"] > 0
    assert r["gpu_mem_start_mb"] is None  # no CUDA here
    assert [s[0] for s in r["samples"]] == [20, 40]
    assert host_rss_bytes() > 0
    g.close()


def test_graph_bench_quick_runs(tmp_path):
    spec = importlib.util.spec_from_file_location("graph_bench", ROOT / "benchmarks" / "graph_bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    g = bench.build_graph((96, 72), max_corners=50)
    assert len(g.nodes) >= 12
    kinds = {n.kind for n in g.nodes.values()}
    assert {"color_convert", "gaussian_pyramid", "fast_corners", "optical_flow_pyr_lk", "user"} <= kinds
    report = bench.main(["--quick", "--frames", "3", "--size", "96x72", "--out", str(tmp_path),
                         "--overhead-nodes", "10", "--soak", "6"])
    policies = ["baseline", "heft", "xeft", "best"]
    assert [(r["policy"], r["costs"]) for r in report["policies"]] == \
        [(p, "calibrated") for p in policies] + [(p, "history") for p in policies]
    for policy in policies:
        assert (tmp_path / f"gantt_{policy}.png").stat().st_size > 0
        assert (tmp_path / f"gantt_{policy}_calibrated.png").stat().st_size > 0
        assert (tmp_path / f"gantt_{policy}_pipelined.png").stat().st_size > 0
    saved = json.loads((tmp_path / "graph_bench.json").read_text())
    assert saved["soak"]["frames"] == 6
    # Per-node diagnosis: each node's cost alone and in the running frames, on its processor.
    row = saved["policies"][1]
    assert set(row["nodes"]) == set(g.nodes)
    assert all(t["measured_ms"] >= 0 and t["calibrated_ms"] > 0 for t in row["nodes"].values())
    # The history pass scheduled with what the first pass measured.
    assert saved["history"] and set(saved["history"]) <= set(g.nodes)
    assert saved["switch_interval"]["chosen"] in [float(k) for k in saved["switch_interval"]["switch"]]
    assert saved["switch_interval"]["spin_chosen"] in (0.0, 3e-5)
    assert all(1 <= r["rounds"] <= 3 for r in saved["policies"])
    mixed = [o for o in saved["overhead"] if o["mixed"]]
    assert mixed and all(set(o["breakdown"]) == {"gpu_task", "cpu_task", "cpu_to_gpu", "gpu_to_cpu"}
                         for o in mixed)
    md = (tmp_path / "graph_bench.md").read_text()
    assert "| best" in md and "history" in md
    # The replay: the model with the measured costs, per run, and as a mode of its own.
    assert all(r["replayed_ms"] > 0 for r in saved["policies"])
    assert bench.main(["--replay", str(tmp_path / "graph_bench.json")]) is None
    replay = (tmp_path / "replay.md").read_text()
    assert replay.count("| heft |") == 2 and "replayed ms" in replay


def test_replay_charges_measured_costs_and_copies_to_the_nodes():
    spec = importlib.util.spec_from_file_location("graph_bench", ROOT / "benchmarks" / "graph_bench.py")
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    row = {"nodes": {
        "a": {"pe": "cpu0", "measured_ms": 1.0, "transfer_ms": 0.0, "host_ms": None},
        # GPU: the host call (0.9 ms, 0.2 of it copies) outlasts the device interval (0.5 ms).
        "b": {"pe": "gpu", "measured_ms": 0.5, "transfer_ms": 0.2, "host_ms": 0.9},
        "c": {"pe": "cpu1", "measured_ms": 0.3, "transfer_ms": 0.05, "host_ms": None},
    }}
    d = {"cpu_gap": 0.001, "gpu_gap": 0.002, "handoff": 0.01}
    got = bench.replay_ms(row, [("a", "b"), ("b", "c")], d, 2)
    want = (1.0 + 0.001) + 0.01 + (0.7 + 0.2 + 0.002) + 0.01 + (0.3 + 0.05 + 0.001)
    assert got == pytest.approx(want)
