"""Calibration: measured costs, the per-machine cache (reuse, recalibrate), the transfer
model, and the task DAG built from them."""

from __future__ import annotations

import json
import math
import socket
import threading
import time

import cv2

import numpy as np
import pytest

import warpvx
from warpvx.graph import calibration as cal_mod
from warpvx.graph.calibration import TransferModel, _fit, cache_file

from .helpers import joined_pair

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
    written = fresh_cache.stat().st_mtime_ns
    c2 = _graph(frames[0]).calibrate(gpu="warp-cpu")
    assert c2.fresh == [] and c2.nodes == c1.nodes
    assert fresh_cache.stat().st_mtime_ns == written  # nothing measured: the file not rewritten
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
    d = c.dispatch
    assert set(d) >= {"cpu_node", "gpu_node", "cpu_gap", "gpu_gap", "handoff", "start"}
    assert d["cpu_node"] > 0 and d["gpu_node"] > 0 and d["handoff"] >= 0
    # A node costs its calibrated time plus the executor's dispatch cost on that processor.
    assert dag.nodes["pyr"]["cost"]["cpu1"] == pytest.approx(c.nodes["pyr"]["cpu"] + d["cpu_node"])
    # The GPU pays the upload of the input frame; an edge pays the gray image's transfer plus
    # the hand-off between a CPU worker and the GPU thread.
    frame_bytes = frames[0].nbytes
    assert dag.nodes["gray"]["cost"]["gpu"] == pytest.approx(
        c.nodes["gray"]["gpu"] + d["gpu_node"] + c.transfer.upload(frame_bytes))
    gray_bytes = frame_bytes // 3
    assert dag.edges["gray", "pyr"]["comm"] == pytest.approx(c.transfer.time(gray_bytes) + d["handoff"])
    assert dag.edges["gray", "hist"]["comm"] == pytest.approx(c.transfer.time(gray_bytes) + d["handoff"])


def test_dispatch_costs_are_measured_through_the_executor_and_cached(fresh_cache, frames):
    c = _graph(frames[0]).calibrate(gpu="warp-cpu", repeats=1, warmup=0)
    d = c.dispatch
    for key in ("cpu_node", "gpu_node", "cpu_gap", "gpu_gap", "handoff", "start"):
        assert math.isfinite(d[key]) and d[key] >= 0, key
    # A task costs more than nothing and far less than a millisecond-scale kernel would.
    assert 0 < d["cpu_node"] < 5 and 0 < d["gpu_node"] < 5
    assert d["cpu_gap"] <= d["cpu_node"] + 1e-9 and d["gpu_gap"] <= d["gpu_node"] + 1e-9
    cached = json.loads(fresh_cache.read_text())["machines"][c.machine]["executor"]["warp-cpu"]
    assert cached == pytest.approx(d)
    again = _graph(frames[0]).calibrate(gpu="warp-cpu")
    assert again.dispatch == pytest.approx(d)  # from the cache, not measured again
    assert cal_mod.measure_dispatch(None, n_nodes=4, frames=2)["gpu_node"] == 0.0


