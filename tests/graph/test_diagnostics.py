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
    assert [r["policy"] for r in report["policies"]] == ["baseline", "heft", "xeft", "best"]
    for policy in ("baseline", "heft", "xeft", "best"):
        assert (tmp_path / f"gantt_{policy}.png").stat().st_size > 0
        assert (tmp_path / f"gantt_{policy}_pipelined.png").stat().st_size > 0
    saved = json.loads((tmp_path / "graph_bench.json").read_text())
    assert saved["soak"]["frames"] == 6
    assert "| best" in (tmp_path / "graph_bench.md").read_text()
