"""Batches of inputs (warpvx.apps.batch): inputs, outputs, faults, resume; in process and on Ray.

Clips are made here from the bundled hand-held clip (three cuts) and from real photos
(scikit-image's astronaut and coffee) shaken by known random similarities, one of them as an
image folder; a garbage file and a truncated MP4 are the corrupt inputs.
"""

from __future__ import annotations

import argparse
import csv
import os
import shutil
import sys

import cv2
import numpy as np
import pytest

from tests.apps.conftest import CLIP
from tests.images import bgr
from warpvx import cli
from warpvx.apps import batch
from warpvx.apps import orbslam_cli as orb
from warpvx.apps import stabilize_cli as st
from warpvx.apps import stabilize_metrics as sm
from warpvx.errors import WarpvxError

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
ARGS = ["--window", "5", "--max-frames", "10", "--metrics", "m.json", "--quiet"]
ORB_ARGS = ["--mono", "--no-plot", "--quiet"]


def _write_video(path, frames, fps=25.0):
    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    for f in frames:
        writer.write(f)
    writer.release()
    return str(path)


def _read_video(path):
    cap, frames = cv2.VideoCapture(str(path)), []
    while True:
        ok, f = cap.read()
        if not ok:
            return np.array(frames)
        frames.append(f)


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """Five real inputs (four MP4s, one PNG folder) and two corrupt MP4s: ``(good, bad)``."""
    d = tmp_path_factory.mktemp("clips")
    cap, bikes = cv2.VideoCapture(CLIP), []
    while len(bikes) < 30:
        ok, f = cap.read()
        assert ok, "the bundled clip is shorter than 30 frames"
        bikes.append(cv2.resize(f, (320, 136), interpolation=cv2.INTER_AREA))
    good = [_write_video(d / f"bikes{k}.mp4", bikes[10 * k:10 * k + 10]) for k in range(3)]
    good.append(_write_video(d / "astronaut.mp4", sm.shaky_clip(bgr("astronaut"), 10, (160, 120), seed=1)[0]))
    folder = d / "coffee"
    folder.mkdir()
    for k, f in enumerate(sm.shaky_clip(bgr("coffee"), 10, (200, 150), seed=2)[0]):
        cv2.imwrite(str(folder / f"{k:03d}.png"), f)
    good.append(str(folder))
    garbage = d / "garbage.mp4"
    garbage.write_bytes(os.urandom(4096))
    truncated = d / "truncated.mp4"
    whole = open(good[0], "rb").read()
    truncated.write_bytes(whole[: len(whole) // 3])
    return good, [str(garbage), str(truncated)]


@pytest.fixture(scope="module")
def alone(clips, tmp_path_factory):
    """Each good input stabilized alone by ``warpvx stabilize IN OUT``: {input: (frames, ITF)}."""
    d, ref = tmp_path_factory.mktemp("alone"), {}
    for k, src in enumerate(clips[0]):
        out = d / f"{k}.mp4"
        metrics = d / f"{k}.json"
        args = ARGS[:ARGS.index("--metrics")] + ["--metrics", str(metrics), "--quiet"]
        assert cli.main(["stabilize", src, str(out)] + args) == 0
        ref[src] = (_read_video(out), sm_itf(metrics))
    return ref


def sm_itf(path):
    return sm_json(path)["output"]["itf"]


def options(*argv):
    """The stabilizer's options for ``argv`` as its command line parses them."""
    return batch.parse_options(st.add_arguments, ["IN", *argv])


def check_matches_alone(rows, alone, names):
    for row in rows:
        frames, itf = alone[row["input"]]
        assert row["status"] == "done", row["error"]
        assert row["output"].endswith(os.sep + names[row["input"]])
        np.testing.assert_array_equal(_read_video(os.path.join(row["output"], "stabilized.mp4")), frames)
        assert row["frames"] == len(frames) and row["quality"] == itf and row["fps"] > 0


# --------------------------------------------------------------------------- inputs


def test_expand_inputs_paths_folders_globs_and_lists(tmp_path, clips):
    good, bad = clips
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("b.mp4", "a.avi", "notes.txt"):
        (videos / name).write_bytes(b"")
    (tmp_path / "list.txt").write_text(f"# the archive\n{good[3]}\n\nvideos/a.avi  # relative\n")
    got = batch.expand_inputs([good[0], str(videos), os.path.join(os.path.dirname(good[0]), "bikes[12].mp4"),
                               "@" + str(tmp_path / "list.txt"), good[4], good[0]])
    assert got == [good[0], str(videos / "a.avi"), str(videos / "b.mp4"), good[1], good[2], good[3], good[4]]
    assert batch.output_names(["x/clip.mp4", "y/clip.avi", "z/seq/", "clip"]) == ["clip", "clip-2", "seq", "clip-3"]


@pytest.mark.parametrize("items, field", [
    (["nothing-here-*.mp4"], "inputs"), (["@no-such-list.txt"], "inputs"), ([], "inputs")])
def test_expand_inputs_bad_input_names_the_argument(items, field):
    with pytest.raises(WarpvxError, match=field):
        batch.expand_inputs(items)


def test_cli_one_in_out_pair_stays_a_single_run_and_a_batch_needs_out(clips, tmp_path, capsys):
    good, _ = clips
    assert cli.main(["stabilize", good[0], str(tmp_path / "one.mp4"), "--quiet"]) == 0
    assert os.path.isfile(tmp_path / "one.mp4") and not os.path.exists(tmp_path / "one")
    for argv, field in [([good[0]], "output"), (good[:3], "out"),
                        ([good[0], str(tmp_path / "o.mp4"), "--resume"], "out"),
                        ([str(tmp_path / "demo"), "--demo", "--ray"], "input")]:
        assert cli.main(["stabilize", *argv, "--quiet"]) == 2
        err = capsys.readouterr().err
        assert f" {field}" in err.split("error:")[1].split(":")[0] and len(err.strip().splitlines()) == 1


# --------------------------------------------------------------------------- in process


def test_batch_matches_each_input_alone_and_a_corrupt_input_fails_alone(clips, alone, tmp_path, capsys):
    good, bad = clips
    out = tmp_path / "out"
    inputs = [good[0], bad[0], *good[1:], bad[1]]
    rc = cli.main(["stabilize", *inputs, "--out", str(out)] + ARGS)
    assert rc == 1  # some input failed
    printed = capsys.readouterr().out
    with open(out / batch.SUMMARY_CSV) as f:
        table = list(csv.DictReader(f))
    assert [r["input"] for r in table] == inputs
    assert [r["status"] for r in table] == ["done", "failed", "done", "done", "done", "done", "failed"]
    for r in (table[1], table[-1]):
        assert "input" in r["error"] and os.path.basename(r["input"]) in printed
    rows = [dict(r, frames=int(r["frames"]), quality=float(r["quality"]), fps=float(r["fps"]))
            for r in table if r["status"] == "done"]
    check_matches_alone(rows, alone, dict(zip(good, ["bikes0", "bikes1", "bikes2", "astronaut", "coffee"])))
    assert sorted(os.listdir(out)) == ["astronaut", "batch_summary.csv", "bikes0", "bikes1", "bikes2", "coffee"]
    assert batch.read_complete(out / "bikes0")["frames"] == 10


def test_resume_skips_complete_outputs_only(clips, tmp_path):
    good, bad = clips
    out = str(tmp_path / "out")
    opts = options("--window", "3", "--max-frames", "4")
    first = batch.run_items("stabilize", good[:3] + bad[:1], out, opts, progress=False)
    assert [r["status"] for r in first] == ["done", "done", "done", "failed"]
    # bikes1 as a worker that died left it; bikes2 a folder of the user's, never overwritten
    shutil.rmtree(os.path.join(out, "bikes1"))
    os.mkdir(os.path.join(out, ".bikes1.partial-dead"))
    shutil.rmtree(os.path.join(out, "bikes2"))
    os.mkdir(os.path.join(out, "bikes2"))
    open(os.path.join(out, "bikes2", "mine.txt"), "w").close()
    calls = []

    def counting(source, out_dir, options):
        calls.append(source)
        return batch.run_stabilize(source, out_dir, options)

    second = batch.run_items(counting, good[:3] + bad[:1], out, opts, resume=True, progress=False)
    assert calls == [good[1], bad[0]]
    assert [r["status"] for r in second] == ["skipped", "done", "failed", "failed"]
    assert second[0]["frames"] == first[0]["frames"] and second[0]["seconds"] == first[0]["seconds"]
    assert "no batch output" in second[2]["error"] and os.listdir(os.path.join(out, "bikes2")) == ["mine.txt"]
    assert sorted(os.listdir(out)) == ["bikes0", "bikes1", "bikes2"]  # the dead partial is gone


def test_ray_missing_is_a_clear_error(monkeypatch, clips, tmp_path):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(WarpvxError, match=r"ray: Ray is not installed .*warpvx\[cluster\]"):
        batch.run_items("stabilize", clips[0][:1], str(tmp_path), options(), ray="", progress=False)


# --------------------------------------------------------------------------- on Ray


@pytest.fixture(scope="module")
def ray_local():
    """A local Ray instance with 2 CPUs, shared by this module's Ray tests (it takes ~10 s to
    start); its workers import this checkout's warpvx and tests."""
    ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'warpvx[cluster]')")
    mp = pytest.MonkeyPatch()
    mp.setenv("PYTHONPATH", os.pathsep.join(filter(None, [ROOT, os.environ.get("PYTHONPATH")])))
    mp.setenv("RAY_AUTH_MODE", "disabled")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    here = ray.get(ray.remote(lambda: __import__("warpvx").__file__).remote())
    assert here.startswith(ROOT), f"Ray workers import {here}, not this checkout"
    yield ray
    ray.shutdown()
    mp.undo()


def test_ray_batch_matches_each_input_alone(ray_local, clips, alone, tmp_path):
    good, bad = clips
    args = argparse.Namespace(input=[*good, *bad], out=str(tmp_path / "out"), ray="", resume=False,
                              num_gpus=None, cpus_per_input=1, workers=2, retries=1,
                              **options(*ARGS))
    assert batch.run_batch(args, "stabilize") == 1
    with open(tmp_path / "out" / batch.SUMMARY_CSV) as f:
        table = list(csv.DictReader(f))
    assert [r["status"] for r in table] == ["done"] * 5 + ["failed"] * 2
    assert all("cannot open" in r["error"] for r in table[5:])
    rows = [dict(r, frames=int(r["frames"]), quality=float(r["quality"]), fps=float(r["fps"]))
            for r in table[:5]]
    check_matches_alone(rows, alone, dict(zip(good, ["bikes0", "bikes1", "bikes2", "astronaut", "coffee"])))


def crash_once(source, out_dir, options):
    """An adapter whose worker process dies on its first attempt, leaving a half-written
    output, then runs the stabilizer (the marker file remembers the attempt)."""
    options = dict(options)
    marker = options.pop("crash_marker")
    if not os.path.exists(marker):
        open(marker, "w").close()
        with open(os.path.join(out_dir, "stabilized.mp4"), "wb") as f:
            f.write(b"half a video")
        os._exit(1)
    return batch.run_stabilize(source, out_dir, options)


@pytest.mark.parametrize("retries", [1, 0])
def test_ray_worker_that_dies_is_retried_and_never_leaves_a_complete_looking_output(
        ray_local, clips, alone, tmp_path, retries):
    good, _ = clips
    out = tmp_path / "out"
    opts = dict(options(*ARGS), crash_marker=str(tmp_path / "crashed"))
    rows = batch.run_items(crash_once, good[:1], str(out), opts, ray="", cpus_per_input=1,
                           retries=retries, progress=False)
    assert os.path.exists(tmp_path / "crashed")  # the first attempt did die
    if retries:
        check_matches_alone(rows, alone, {good[0]: "bikes0"})
        assert os.listdir(out) == ["bikes0"]  # the dead attempt's partial folder is gone
    else:
        assert rows[0]["status"] == "failed" and "worker died" in rows[0]["error"]
        assert not os.path.exists(out / "bikes0")  # only a .partial folder, never presented as done
        again = batch.run_items(crash_once, good[:1], str(out), opts, resume=True, progress=False)
        check_matches_alone(again, alone, {good[0]: "bikes0"})
        assert os.listdir(out) == ["bikes0"]


def test_ray_worker_count_fits_the_cluster():
    from warpvx.apps.batch_ray import worker_count

    assert worker_count({"CPU": 16, "GPU": 1}, 0.25, 2, 100) == 4
    assert worker_count({"CPU": 16, "GPU": 1}, 0.25, 2, 3) == 3
    assert worker_count({"CPU": 2}, 0, 1, 10) == 2
    for resources, args, field in [({"CPU": 8, "GPU": 1}, (0.5, 2, 10, 3), "workers"),
                                   ({"CPU": 8}, (1, 1, 10), "num_gpus"),
                                   ({"CPU": 8, "GPU": 2}, (1.5, 1, 10), "num_gpus"),
                                   ({"CPU": 8}, (0, 0, 10), "cpus_per_input")]:
        with pytest.raises(WarpvxError, match=field):
            worker_count(resources, *args)


@pytest.fixture(scope="module")
def sequences(tmp_path_factory):
    """Two rendered 8-frame KITTI-layout sequences (320x240, exact poses in poses.txt) and,
    for each, the ATE and trajectory of ``warpvx orbslam SOURCE --gt poses.txt`` alone."""
    from warpvx.apps.orbslam_synth import render_sequence, write_kitti_sequence

    d, seqs, ref = tmp_path_factory.mktemp("seqs"), [], {}
    for k, step in enumerate((0.05, 0.03)):
        left, _, K, poses = render_sequence(8, (320, 240), step=step, supersample=1)
        seq = str(write_kitti_sequence(d / f"seq{k}", left, K, poses))
        out = d / f"alone{k}"
        assert cli.main(["orbslam", seq, "--gt", os.path.join(seq, "poses.txt"), "--out", str(out)]
                        + ORB_ARGS) == 0
        ref[seq] = (sm_json(out / "metrics.json")["warpvx"]["ate"]["rmse"],
                    (out / "trajectory.kitti.txt").read_text())
        seqs.append(seq)
    return seqs, ref


def sm_json(path):
    import json

    with open(path) as f:
        return json.load(f)


def check_orbslam_matches_alone(rows, ref):
    for row in rows:
        ate, trajectory = ref[row["input"]]
        assert row["status"] == "done", row["error"]
        assert float(row["ate"]) == ate and int(row["frames"]) == 8
        with open(os.path.join(row["output"], "trajectory.kitti.txt")) as f:
            assert f.read() == trajectory


def test_orbslam_batch_finds_each_ground_truth_and_matches_runs_alone(sequences, tmp_path, capsys):
    seqs, ref = sequences
    out = tmp_path / "out"
    assert cli.main(["orbslam", *seqs, "--out", str(out)] + ORB_ARGS) == 0
    with open(out / batch.SUMMARY_CSV) as f:
        check_orbslam_matches_alone(list(csv.DictReader(f)), ref)
    assert "ate" in capsys.readouterr().out


def test_orbslam_adapter_needs_the_module(monkeypatch, sequences, tmp_path):
    import warpvx.apps

    # The front end missing: the adapter's fresh import of its command line then fails.
    for name in ("orbslam", "orbslam_cli"):
        monkeypatch.delattr(warpvx.apps, name, raising=False)
    monkeypatch.delitem(sys.modules, "warpvx.apps.orbslam_cli", raising=False)
    monkeypatch.setitem(sys.modules, "warpvx.apps.orbslam", None)
    [row] = batch.run_items("orbslam", sequences[0][:1], str(tmp_path), {}, progress=False)
    assert row["status"] == "failed" and "warpvx.apps.orbslam is not available" in row["error"]


def test_ray_orbslam_batch_matches_runs_alone(ray_local, sequences, tmp_path):
    seqs, ref = sequences
    opts = batch.parse_options(orb.add_arguments, ["S", *ORB_ARGS], paths="source")
    rows = batch.run_items("orbslam", seqs, str(tmp_path), opts, ray="", cpus_per_input=1, progress=False)
    check_orbslam_matches_alone(rows, ref)