def test_learnt_history_drives_the_history_costs(fresh_cache, frames):
    g = _graph(frames[0])
    g.node("gray").target = "gpu"  # one node of each kind, and copies between them
    plan = g.schedule("heft", n_cpus=2, gpu="warp-cpu")
    runs = []
    for f in frames:
        g.process({"frame": f})
        runs.append(plan.last_run[-1])
    learnt = g.learn(runs=runs)
    assert set(learnt) == set(g.nodes)
    c = plan.calibration
    for node, proc in plan.placement.items():
        pe = "gpu" if proc == "gpu" else "cpu"
        if pe == "gpu":  # the GPU role is busy for the longer of the device and host times
            per_frame = [max(r.compute_ms(node), r.host[node][1] - r.host[node][0] - r.transfers.get(node, 0.0))
                         for r in runs[1:]]
        else:
            per_frame = [r.compute_ms(node) for r in runs[1:]]  # the first frame is skipped
        assert learnt[node][pe] == pytest.approx(np.median(per_frame))
        assert c.history[node][pe] == learnt[node][pe]
        assert c.history[node][f"{pe}_copies"] == pytest.approx(
            np.median([r.transfers.get(node, 0.0) for r in runs[1:]]))
        assert c.placement[node] == pe
    # Copies: measured over modelled time, per frame, the median.
    ratios = []
    for r in runs[1:]:
        measured = sum(r.transfers[t] for t in r.copied)
        modelled = sum(c.transfer.upload(b) if r.timeline[t].processor == "gpu" else c.transfer.download(b)
                       for t, b in r.copied.items())
        ratios.append(measured / modelled)
    assert c.transfer_scale == pytest.approx(np.median(ratios))
    hdag = g.to_task_dag(2, gpu="warp-cpu", costs="history")
    cdag = g.to_task_dag(2, gpu="warp-cpu")
    node, proc = "hist", plan.placement["hist"]
    # History: the node's measured time plus the copies it made where it ran (the executor
    # copies on the consumer's processor), plus the executor's cost between tasks.
    h = c.history[node]
    assert hdag.nodes[node]["cost"][proc] == pytest.approx(h["cpu"] + h["cpu_copies"] + c.dispatch["cpu_gap"])
    assert h["cpu_copies"] > 0  # hist downloads gray from the GPU
    assert cdag.nodes[node]["cost"][proc] == pytest.approx(c.nodes[node]["cpu"] + c.dispatch["cpu_node"])
    gray_bytes = frames[0].nbytes // 3
    assert hdag.edges["gray", "hist"]["comm"] == pytest.approx(c.dispatch["handoff"])  # copies: on nodes
    assert cdag.edges["gray", "hist"]["comm"] == pytest.approx(c.dispatch["handoff"] + c.transfer.time(gray_bytes))
    # Where a node has not run, history charges the copies its inputs would need given where
    # their producers ran, scaled as copies were in the frames: pyr on the GPU would upload gray
    # only if gray ran on the CPU; gray ran on the GPU, so pyr on the CPU downloads it.
    pyr_pe = c.placement["pyr"]
    other = "gpu" if pyr_pe == "cpu" else "cpu"
    want = c.nodes["pyr"][other] + c.dispatch[f"{other}_node"]
    if other == "cpu":
        want += c.transfer_scale * c.transfer.download(gray_bytes)
    got = hdag.nodes["pyr"]["cost"]["gpu" if other == "gpu" else "cpu0"]
    assert got == pytest.approx(want)
    assert g.schedule("heft", n_cpus=2, gpu="warp-cpu", costs="history").costs == "history"
    # The history is cached with the calibration: a new graph of the same nodes finds it.
    again = _graph(frames[0]).calibrate(gpu="warp-cpu")
    assert again.history == c.history and again.transfer_scale == pytest.approx(c.transfer_scale)
    with pytest.raises(warpvx.GraphError, match="costs"):
        g.to_task_dag(2, gpu="warp-cpu", costs="guess")
    with pytest.raises(warpvx.GraphError, match="learn: nothing measured"):
        _graph(frames[0]).learn()
    g.close()


def test_two_verification_frames_give_temporal_nodes_real_motion(fresh_cache, frames):
    from warpvx.graph.calibration import input_values

    g = warpvx.Graph("lk")
    f = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(f, code="BGR2GRAY", name="gray")
    pyr = g.gaussian_pyramid(gray, levels=2, name="pyr")
    pts = g.harris_corners(gray, max_corners=40, quality_level=0.01, min_distance=5, name="pts")
    prev_pyr, prev_pts = g.delay(pyr), g.delay(pts)
    g.output("next", g.optical_flow_pyr_lk(prev_pyr[-1], pyr, prev_pts[-1], max_level=1, name="lk")[0])
    g.verify([{"frame": frames[0]}, {"frame": frames[3]}])
    gray0 = cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY)
    gray3 = cv2.cvtColor(frames[3], cv2.COLOR_BGR2GRAY)
    prev, nxt, prev_points = input_values(g, g.node("lk"))
    np.testing.assert_array_equal(prev[0], gray0)  # delay[-1]: the first frame's pyramid
    np.testing.assert_array_equal(nxt[0], gray3)  # this frame's
    assert len(prev_points) > 0
    with pytest.raises(warpvx.GraphError, match="inputs"):
        g.verify([{"frame": frames[0]}] * 3)
    g.close()


