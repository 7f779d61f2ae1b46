"""The benchmark harness (warpvx bench): it runs, writes JSON with positive timings, skips
what is missing, and times batches sensibly. No timing assertions (this machine is shared)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from warpvx import bench, cli
from warpvx.backend import cuda_available
from warpvx.errors import BackendError
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


def _usage_error(argv, capsys) -> str:
    """Run ``warpvx ARGV``, expect exit status 2; return stderr, checked to be one line."""
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    return err


def test_unknown_primitive_is_an_error(tmp_path, capsys):
    err = _usage_error(["bench", "--primitives", "no_such_thing", "--out", str(tmp_path)], capsys)
    assert "--primitives" in err and "no_such_thing" in err and "gaussian_blur" in err


def test_bad_size_is_an_error(tmp_path, capsys):
    assert "--sizes" in _usage_error(["bench", "--sizes", "big", "--out", str(tmp_path)], capsys)


@pytest.mark.parametrize("names", [["gpu"], ["cpu,gpu"], ["cpu", "CUDA"], ["cuda:x"]])
def test_unknown_backend_is_an_error(names, capsys):
    """A typo is refused before anything runs, naming the argument and the valid names."""
    err = _usage_error(["bench", "--backends", *names], capsys)
    assert "--backends" in err and "valid: cpu, warp-cpu, cuda, cuda:N" in err


def test_unknown_backend_in_run_is_a_backend_error():
    with pytest.raises(BackendError, match="backends.*'gpu'"):
        bench.run(backends=["gpu"], progress=False)


def test_bad_repeat_is_an_error(capsys):
    assert "--repeat" in _usage_error(["bench", "--repeat", "0"], capsys)


def _quick(tmp_path, *extra):
    return ["bench", "--quick", "--primitives", "color_convert", "--sizes", "32x24", "--out",
            str(tmp_path), "--no-progress", "--no-plot", *extra]


@pytest.mark.skipif(cuda_available(), reason="needs a machine without CUDA")
def test_unavailable_backend_is_a_note(tmp_path, capsys):
    assert cli.main(_quick(tmp_path, "--backends", "cpu", "cuda")) == 0
    out = capsys.readouterr().out
    assert "note: 'cuda' is not available on this machine" in out
    data = json.loads(next(tmp_path.glob("bench-*.json")).read_text())
    assert data["backends"] == ["cpu"]


@pytest.mark.skipif(cuda_available(), reason="needs a machine without CUDA")
def test_no_warp_backend_is_said(tmp_path, capsys):
    """On a CPU-only machine the default backends run no Warp kernel: the output says so."""
    assert cli.main(_quick(tmp_path)) == 0
    assert "note: no Warp backend ran" in capsys.readouterr().out
    assert cli.main(_quick(tmp_path, "--backends", "cpu", "warp-cpu")) == 0
    assert "no Warp backend ran" not in capsys.readouterr().out


def test_table_says_what_rows_are(tmp_path, capsys):
    """The table's legend names every implementation in it and the ratio's direction; the
    JSON records the same legend and the input photo."""
    assert cli.main(_quick(tmp_path, "--backends", "cpu", "warp-cpu")) == 0
    out = capsys.readouterr().out
    data = json.loads(next(tmp_path.glob("bench-*.json")).read_text())
    impls = {r["impl"] for r in data["results"]}
    assert impls == {"opencv", "cpu", "warp-cpu"} == set(data["impls"])
    legend = {line.split(" = ", 1)[0].strip(): line.split(" = ", 1)[1]
              for line in out.splitlines() if " = " in line}
    assert "NumPy/OpenCV implementation" in legend["cpu"] and "not Warp" in legend["cpu"]
    assert "Warp kernels on Warp's CPU device" in legend["warp-cpu"]
    assert "reference" in legend["opencv"]
    assert "OpenCV time / this time; > 1 is faster" in legend["vs OpenCV"]
    photo = bench.load_photo()
    assert data["photo"]["name"] == "astronaut" and data["photo"]["source"]
    assert data["photo"]["size"] == f"{photo.shape[1]}x{photo.shape[0]}"


def _synthetic_report():
    """Two sizes, cases whose labels share their first 50 characters, three implementations."""
    results = []
    long_case = "1000 pts, 21x21, max_level 3"
    for size in ("1920x1080", "1241x376"):
        for prim, case in [("optical_flow_pyr_lk", long_case),
                           ("optical_flow_pyr_lk", long_case + ", video loop (one new pyramid)"),
                           ("gaussian_blur", "5x5 s1 gray")]:
            for k, impl in enumerate(["opencv", "cpu", "cuda:0"]):
                results.append(bench.Result(prim, case, size, impl, per_call_s=1e-4 * (k + 1)))
    machine = {"cpu_model": "Test CPU", "cpu_cores": 2,
               "gpus": [{"device": "cuda:0", "name": "Test GPU", "memory_gib": 1.0}]}
    return bench.Report(machine=machine, settings={}, sizes=["1920x1080", "1241x376"],
                        backends=["cpu", "cuda"], results=results,
                        photo={"name": "astronaut", "source": "test", "size": "512x512"})


def test_plot_layout():
    """Title clear of the first panel, a time label on every panel, case labels whole, unique
    and inside the figure."""
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    report = _synthetic_report()
    fig = bench.plot_figure(report)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        page = fig.bbox
        first = fig.axes[0]
        title = fig._suptitle.get_window_extent(renderer)
        assert title.y0 >= first.get_tightbbox(renderer).y1 - 1
        for ax in fig.axes:
            assert "time per call" in ax.get_xlabel()
            labels = ax.get_yticklabels()
            texts = [t.get_text() for t in labels]
            assert len(set(texts)) == len(texts) == 3
            assert {f"{r.primitive}: {r.case}" for r in report.results} == set(texts)
            for t in labels:
                box = t.get_window_extent(renderer)
                assert box.x0 >= page.x0 and box.x1 <= page.x1
        legend = fig.legends[0]
        assert [t.get_text() for t in legend.get_texts()][2] == "warpvx cuda:0 (Warp, GPU)"
    finally:
        plt.close(fig)


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


def test_orb_ab_interleaves_rounds_and_reports_medians(tmp_path, monkeypatch):
    """benchmarks/perf/hot_paths.py orb-ab: a fresh process per round, the arms' order rotated,
    per arm the medians of its rounds (FPS against the first arm's); a round missing an arm is
    an error. (The runs faked: FPS 100 (arm 0) or 200 (arm 1, 2) plus the round.)"""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import hot_paths

    monkeypatch.setattr(hot_paths, "_rendered", lambda cache: None)
    rotations = []

    def fake_run(argv, **kwargs):
        rotate = int(argv[argv.index("--rotate") + 1])
        rotations.append(rotate)
        rows = [{"fps": (100 if i == 0 else 200) + rotate, "steady_fps": 300 + rotate, "wall": 40.0 + i, "cpu": 25.0,
                 "wait_ahead": 6.0, "wait_keyframe": 0.5} for i in range(3)]
        out = "".join(f"arm {i} 0: {r['fps']:.1f} FPS {json.dumps(r)}\n" for i, r in enumerate(rows)
                      if not (missing and i == 2))
        return type("Done", (), {"stdout": out, "stderr": "", "returncode": 0})()

    monkeypatch.setattr(hot_paths.subprocess, "run", fake_run)
    missing = False
    lines = hot_paths.orb_ab(3, str(tmp_path), experiment="nice")
    assert rotations == [0, 1, 2]
    assert (tmp_path / "nice-ab.md").read_text().splitlines() == lines
    assert "--experiment nice" in lines[0]
    rows = {line.split(" | ")[0][2:]: line.split(" | ") for line in lines if line.startswith("| nice")}
    assert rows["nice 0 (default)"][1:3] == ["100.0 / 101.0 / 102.0", "101.0 (+0.0%)"]
    assert rows["nice 5"][2] == "201.0 (+99.0%)" and rows["nice 5"][3] == "301.0"
    assert rows["nice 10"][4:6] == ["42.00", "25.00"]
    missing = True
    with pytest.raises(RuntimeError, match="2 of 3 arms"):
        hot_paths.orb_ab(1, str(tmp_path), experiment="nice")


def test_handoff_floor_writes_its_rows(tmp_path):
    """benchmarks/perf/handoff_floor.py on Warp's CPU device: the four rows, each a positive
    time per round with its half per node, under the command that regenerates them."""
    from pathlib import Path

    pytest.importorskip("warp")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import handoff_floor

    assert handoff_floor.main(["--out", str(tmp_path), "--device", "cpu", "--rounds", "20",
                               "--batches", "2"]) == 0
    text = (tmp_path / "handoff_floor.md").read_text()
    assert text.startswith("<!-- PYTHONPATH=. python3 benchmarks/perf/handoff_floor.py --out ")
    rows = [line.split("|")[1:4] for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| what")]
    assert [r[0].strip() for r in rows] == ["copies", "copies + event", "threads",
                                            "threads + copies"]
    for _, per_round, per_node in rows:
        assert float(per_round) > 0 and float(per_node) == pytest.approx(float(per_round) / 2, abs=0.06)
    for bad in (["--rounds", "0"], ["--batches", "-1"]):
        with pytest.raises(SystemExit):
            handoff_floor.main(["--out", str(tmp_path), "--device", "cpu", *bad])


def test_pipeline_threads_writes_a_row_per_round_and_placement(tmp_path):
    """benchmarks/perf/pipeline_threads.py on Warp's CPU device (small frames): one row per
    placement, its FPS positive, the split placement's homographies on two CPU workers and
    the baseline's on one, each CPU task's times listed, under the regenerating command."""
    from pathlib import Path

    pytest.importorskip("warp")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import cv2
    import pipeline_threads

    threads = cv2.getNumThreads()
    pipeline_threads.main(["--out", str(tmp_path), "--gpu", "warp-cpu", "--size", "160x120",
                           "--frames", "4", "--rounds", "1"])
    text = (tmp_path / "pipeline_threads.md").read_text()
    assert text.startswith("<!-- PYTHONPATH=. python3 benchmarks/perf/pipeline_threads.py --out ")
    assert "OpenCV threads: 1." in text  # the default, as graph_bench's
    assert cv2.getNumThreads() == threads  # restored after the run
    assert "baseline: homographyL cpu0, homographyR cpu0" in text
    assert "split: homographyL cpu0, homographyR cpu1" in text
    rows = {r.split("|")[2].strip(): r.split("|") for r in text.splitlines() if r.startswith("| 0 |")}
    assert set(rows) == {"baseline", "split"}
    assert all(float(r[3]) > 0 for r in rows.values())
    for r in rows.values():
        assert [t.split()[0] for t in r[6].split(",")] == ["homographyL", "homographyR", "fuse"]
    for bad in (["--frames", "0"], ["--rounds", "-1"], ["--size", "320"], ["--size", "8x8"],
                ["--policies", "baseline,nope"], ["--cv-threads", "-2"]):
        with pytest.raises(SystemExit):
            pipeline_threads.main(["--out", str(tmp_path), "--gpu", "warp-cpu", *bad])


def test_pipeline_bottleneck_runs_each_variant_and_takes_away_what_it_says(tmp_path):
    """benchmarks/perf/pipeline_bottleneck.py on Warp's CPU device (small frames): a row per
    variant with a positive frame rate and the medians, under the regenerating command; its
    variants of the graph leave out what they name (the detector and its output; RANSAC:
    the identity, from the same inputs)."""
    from pathlib import Path

    pytest.importorskip("warp")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import pipeline_bottleneck  # (puts benchmarks/ on the path too)

    graph_bench = pipeline_bottleneck.graph_bench
    full = graph_bench.build_graph((160, 120))
    bare = graph_bench.build_graph((160, 120), detector=False)
    assert "detectorL" in full.nodes and "detectorL" not in bare.nodes
    assert len(bare.nodes) == len(full.nodes) - 1 and "scoreL" not in bare.outputs
    status = np.ones((5, 1), np.uint8)
    pts = np.float32([[0, 0], [9, 0], [0, 9], [9, 9], [5, 4]])
    assert np.array_equal(pipeline_bottleneck.homography_without_ransac(pts, pts + 1, status),
                          np.eye(3))
    pipeline_bottleneck.main(["--out", str(tmp_path), "--gpu", "warp-cpu", "--size", "160x120",
                              "--frames", "3", "--rounds", "1"])
    text = (tmp_path / "pipeline_bottleneck.md").read_text()
    assert text.startswith("<!-- PYTHONPATH=. python3 benchmarks/perf/pipeline_bottleneck.py --out ")
    rows = {r.split("|")[2].strip(): float(r.split("|")[3]) for r in text.splitlines()
            if r.startswith("| 0 |")}
    assert set(rows) == set(pipeline_bottleneck.VARIANTS) and min(rows.values()) > 0
    assert "Medians over the rounds: as-is" in text
    for bad in (["--frames", "0"], ["--size", "8x8"], ["--cv-threads", "-1"]):
        with pytest.raises(SystemExit):
            pipeline_bottleneck.main(["--out", str(tmp_path), "--gpu", "warp-cpu", *bad])


def test_process_nodes_bench_runs_both_graphs_both_ways(tmp_path):
    """benchmarks/perf/process_nodes.py (CPU only, small): a row per round, graph and
    placement, the medians, and the outputs of the two placements equal; bad arguments
    refused by name."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import process_nodes

    process_nodes.main(["--out", str(tmp_path), "--frames", "12", "--rounds", "1",
                        "--python-ms", "0.2"])
    text = (tmp_path / "process_nodes.md").read_text()
    assert text.startswith("<!-- PYTHONPATH=. python3 benchmarks/perf/process_nodes.py --out ")
    rows = [r.split("|") for r in text.splitlines() if r.startswith("| 0 |")]
    assert {(r[2].strip(), r[3].strip()) for r in rows} == {
        (k, w) for k in ("python", "ransac") for w in ("in this process", "in worker processes")}
    assert all(float(r[4]) > 0 for r in rows)
    assert text.count("outputs equal bit for bit: yes") == 2
    for bad in (["--frames", "0"], ["--python-ms", "0"], ["--depth", "-1"]):
        with pytest.raises(SystemExit):
            process_nodes.main(["--out", str(tmp_path), *bad])


def test_model_replay_first_rows_pair_by_experiment_and_policy():
    """benchmarks/model_replay.py: a prediction is scored against the first frames of its own
    experiment and policy, whatever order the other checkout recorded its rows in."""
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import model_replay

    rows = [{"tag": "a", "policy": "x", "pred_ms": 2.0}, {"tag": "a", "policy": "y", "pred_ms": 3.0},
            {"tag": "b", "policy": "x", "pred_ms": 1.0}]
    ref = [{"tag": "a", "policy": "y", "measured_first_ms": 2.0},
           {"tag": "a", "policy": "x", "measured_first_ms": 1.0},
           {"tag": "b", "policy": "x"}]  # not recorded there: left out
    got = {(r["tag"], r["policy"]): r["error_pct"] for r in model_replay.first_rows(rows, ref)}
    assert got == {("a", "x"): pytest.approx(100.0), ("a", "y"): pytest.approx(50.0)}


def _host_speed_replay():
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import host_speed_replay

    return host_speed_replay


def test_host_speed_probe_ratios_pair_frames_with_their_rounds():
    """benchmarks/host_speed_replay.py: each out-of-sample frame gets the reference of the
    round it ran in over the training rounds' median; baseline, heft and xeft count their
    training rounds among their frames, best joined at the later rounds."""
    hs = _host_speed_replay()

    def log(refs, n):
        return [{"reference_ms": r, "medians": [1.0] * n} for r in refs]

    e = {"settle": {"log": log([9.0], 3)},
         "round_log": {"training": log([2.0, 4.0], 3), "later": log([6.0, 3.0, 12.0, 1.5], 4)}}
    # baseline: frames 21-40 ran in the first two later rounds (block 10, 20 fit frames).
    got = hs.probe_ratios(e, "baseline", fit_rounds=2, block=10, n_out=20)
    assert got["round"] == [2.0] * 10 + [1.0] * 10
    assert got["first"] == [2.0] * 20
    assert got["oracle"] == [4.5 / 3.0] * 20
    # the rolling median of the round and the two before, over the settle and training rounds'
    assert got["rolling"][0] == pytest.approx(4.0 / 4.0)
    assert got["rolling"][10] == pytest.approx(4.0 / 4.0)
    # best: its frames 21-40 are its third and fourth later rounds.
    got = hs.probe_ratios(e, "best", fit_rounds=2, block=10, n_out=20)
    assert got["round"] == [4.0] * 10 + [0.5] * 10
    assert got["first"] == [4.0] * 20


def test_host_speed_scaled_scales_only_the_named_parts():
    """benchmarks/host_speed_replay.py: ``scaled`` multiplies the named processing elements'
    task work (ratio and fixed cost per task: the whole in-frame time) and, with the GPU
    host thread, a captured segment's fixed cost per replay; nothing else."""
    from warpvx.graph.model import ContentionModel, Slowdown

    hs = _host_speed_replay()
    model = ContentionModel(
        slowdown={"cpu": Slowdown(ratio=1.2, overhead=0.1, node={"a": 1.5}, per_cpu=0.3),
                  "gpu": Slowdown(ratio=0.8, overhead=0.02, per_gpu=0.1)},
        latency={}, alone={}, reads={}, transfer=None, cuda=True, segment_ratio=0.5,
        segment_fixed=0.05)
    cpu = hs.scaled(model, 2.0, ("cpu",))
    assert cpu.slowdown["cpu"].in_frame("a", 3.0) == pytest.approx(2.0 * model.slowdown["cpu"].in_frame("a", 3.0))
    assert cpu.slowdown["cpu"].speed_divisor(1, 0) == model.slowdown["cpu"].speed_divisor(1, 0)
    assert cpu.slowdown["gpu"] == model.slowdown["gpu"]
    assert (cpu.segment_fixed, cpu.segment_ratio) == (0.05, 0.5)
    both = hs.scaled(model, 2.0, ("cpu", "gpu"))
    assert both.slowdown["gpu"].in_frame("b", 1.0) == pytest.approx(2.0 * model.slowdown["gpu"].in_frame("b", 1.0))
    assert (both.segment_fixed, both.segment_ratio) == (pytest.approx(0.1), 0.5)
    assert model.slowdown["cpu"].ratio == 1.2  # the model itself untouched


def test_best_throughput_writes_both_objectives_rows(tmp_path):
    """benchmarks/perf/best_throughput.py on Warp's CPU device: the baseline and the two
    kept plans, each measured both ways (a positive makespan and frame rate), each best row
    naming a candidate its own trial measured, under the command that regenerates them."""
    from pathlib import Path

    pytest.importorskip("warp")
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "perf"))
    import best_throughput

    best_throughput.main(["--out", str(tmp_path), "--gpu", "warp-cpu", "--size", "160x120",
                          "--rounds", "1", "--frames", "2", "--margin", "1e6"])
    text = (tmp_path / "best_throughput.md").read_text()
    assert text.startswith("<!-- PYTHONPATH=. python3 benchmarks/perf/best_throughput.py --out ")
    rows = [[c.strip() for c in line.split("|")[1:-1]] for line in text.splitlines()
            if line.startswith("| ") and not line.startswith("| plan")]
    assert [r[0] for r in rows] == ["baseline", "best (latency)", "best (throughput)"]
    for name, kept, trial, _, ms, fps in rows:
        assert float(ms) > 0 and float(fps) > 0
        if name != "baseline":  # (every candidate within the margin: a trial ran)
            unit = "FPS" if "throughput" in name else "ms"
            assert f"{kept} " in trial and trial.endswith(unit)
