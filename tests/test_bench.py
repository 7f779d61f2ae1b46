"""The benchmark harness (warpvx bench): it runs, writes JSON with positive timings, skips
what is missing, and times batches sensibly. No timing assertions (this machine is shared)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from warpvx import bench, cli
from warpvx.registry import REGISTRY, register


def test_quick_run_writes_json(tmp_path):
    rc = cli.main(["bench", "--quick", "--primitives", "gaussian_pyramid", "--sizes", "320x240",
                   "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    files = list(tmp_path.glob("bench-*.json"))
    assert len(files) == 1
    data = json.loads(files[0].read_text())
    assert data["sizes"] == ["320x240"]
    assert data["machine"]["cpu_cores"] >= 1 and data["machine"]["versions"]["opencv"]
    rows = data["results"]
    impls = {r["impl"] for r in rows}
    assert {"opencv", "cpu"} <= impls
    assert all(r["primitive"] == "gaussian_pyramid" and r["size"] == "320x240" for r in rows)
    assert all(r["per_call_s"] > 0 and r["calls_per_batch"] >= 1 for r in rows)
    assert all(r["speedup_vs_opencv"] > 0 for r in rows)
    opencv = [r for r in rows if r["impl"] == "opencv"]
    assert all(r["speedup_vs_opencv"] == 1.0 for r in opencv)


def test_quick_run_plot(tmp_path):
    pytest.importorskip("matplotlib")
    rc = cli.main(["bench", "--quick", "--primitives", "gaussian_blur", "--sizes", "160x120,96x64",
                   "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    png = list(tmp_path.glob("bench-*.png"))
    assert len(png) == 1 and png[0].stat().st_size > 1000


def test_graph_timing_on_warp_cpu(tmp_path):
    """--graph replays a captured Warp graph (CPU graphs here) and reports the bandwidth floor."""
    rc = cli.main(["bench", "--quick", "--primitives", "scale_pyramid", "--sizes", "96x64",
                   "--backends", "warp-cpu", "--graph", "--out", str(tmp_path), "--no-progress",
                   "--no-plot"])
    assert rc == 0
    data = json.loads(next(tmp_path.glob("bench-*.json")).read_text())
    assert data["copy_bandwidth_gbps"]["cpu"] > 0
    row = next(r for r in data["results"] if r["impl"] == "warp-cpu")
    assert row["graph_per_call_s"] > 0 and row["floor_s"] > 0 and row["graph_over_floor"] > 0


def test_missing_bench_module_is_skipped_with_a_note(tmp_path, capsys):
    register("bench_probe_missing", public="warpvx.nowhere:probe", cpu="warpvx.nowhere:probe",
             bench="warpvx.nowhere_at_all:bench_cases_probe")
    try:
        rc = cli.main(["bench", "--quick", "--primitives", "bench_probe_missing", "--sizes", "32x24",
                       "--out", str(tmp_path), "--no-progress", "--no-plot"])
    finally:
        REGISTRY.pop("bench_probe_missing", None)
    assert rc == 0
    out = capsys.readouterr().out
    assert "bench_probe_missing: skipped" in out


def test_unknown_primitive_is_an_error(tmp_path, capsys):
    rc = cli.main(["bench", "--primitives", "no_such_thing", "--out", str(tmp_path)])
    assert rc == 2
    assert "no_such_thing" in capsys.readouterr().err


def test_bad_size_is_an_error(tmp_path, capsys):
    assert cli.main(["bench", "--sizes", "big", "--out", str(tmp_path)]) == 2
    assert "--sizes" in capsys.readouterr().err


def test_time_per_call_s_batches():
    calls = []
    per_call, batch = bench.time_per_call_s(lambda: calls.append(1), settings=bench.Settings.quick())
    assert per_call > 0 and batch >= 1
    # warm-up + sizing call + repeat batches
    assert len(calls) == 1 + 1 + 3 * batch


def test_bundled_photo_when_scikit_image_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "skimage", None)  # import skimage -> ImportError
    img = bench.load_photo()
    assert img.shape == (448, 448, 3) and img.dtype == np.uint8
    assert img.std() > 20  # a real photo, not a blank


def test_photo_at_sizes():
    img = bench.photo_at(bench.load_photo(), (1241, 376))
    assert img.shape == (376, 1241, 3) and img.flags.c_contiguous
