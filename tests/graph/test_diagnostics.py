"""Executor overhead (a measurement, not a timed assertion), the soak run, and the GPU-machine
benchmark script in its --quick form."""

from __future__ import annotations

import json
import math
import statistics
import tarfile

import numpy as np
import pytest

import warpvx
from warpvx.graph.diagnostics import executor_overhead, host_rss_bytes, soak

from tests.benchmark_scripts import load_bench

pytestmark = pytest.mark.timeout(300)  # a hang guard; the bench run takes ~15 s alone


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
    # Identity nodes are scheduled far shorter than Executor.INLINE_MAX_MS: all may run inline.
    assert r["inline_units"] == "20/20"
    ends = {"frame_head", "frame_tail"}
    assert set(r["breakdown"]) == ends | ({"gpu_task", "cpu_task", "cpu_to_gpu", "gpu_to_cpu"}
                                          if mixed else set())
    assert all(0 <= v < r["frame_us"] for v in r["breakdown"].values())
    # The frame's ends and its tasks' span fit in the frame (one median each: 2x slack).
    assert r["breakdown"]["frame_head"] + r["breakdown"]["frame_tail"] < 2 * r["frame_us"]
    print(f"\nexecutor overhead ({'mixed' if mixed else 'cpu'}): {r['per_node_us']:.1f} us/node")


def test_profile_overhead_sees_the_role_threads():
    from warpvx.graph.diagnostics import profile_overhead
    from warpvx.runtime.roles import RoleRunner

    loop = RoleRunner._role_loop
    text = profile_overhead(8, 5, chain="mixed", gpu="warp-cpu", top=400)
    # GPU and CPU tasks run on the executor's role threads only, never the caller's.
    assert "_run_gpu_task" in text and "_run_cpu_task" in text
    assert "Ordered by: internal time" in text and "Ordered by: cumulative time" in text
    assert RoleRunner._role_loop is loop  # the wrapper is gone


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
    bench = load_bench("graph_bench")
    g = bench.build_graph((96, 72), max_corners=50)
    assert len(g.nodes) == 16
    kinds = {n.kind for n in g.nodes.values()}
    assert {"color_convert", "gaussian_pyramid", "fast_corners", "optical_flow_pyr_lk", "user"} <= kinds
    heavy = bench.build_graph((96, 72), max_corners=50, cpu_heavy=True)
    assert len(heavy.nodes) == 21 and set(g.nodes) < set(heavy.nodes)
    report = bench.main(["--quick", "--frames", "6", "--fit-frames", "3", "--size", "96x72",
                         "--out", str(tmp_path), "--overhead-nodes", "10", "--soak", "6"])
    policies = ["baseline", "heft", "xeft", "best"]
    assert [e["tag"] for e in report["experiments"]] == ["two-cameras_96x72", "two-cameras-cv_96x72"]
    for e in report["experiments"]:
        assert [r["policy"] for r in e["policies"]] == policies
        for r in e["policies"]:
            for key in ("pred_in_ms", "pred_out_ms", "measured_in_ms", "measured_out_ms"):
                assert math.isfinite(r[key]) and r[key] > 0
            assert r["error_out_pct"] == pytest.approx(
                100 * (r["pred_out_ms"] - r["measured_out_ms"]) / r["measured_out_ms"])
        best = e["policies"][-1]
        # The model's candidates; a trial (when several were within its margin) kept the
        # measured fastest of them.
        assert best["pred_out_ms"] == pytest.approx(best["candidates"][best["chosen"]], rel=1e-6)
        trial = best["trial_ms"]
        if trial:
            assert best["chosen"] == min(trial, key=trial.get)
        else:
            assert best["chosen"] == e["model_pick"]
        assert e["fastest"] in policies
        assert len(best["fit_frames_data"]) == 3
        assert (tmp_path / f"gantt_{e['tag']}_best.png").stat().st_size > 0
    with tarfile.open(tmp_path / "gantt.tar") as tar:
        names = set(tar.getnames())
    for e in report["experiments"]:
        for policy in policies:
            assert f"gantt/gantt_{e['tag']}_{policy}.png" in names
            assert f"gantt/gantt_{e['tag']}_{policy}_pipelined.png" in names
    assert len(list(tmp_path.iterdir())) <= 8  # what comes back from the GPU machine
    saved = json.loads((tmp_path / "graph_bench.json").read_text())
    # Fit/predict split: in sample is frames 1-3, out of sample frames 4-6; refitting offline
    # on the training policy's recorded frames 1-3 alone gives the recorded out-of-sample
    # predictions of every policy, so the later frames never entered the model.
    rows = iter(bench.replay(saved))
    for e in saved["experiments"]:
        for r in e["policies"]:
            spans = r["makespans"]
            assert len(spans) == 6 and e["fit_frames"] == 3
            fit = spans[:3] if r["policy"] != e["train"] else \
                [max(t[2] for t in f.values()) for f in r["fit_frames_data"]]  # trained alone
            assert r["measured_in_ms"] == pytest.approx(statistics.median(fit))
            assert r["measured_out_ms"] == pytest.approx(statistics.median(spans[3:]))
            assert next(rows)["pred_ms"] == pytest.approx(r["pred_out_ms"], rel=1e-9)
    assert saved["soak"]["frames"] == 6
    row = saved["experiments"][0]["policies"][1]
    assert set(row["nodes"]) == set(g.nodes)
    assert all(t["measured_ms"] >= 0 and t["calibrated_ms"] > 0 for t in row["nodes"].values())
    assert saved["switch_interval"]["chosen"] in [float(k) for k in saved["switch_interval"]["switch"]]
    mixed = [o for o in saved["overhead"] if o["mixed"]]
    assert mixed and all(set(o["breakdown"]) == {"gpu_task", "cpu_task", "cpu_to_gpu", "gpu_to_cpu",
                                             "frame_head", "frame_tail"}
                         for o in mixed)
    md = (tmp_path / "graph_bench.md").read_text()
    assert "| best" in md and "out of sample" in md and "graph_bench.py --quick" in md


