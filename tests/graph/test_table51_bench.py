"""The Table 5.1 script runs (smoke test on Warp's CPU device, one small cell group)."""

from __future__ import annotations

import importlib.util
import json
import math
import os
import tarfile

import pytest

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "benchmarks", "table51.py")


def _load():
    spec = importlib.util.spec_from_file_location("table51", SCRIPT)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    return bench


@pytest.mark.slow
def test_table51_model_columns(tmp_path):
    bench = _load()
    assert bench.main(["--gpu", "warp-cpu", "--cameras", "1", "--dl", "15", "--cpus", "2,3",
                       "--measure-cpus", "2", "--frames", "2", "--fit-frames", "2",
                       "--stream-frames", "4", "--width", "240", "--height", "96",
                       "--quadtree", "cpu,gpu", "--gantt", "1:15:2", "--period-frames", "3",
                       "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "table51.json").read_text())["rows"]
    for quadtree in ("cpu", "gpu"):
        assert [r["policy"] for r in rows if r["n_cpus"] == 2 and r["quadtree"] == quadtree] \
            == list(bench.POLICIES)
    measured = [r for r in rows if r["n_cpus"] == 2]
    for r in measured:
        assert r["predicted_period_ms"] > 0
        # K frames in flight are never slower per frame than one frame after another.
        assert r["predicted_period_ms"] <= r["predicted_ms"] * (1 + 1e-9)
    # The baseline puts every node with a Warp implementation on the GPU role: all but the
    # CPU-exclusive quadtrees (one per level: 8) with quadtree=cpu.
    base = {r["quadtree"]: r["gpu_nodes"] for r in measured if r["policy"] == "baseline"}
    assert base["gpu"] - base["cpu"] == 8
    for r in measured:
        for key in ("model_ms", "measured_ms", "predicted_ms"):
            assert math.isfinite(r[key]) and r[key] > 0, (r["policy"], key)
        assert r["model_error_pct"] == pytest.approx(
            100 * (r["model_ms"] - r["measured_ms"]) / r["measured_ms"])
        assert r["predicted_error_pct"] == pytest.approx(
            100 * (r["predicted_ms"] - r["measured_ms"]) / r["measured_ms"])
    # Unmeasured CPU counts are predicted only: no measured or model columns.
    assert all("model_ms" not in r and "measured_ms" not in r for r in rows if r["n_cpus"] == 3)
    md = (tmp_path / "table51.md").read_text()
    assert "| model ms | error |" in md
    assert "## Compared with the thesis" in md and "| Quadtree |" in md
    # Gantt charts of the --gantt cell, both quadtree settings, three policies, in one archive.
    with tarfile.open(tmp_path / "gantt.tgz") as tar:
        charts = sorted(n for n in tar.getnames() if n.endswith(".png"))
    assert len(charts) == 6 and "gantt/1cam-cpuqt-dl15-2cpu-xeft.png" in charts
    assert not (tmp_path / "gantt").exists()


def test_table51_rejects_too_few_stream_frames(tmp_path):
    with pytest.raises(SystemExit):
        _load().main(["--fit-frames", "3", "--frames", "3", "--stream-frames", "5",
                      "--out", str(tmp_path)])