def test_contention_probe_times_mixes_of_plausible_nodes(fresh_cache, frames):
    # The CPU mix holds the nodes a scheduler might put on a CPU worker (CPU-only ones and
    # those within PROBE_SPREAD of their GPU time); each pair says who was busy beside it.
    g = warpvx.Graph("probe")
    frame = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray")
    g.output("blur", g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="blur"))
    g.output("mean", g.user(lambda x: np.array([x.mean()]), [gray], "m", name="mean"))
    cal = g.calibrate({"frame": frames[0]}, gpu="warp-cpu", repeats=3)
    from warpvx.backend import resolve_backend

    probe = cal_mod.measure_contention(g, cal, resolve_backend("warp-cpu"), 2, repeats=3)
    assert set(probe) - {("cpu", "heavy")} == {("cpu", "cpu"), ("cpu", "gpu"), ("gpu", "cpu")}
    spread = cal_mod.PROBE_SPREAD
    want_cpu = sorted(n for n, t in cal.nodes.items()
                      if t["cpu"] and (not t["gpu"] or t["cpu"] <= spread * t["gpu"]))
    assert probe[("cpu", "cpu")][0].split(",") == want_cpu and "mean" in want_cpu
    assert probe[("gpu", "cpu")][0].split(",") == ["blur", "gray"]
    for (victim, loader), (_, alone, loaded, cpus, gpus) in probe.items():
        assert alone > 0 and loaded > 0
        assert (cpus, gpus) == ({"cpu": 1 if victim == "cpu" else 2, "gpu": 0, "heavy": 1}[loader],
                                1 if loader == "gpu" else 0)
    # One alone time per victim kind, shared by its pairs.
    assert probe[("cpu", "cpu")][1] == probe[("cpu", "gpu")][1]


def test_contention_probe_reads_a_drift_between_blocks_as_no_contention(fresh_cache, frames, monkeypatch):
    # Every timed block runs 1 + 0.5 per loader slower with loaders beside it; the machine
    # gets 1.7x slower for good after the first block (as frames of one placement did
    # between blocks on the H100). Alone and loaded in turn, the probe still reports the
    # true slowdown; timing alone once, then loaded, would report 2.55x for 1.5x.
    g = warpvx.Graph("probe")
    frame = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray")
    g.output("mean", g.user(lambda x: np.array([x.mean()]), [gray], "m", name="mean"))
    cal = g.calibrate({"frame": frames[0]}, gpu="warp-cpu", repeats=3)
    from warpvx.backend import resolve_backend

    blocks = []

    def drifting(call, scope, bodies, *, repeats, mean=False):
        blocks.append(len(bodies))
        return 2.0 * (1.0 if len(blocks) == 1 else 1.7) * (1.0 + 0.5 * len(bodies))

    monkeypatch.setattr(cal_mod, "_time_beside", drifting)
    probe = cal_mod.measure_contention(g, cal, resolve_backend("warp-cpu"), 2, repeats=3)
    assert blocks[:2] == [0, 1] and blocks[2:4] == [1, 0]  # A B, B A, ...
    for (_, _, alone, loaded, cpus, gpus) in ((k, *v) for k, v in probe.items()):
        assert loaded / alone == pytest.approx(1.0 + 0.5 * (cpus + gpus))


_BUS = {"users": 0}
_BUS_LOCK = threading.Lock()


def _bus_bound(x):
    # Stands for memory-bound work that releases the GIL (a long OpenCV call): 10 steps on
    # a shared resource (one "memory bus") that each take 0.5 ms per call using it at that
    # moment, so two at once take twice as long, whatever the GIL does.
    with _BUS_LOCK:
        _BUS["users"] += 1
    try:
        for _ in range(10):
            time.sleep(0.0005 * _BUS["users"])
    finally:
        with _BUS_LOCK:
            _BUS["users"] -= 1
    return x + 1


