"""Calibration: measured costs, the per-machine cache (reuse, recalibrate), the transfer
model, and the task DAG built from them."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest

import warpvx
from warpvx.graph import calibration as cal_mod
from warpvx.graph.calibration import TransferModel, _fit, cache_file

pytestmark = pytest.mark.timeout(60)


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("WARPVX_CACHE_DIR", str(tmp_path / "c"))
    return tmp_path / "c" / "calibration.json"


def _graph(frame):
    g = warpvx.Graph("cal")
    f = g.input("frame", shape=frame.shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray")
    g.gaussian_pyramid(gray, levels=2, name="pyr")
    g.output("h", g.user(lambda im: np.histogram(im, 16)[0], [gray], name="hist"))
    return g


def test_cache_is_written_reused_and_recalibrated(fresh_cache, frames):
    assert cache_file() == fresh_cache
    g = _graph(frames[0])
    c1 = g.calibrate(gpu="warp-cpu", repeats=2, warmup=1)
    assert sorted(c1.fresh) == ["gray", "hist", "pyr"]
    assert c1.nodes["hist"]["gpu"] is None  # CPU-only user node
    assert all(c1.nodes[n]["cpu"] > 0 for n in ("gray", "pyr", "hist"))
    assert c1.nodes["gray"]["gpu"] > 0
    data = json.loads(fresh_cache.read_text())
    machine = c1.machine
    assert machine.startswith(socket.gethostname() + "|") and "warp-cpu" in machine
    cpu_key = cal_mod.cpu_backend_key()
    assert set(data["machines"][machine]["nodes"]) == {cpu_key, "warp-cpu"}
    assert set(data["machines"][machine]["transfer"]["warp-cpu"]) == {
        "h2d_latency", "h2d_per_byte", "d2h_latency", "d2h_per_byte"}

    # Another graph of the same nodes and sizes: everything from the cache.
    c2 = _graph(frames[0]).calibrate(gpu="warp-cpu")
    assert c2.fresh == [] and c2.nodes == c1.nodes
    # recalibrate=True measures again.
    c3 = _graph(frames[0]).calibrate(gpu="warp-cpu", recalibrate=True, repeats=2, warmup=1)
    assert sorted(c3.fresh) == ["gray", "hist", "pyr"]
    # Other sizes are other entries.
    small = np.ascontiguousarray(frames[0][:48, :64])
    c4 = _graph(small).calibrate(gpu="warp-cpu", repeats=2, warmup=1)
    assert sorted(c4.fresh) == ["gray", "hist", "pyr"]
    entries = json.loads(fresh_cache.read_text())["machines"][machine]["nodes"][cpu_key]
    assert sum(k.startswith("color_convert|") for k in entries) == 2


def test_corrupt_cache_is_ignored(fresh_cache, frames):
    fresh_cache.parent.mkdir(parents=True)
    fresh_cache.write_text("{not json")
    c = _graph(frames[0]).calibrate(gpu=False, repeats=1, warmup=0)
    assert c.gpu is None and c.nodes["gray"]["gpu"] is None
    assert json.loads(fresh_cache.read_text())["version"] == cal_mod.CACHE_VERSION


def test_transfer_fit_recovers_latency_and_bandwidth():
    sizes = [1 << 12, 1 << 16, 1 << 20, 1 << 22]
    a, b = 0.02, 1e-6  # 20 us + 1 GB/s
    fa, fb = _fit(sizes, [a + b * n for n in sizes])
    assert fa == pytest.approx(a, rel=1e-6) and fb == pytest.approx(b, rel=1e-6)
    assert _fit(sizes, [0.5, 0.4, 0.3, 0.2])[1] == 0.0  # never a negative bandwidth
    m = TransferModel(0.01, 1e-6, 0.03, 2e-6)
    assert m.time(1000) == pytest.approx(0.5 * (0.011 + 0.032))
    assert m.bandwidth_gbps == pytest.approx((1.0, 0.5))


def test_measured_transfer_is_sane():
    m = cal_mod.measure_transfer(warpvx.backend.resolve_backend("warp-cpu"), sizes=[1 << 10, 1 << 20],
                                 repeats=3)
    assert m.h2d_latency >= 0 and m.h2d_per_byte >= 0 and m.d2h_per_byte >= 0
    assert m.upload(1 << 20) > 0


def test_task_dag_from_calibration(fresh_cache, frames):
    g = _graph(frames[0])
    g.node("pyr").target = "cpu"
    dag = g.to_task_dag(3, gpu="warp-cpu")
    c = g._calibrations["warp-cpu"]
    assert dag.graph["processors"] == ["cpu0", "cpu1", "cpu2", "gpu"]
    assert set(dag.nodes["gray"]["cost"]) == {"cpu0", "cpu1", "cpu2", "gpu"}
    assert set(dag.nodes["pyr"]["cost"]) == {"cpu0", "cpu1", "cpu2"}  # pinned
    assert set(dag.nodes["hist"]["cost"]) == {"cpu0", "cpu1", "cpu2"}  # exclusive
    assert dag.nodes["pyr"]["cost"]["cpu1"] == c.nodes["pyr"]["cpu"]
    # The GPU pays the upload of the input frame; an edge pays the gray image's transfer.
    frame_bytes = frames[0].nbytes
    assert dag.nodes["gray"]["cost"]["gpu"] == pytest.approx(
        c.nodes["gray"]["gpu"] + c.transfer.upload(frame_bytes))
    gray_bytes = frame_bytes // 3
    assert dag.edges["gray", "pyr"]["comm"] == pytest.approx(c.transfer.time(gray_bytes))
    assert dag.edges["gray", "hist"]["comm"] == pytest.approx(c.transfer.time(gray_bytes))
