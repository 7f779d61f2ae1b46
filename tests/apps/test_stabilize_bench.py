"""The GPU speed script runs (smoke test on Warp's CPU device, a few frames)."""

from __future__ import annotations

import importlib.util
import json
import os

import pytest

from tests.apps.conftest import CLIP

SCRIPT = os.path.join(os.path.dirname(CLIP), "..", "..", "benchmarks", "stabilize_bench.py")


@pytest.mark.slow
def test_stabilize_bench_smoke(tmp_path):
    pytest.importorskip("matplotlib")
    spec = importlib.util.spec_from_file_location("stabilize_bench", SCRIPT)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    assert bench.main(["--backend", "warp-cpu", "--frames", "3", "--device-frames", "4",
                       "--seconds", "5", "--depth", "2", "--sizes", "160x120",
                       "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "stabilize_bench.json").read_text())
    (row,) = report["rows"]
    assert row["graph"]["frames"] == 3 and row["model_fps"] > 0 and row["graph_fps"] > 0
    assert row["graph"]["placement"]["ransac"] == "gpu"  # find_homography on the Warp device
    assert row["device"]["frames"] == 4 and row["device_fps"] > 0  # the device engine's row
    parts = row["device"]["breakdown_ms"]  # device time of a frame's program vs host calls
    assert parts["device: one frame's program"] > 0 and parts["host: submit"] > 0
    md = (tmp_path / "stabilize_bench.md").read_text()
    assert "| 160x120 |" in md and "where a frame's time goes" in md
    assert (tmp_path / "gantt_160x120.png").stat().st_size > 0