def test_gantt_labels_rows_names_and_error_on_warp_cpu(frames, tmp_path):
    # A mixed placement on Warp's CPU device: both rows name that GPU role "gpu (warp-cpu)",
    # every node is named on both charts (in its bar or in the numbered list under the
    # axis), time is in ms and the title gives the prediction's error.
    import matplotlib

    matplotlib.use("Agg")
    g = warpvx.Graph("gantt")
    frame = g.input("frame", shape=frames[0].shape, dtype=np.uint8)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray", target="gpu")
    blur = g.gaussian_blur(gray, ksize=(5, 5), sigma=1.2, name="blur", target="cpu")
    g.output("kps", g.fast_corners(blur, threshold=20, name="fast", target="gpu"))
    g.output("mean", g.user(lambda x: np.array([x.mean()]), [gray], "m", name="mean"))
    g.verify({"frame": frames[0]})
    plan = g.schedule("heft", n_cpus=1, gpu="warp-cpu")
    runs = []
    for f in frames:
        g.process({"frame": f})
        runs.append(plan.last_run[-1])
    plan.prediction = g.fit_model(plan, runs=runs[:2]).predict(plan)
    fig = plan.gantt(tmp_path / "gantt.png")
    assert (tmp_path / "gantt.png").stat().st_size > 0
    title = fig._suptitle.get_text()
    predicted, measured = plan.predicted_makespan, plan.measured_makespans()[-1]
    assert f"predicted {predicted:.3f} ms" in title
    assert f"{100 * (predicted - measured) / measured:+.1f}%" in title
    for ax in fig.axes[:2]:
        rows = [t.get_text() for t in ax.get_yticklabels()]
        assert "gpu (warp-cpu)" in rows and "gpu" not in rows and "cpu0" in rows
        assert ax.get_xlabel().startswith("time (ms)")
        shown = " ".join([t.get_text() for t in ax.texts] + [ax.get_xlabel()])
        for node in g.nodes:
            assert node in shown, (node, shown)


def test_gantt_sliver_numbers_do_not_overlap():
    # Thirteen slivers in three tight groups around two wide bars: every sliver's number
    # is shown once (alone or in a range such as "1-5"), no two labels overlap, and the
    # list under the axis names each number.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from warpvx.sched.gantt import plot_gantt
    from warpvx.sched.schedule import Schedule, ScheduledTask

    names = [f"n{i}" for i in range(15)]
    tasks, t = {}, 0.0
    for i, n in enumerate(names):
        t += 1.5 if i == 5 else 0.0
        d = 4.0 if i in (10, 11) else 0.05
        tasks[n] = ScheduledTask(n, "cpu0", t, t + d)
        t += d
    tasks["long"] = ScheduledTask("long", "gpu", 0.0, 50.0)
    fig, ax = plt.subplots(figsize=(11, 2.3))
    plot_gantt(Schedule(tasks, ["cpu0", "gpu"]), ax=ax, unit="ms")
    fig.canvas.draw()
    labels = [x for x in ax.texts if x.get_text()[0].isdigit()]
    shown = []
    for x in labels:
        a, _, b = x.get_text().partition("-")
        shown += list(range(int(a), int(b or a) + 1))
    assert sorted(shown) == list(range(1, 14))
    boxes = [x.get_window_extent() for x in labels]
    for i, b1 in enumerate(boxes):
        for b2 in boxes[i + 1:]:
            assert not b1.overlaps(b2)
    key = ax.get_xlabel()
    assert all(f"{k} n" in key for k in range(1, 14))
    plt.close(fig)