def test_contention_probe_times_heavy_cpu_nodes_side_by_side(fresh_cache):
    # Two heavy nodes that contend for a shared resource when run at once, one light one.
    # The heavy mix beside one worker looping it runs about 2x slower (one busy worker);
    # the model fitted with the probe expects the placement running them on two workers
    # to gain little, and without it, to halve the time.
    from warpvx.graph.model import fit, graph_reads
    from warpvx.runtime.timeline import FrameResult
    from warpvx.sched.schedule import Schedule, ScheduledTask

    g, frame = joined_pair("bus", _bus_bound, ("heavyA", "heavyB"))
    cal = g.calibrate(frame, gpu=None, repeats=3)
    probe = cal_mod.measure_contention(g, cal, None, 2, repeats=6)
    mix, alone, loaded, cpus, gpus = probe[("cpu", "heavy")]
    assert mix == "heavyA,heavyB" and (cpus, gpus) == (1, 0)
    # About 2x; less where the loaded machine's sleeps and the loader's gaps between calls
    # leave the victim alone part of the time.
    assert 1.3 < loaded / alone < 2.6
    # Frames of the serial placement (one worker): nothing in them shows the contention.
    serial = {"heavyA": ScheduledTask("heavyA", "cpu0", 0.0, 4.0),
              "heavyB": ScheduledTask("heavyB", "cpu0", 4.0, 8.0),
              "join": ScheduledTask("join", "cpu0", 8.0, 8.01)}
    runs = [FrameResult(i, {}, dict(serial), 0.0) for i in range(3)]
    placement = {t: s.processor for t, s in serial.items()}
    cal.nodes.update({"heavyA": {"cpu": 4.0, "gpu": None}, "heavyB": {"cpu": 4.0, "gpu": None},
                      "join": {"cpu": 0.01, "gpu": None}})
    split = Schedule({"heavyA": ScheduledTask("heavyA", "cpu0", 0, 4),
                      "heavyB": ScheduledTask("heavyB", "cpu1", 0, 4),
                      "join": ScheduledTask("join", "cpu0", 4, 4.01)}, ["cpu0", "cpu1"])
    reads = graph_reads(g)
    probed = fit(cal, reads, runs, placement, probe={("cpu", "heavy"): probe[("cpu", "heavy")]})
    blind = fit(cal, reads, runs, placement)
    assert blind.makespan(split) == pytest.approx(4.0, rel=0.05)
    assert probed.makespan(split) > 5.0
    g.close()


def test_learn_charges_each_frame_to_the_processor_that_ran_it(fresh_cache, frames):
    """Under a K-frame plan a node may run on a CPU worker in one frame and on the GPU in the
    next: each frame's time is learnt for the kind of processor its timeline names."""
    from warpvx.runtime.timeline import FrameResult
    from warpvx.sched.schedule import ScheduledTask

    g = _graph(frames[0])
    plan = g.schedule("heft", n_cpus=2, gpu="warp-cpu")
    times = {"cpu0": [3.0, 5.0, 4.0], "gpu": [1.0, 2.0, 1.5]}
    runs = []
    for i in range(3):
        for proc in ("cpu0", "gpu"):
            t = times[proc][i]
            runs.append(FrameResult(len(runs), {}, {"hist": ScheduledTask("hist", proc, 1.0, 1.0 + t)}, 0.0))
    learnt = cal_mod.learn(plan.calibration, runs, {"hist": "cpu0"}, skip=0)
    assert learnt["hist"] == pytest.approx({"cpu": 4.0, "gpu": 1.5})
    assert plan.calibration.history["hist"]["gpu"] == pytest.approx(1.5)
    assert plan.calibration.placement["hist"] == "cpu"  # the one-frame plan's kind


def _python_loop(x):
    s = 0
    for i in range(100_000):
        s += i
    return x + 1


def _sleep(x):
    import time

    time.sleep(0.003)  # releases the GIL for its whole duration
    return x + 1


def test_gil_shares_tell_python_from_gil_free_nodes(fresh_cache, monkeypatch):
    # A pure-Python node holds the GIL: beside a Python thread it runs about 2x slower
    # (sensitivity) and slows that thread down as much (pressure); a node that releases
    # the GIL for its whole call (a sleep, like a long OpenCV call) slows nobody.
    g = warpvx.Graph("gil")
    x = g.input("x", shape=(4,), dtype=np.float32)
    g.output("a", g.user(_python_loop, [x], name="python"))
    g.output("b", g.user(_sleep, [x], name="sleep"))
    g.verify({"x": np.zeros(4, np.float32)})
    cal = g.calibrate(gpu=False, repeats=3)
    monkeypatch.setattr(cal_mod, "GIL_PAIRS", 5)  # a steadier median on a loaded machine
    shares = cal_mod.measure_gil(g, cal, None, repeats=5)
    assert set(shares) == {"python", "sleep"} and all(set(v) == {"cpu"} for v in shares.values())
    assert all(0.0 <= v <= 1.0 for sp in shares.values() for v in sp["cpu"])
    # (Margins for a loaded 2-core machine; on a quiet one these are about 1, 1 and 0.)
    assert shares["python"]["cpu"][0] > 0.4
    assert shares["sleep"]["cpu"][1] < 0.5 and shares["python"]["cpu"][1] > shares["sleep"]["cpu"][1] + 0.15
