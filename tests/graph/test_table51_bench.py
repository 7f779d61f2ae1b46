"""The Table 5.1 script runs (smoke test on Warp's CPU device, one small cell group)."""

from __future__ import annotations

import importlib.util
import json
import math
import os

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
                       "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "table51.json").read_text())["rows"]
    measured = [r for r in rows if r["n_cpus"] == 2]
    assert [r["policy"] for r in measured] == list(bench.POLICIES)
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


def test_table51_rejects_too_few_stream_frames(tmp_path):
    with pytest.raises(SystemExit):
        _load().main(["--fit-frames", "3", "--frames", "3", "--stream-frames", "5",
                      "--out", str(tmp_path)])
