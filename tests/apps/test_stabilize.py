"""The video stabilizer (warpvx.apps.stabilize): graph, model, command line."""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tests.apps.conftest import CLIP, static_frames
from tests.images import clip_frames
from warpvx import cli
from warpvx.apps import stabilize as st
from warpvx.apps import stabilize_metrics as sm
from warpvx.errors import WarpvxError

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")


@pytest.mark.parametrize("kwargs, field", [
    ({"window": 0}, "window"), ({"crop": 0.5}, "crop"), ({"crop": -0.1}, "crop"),
    ({"mode": "future"}, "mode"), ({"motion": "affine"}, "motion"),
    ({"camera_matrix": np.eye(3)}, "dist_coeffs"),
    ({"cut_threshold": 0}, "cut_threshold"), ({"cut_threshold": -0.2}, "cut_threshold"),
    ({"cut_threshold": float("inf")}, "cut_threshold"), ({"cut_threshold": "0.3"}, "cut_threshold"),
])
def test_config_bad_input_names_the_field(kwargs, field):
    with pytest.raises(WarpvxError, match=field):
        st.StabilizerConfig(**kwargs)


def test_weights_follow_the_thesis_form():
    r = 3
    centred = st.StabilizerConfig(window=2 * r + 1, mode="centered").weights()
    np.testing.assert_allclose(centred, np.exp(-0.5 * (np.arange(-r, r + 1) / (0.7 * r)) ** 2))
    causal = st.StabilizerConfig(window=7, mode="causal").weights()
    assert len(causal) == 7 and causal[-1] == 1.0 and np.all(np.diff(causal) > 0)


def test_smoothing_of_translations_is_the_mean_path_minus_the_path():
    """The classic parameter-space smoother (cumulative shifts, weighted mean over the window,
    correction = smoothed - actual) is exact for translations: the order and sign of
    S_j = mean(T_i) T_j^-1 must reproduce it (a swapped inverse doubles the shake)."""
    rng = np.random.default_rng(0)
    path = np.cumsum(rng.normal(0, 3, (9, 2)), axis=0)  # T_i: frame 0 -> frame i, shifts
    cfg = st.StabilizerConfig(window=9)
    w = cfg.weights()
    Ts = [np.array([[1, 0, x], [0, 1, y], [0, 0, 1.0]]) for x, y in path]
    S = st.smooth_transform(*Ts, weights=w, lag=cfg.lag)
    want = (w[:, None] * path).sum(0) / w.sum() - path[cfg.lag]
    np.testing.assert_allclose(S, [[1, 0, want[0]], [0, 1, want[1]], [0, 0, 1]], atol=1e-9)


def test_lost_points_are_parked_alike_on_host_and_warp():
    import warp as wp

    pts = np.float32([[1, 2], [3, 4], [5, 6], [7, 8], [9, 10]])
    status = np.uint8([1, 0, 1, 0, 1])
    host = st.park_lost(pts, status)
    np.testing.assert_array_equal(host[status == 1], pts[status == 1])
    assert (host[status == 0] == st.LOST).all()
    dev = st._park_lost_warp(wp.array(pts, device="cpu"), wp.array(status, device="cpu"))
    np.testing.assert_array_equal(dev.numpy(), host)


def test_point_sets_are_padded_to_the_four_a_homography_needs():
    pts = st.refresh_points(np.float32([[10, 10]]), np.uint8([1]), np.zeros((0, 2), np.float32))
    assert pts.shape == (4, 2) and (pts[0] == 10).all() and (pts[1:] < -1000).all()


def test_truncation_keeps_the_output_inside_the_frame():
    size = (160, 120)
    shift = np.array([[1, 0, 30.0], [0, 1, -25.0], [0, 0, 1]])  # beyond a 10% crop margin
    M = st.truncate_transform(shift, size=size, crop=0.1)
    ones = cv2.warpPerspective(np.ones((120, 160), np.uint8), M, size)
    assert ones[1:-1, 1:-1].min() == 1  # no uncovered pixel
    small = np.array([[1, 0, 3.0], [0, 1, 2.0], [0, 0, 1]])  # within the margin: kept as is
    np.testing.assert_allclose(st.truncate_transform(small, size=size, crop=0.1),
                               st._crop_matrix(size, 0.1) @ small)


@pytest.mark.parametrize("mode", ["centered", "causal"])
def test_one_output_per_input_in_order(bikes, mode):
    frames = bikes[:10]
    out = list(st.stabilize(frames, st.StabilizerConfig(window=5, mode=mode), backend="cpu"))
    assert [o.index for o in out] == list(range(len(frames)))
    for o, f in zip(out, frames):  # frame k shows input frame k, warped by its reported warp
        want = cv2.warpPerspective(f, o.warp, (320, 136), flags=cv2.INTER_LINEAR)
        assert np.mean(np.abs(want.astype(int) - o.image)) < 2.0


def test_causal_mode_does_not_look_ahead(bikes):
    cfg = st.StabilizerConfig(window=5, mode="causal")
    short = list(st.stabilize_model(bikes[:8], cfg))
    longer = list(st.stabilize_model(bikes[:12], cfg))
    for a, b in zip(short, longer):
        np.testing.assert_array_equal(a.image, b.image)


def test_static_clip_stays_still(astronaut):
    frames = static_frames(astronaut, 8)
    out = [o.image for o in st.stabilize(frames, st.StabilizerConfig(window=5), backend="cpu")]
    assert sm.mad(out, 10) == pytest.approx(0.0, abs=1e-3)
    assert sm.itf(out) == sm.PSNR_MAX


@pytest.mark.parametrize("motion, backend", [
    ("translation", "cpu"), ("similarity", "cpu"), ("homography", "cpu"),
    ("homography", "warp-cpu"),  # the find_homography primitive as a node on the Warp device
])
def test_known_translation_shake_is_removed(astronaut, motion, backend):
    frames, ref, _ = sm.shaky_clip(astronaut, 24, (160, 120), shift=5.0, angle=0.0, zoom=0.0, seed=4)
    cfg = st.StabilizerConfig(window=15, motion=motion, crop=0.1)
    out = [o.image for o in st.stabilize(frames, cfg, backend=backend)]
    applied, residual = sm.shake_rms(frames, ref), sm.shake_rms(out, ref)
    assert applied > 3.0
    assert residual < 0.3 * applied


def test_model_and_graph_backends_agree(bikes):
    """Multi-level verification (thesis §2): MAD and ITF within 5% across the OpenCV model and
    the graph on cpu and on Warp."""
    cfg = st.StabilizerConfig(window=7, motion="similarity")
    runs = {"model": [o.image for o in st.stabilize_model(bikes, cfg)]}
    for backend in ("cpu", "warp-cpu"):
        runs[backend] = [o.image for o in st.stabilize(bikes, cfg, backend=backend)]
    scores = {k: (sm.mad(v, 10), sm.mad(v, 100), sm.itf(v)) for k, v in runs.items()}
    ref = np.array(scores["model"])
    for name in ("cpu", "warp-cpu"):
        np.testing.assert_allclose(scores[name], ref, rtol=0.05, err_msg=name)
    assert scores["model"][1] < sm.mad(bikes, 100)  # and it stabilizes


def test_undistortion_runs_remap_first(bikes):
    K = np.array([[300.0, 0, 160], [0, 300, 68], [0, 0, 1]])
    cfg = st.StabilizerConfig(window=3, camera_matrix=K, dist_coeffs=np.array([-0.2, 0.05, 0, 0]))
    g = st.build_graph((320, 136), cfg)
    assert g.node("undistort").kind == "remap"
    a = [o.image for o in st.stabilize(bikes[:4], cfg, backend="cpu")]
    b = [o.image for o in st.stabilize_model(bikes[:4], cfg)]
    assert np.mean(np.abs(a[-1].astype(int) - b[-1])) < 2.0


def _write_video(path, frames, fps=25):
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, frames[0].shape[1::-1]) \
        if frames else cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (64, 48))
    for f in frames:
        w.write(f)
    w.release()


def test_cli_end_to_end(tmp_path, bikes, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(bikes[:8]):
        cv2.imwrite(str(folder / f"{i:03d}.png"), f)
    out, plot, metrics = tmp_path / "out.avi", tmp_path / "traj.png", tmp_path / "m.json"
    pytest.importorskip("matplotlib")
    rc = cli.main(["stabilize", str(folder), str(out), "--window", "5", "--compare", "--quiet",
                   "--plot", str(plot), "--metrics", str(metrics)])
    assert rc == 0
    cap = cv2.VideoCapture(str(out))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 8
    assert int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) == 2 * 320
    assert plot.stat().st_size > 0
    import json

    report = json.loads(metrics.read_text())
    assert report["frames"] == 8 and report["output"]["mad10"] >= 0


def test_demo_writes_into_a_new_folder(tmp_path):
    folder = tmp_path / "demo"
    assert cli.main(["stabilize", "--demo", str(folder), "--max-frames", "6", "--window", "3",
                     "--quiet"]) == 0
    cap = cv2.VideoCapture(str(folder / "stabilized.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    assert int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) == 2 * 640  # input | output
    import json

    assert json.loads((folder / "metrics.json").read_text())["frames"] == 6


def test_script_runs(tmp_path):
    out = tmp_path / "out.mp4"
    # The checkout first, then whatever made Warp importable here (a staged PYTHONPATH).
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        p for p in (os.path.abspath(ROOT), os.environ.get("PYTHONPATH", "")) if p))
    res = subprocess.run([sys.executable, os.path.join(ROOT, "apps", "stabilize.py"), CLIP, str(out),
                          "--max-frames", "6", "--window", "3", "--quiet"],
                         capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    assert int(cv2.VideoCapture(str(out)).get(cv2.CAP_PROP_FRAME_COUNT)) == 6


@pytest.mark.parametrize("case", ["missing", "unreadable", "empty", "window", "crop", "no output",
                                  "cut_threshold"])
def test_cli_bad_input_is_one_line_exit_2(tmp_path, capsys, case):
    src, extra = CLIP, []
    if case == "missing":
        src = str(tmp_path / "nope.mp4")
    elif case == "unreadable":
        src = tmp_path / "junk.mp4"
        src.write_bytes(b"not a video at all")
    elif case == "empty":
        src = tmp_path / "empty.mp4"
        _write_video(src, [])
    elif case == "window":
        extra = ["--window", "0"]
    elif case == "no output":
        extra = None
    elif case == "cut_threshold":
        extra = ["--cut-threshold", "0"]
    else:
        extra = ["--crop", "0.5"]
    argv = [str(src), "--quiet"] if extra is None else [str(src), str(tmp_path / "o.mp4"), "--quiet"] + extra
    rc = cli.main(["stabilize"] + argv)
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert {"missing": "input", "unreadable": "input", "empty": "input", "window": "window",
            "crop": "crop", "no output": "output", "cut_threshold": "cut_threshold"}[case] in err


# --------------------------------------------------------------------------- scene cuts

BIKES = "/work/shared/data/real/bikes.mp4"  # a montage of 6 real shots (shared data)
CARPHONE = "/work/shared/data/real/carphone_pristine.mp4"  # one real in-car shot (shared data)
ENGINES = [("model", None), ("cpu", "graph"), ("warp-cpu", "graph"), ("warp-cpu", "device")]


def _run(frames, backend="cpu", engine="graph", **config):
    cfg = st.StabilizerConfig(**config)
    if backend == "model":
        return list(st.stabilize_model(frames, cfg))
    return list(st.stabilize(frames, cfg, backend=backend, engine=engine))


@pytest.fixture(scope="module")
def two_shots(astronaut):
    """20 frames of the bundled hand-held street clip, then 20 of a real photo shaken (a
    cut at frame 20): (first shot, whole clip)."""
    first = clip_frames(20)
    second, _, _ = sm.shaky_clip(astronaut, 20, (320, 136), shift=4.0, angle=1.0, zoom=0.01, seed=0)
    return first, first + second


@pytest.mark.parametrize("shift, cut", [(0.29, False), (0.31, True)])
def test_a_motion_moving_a_corner_past_the_threshold_is_a_cut(shift, cut):
    size = (320, 240)
    diagonal = np.hypot(*size)
    move = np.array([[1, 0, shift * diagonal * 0.6], [0, 1, shift * diagonal * 0.8], [0, 0, 1]])
    assert st.is_cut(move, size, 0.3) is cut
    assert st.is_cut(move, size, None) is False  # no detection


def test_a_mirror_and_a_corner_past_infinity_are_cuts():
    size = (320, 240)
    assert st.is_cut(np.array([[-1.0, 0, 319], [0, 1, 0], [0, 0, 1]]), size, 0.3)
    assert st.is_cut(np.array([[1.0, 0, 0], [0, 1, 0], [-0.01, 0, 1]]), size, 0.3)
    assert not st.is_cut(np.eye(3), size, 0.3)


@pytest.mark.parametrize("backend, engine", ENGINES)
def test_scene_cut_is_found_where_the_shots_meet(two_shots, backend, engine):
    out = _run(two_shots[1], backend, engine)
    assert [o.segment for o in out] == [0] * 20 + [1] * 20
    assert np.allclose(out[20].trajectory, np.eye(3))  # the path restarts at the cut


@pytest.mark.parametrize("backend, engine", [("cpu", "graph"), ("warp-cpu", "device")])
def test_frames_before_a_cut_are_the_first_shot_stabilized_alone(two_shots, backend, engine):
    """The smoothing window stops at the cut as it stops at the clip's end."""
    first, clip = two_shots
    alone, together = _run(first, backend, engine), _run(clip, backend, engine)[:20]
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(b.image, a.image, err_msg=f"frame {a.index}")
        np.testing.assert_array_equal(b.warp, a.warp)


def test_each_shot_is_steadier_than_the_input_after_a_cut(two_shots):
    clip = two_shots[1]
    out = [o.image for o in _run(clip)]
    for shot in sm.evaluate_shots(clip, out, [20]):
        assert shot["output"]["stability"] >= shot["input"]["stability"], shot
        assert shot["output"]["itf"] >= shot["input"]["itf"], shot
    # Smoothing across the cut warps frames towards the other shot's path.
    across = [o.image for o in _run(clip, cut_threshold=None)]
    assert sm.itf(out) > sm.itf(across) + 1.0


def test_one_shot_has_no_cut():
    assert {o.segment for o in _run(clip_frames(46))} == {0}


@pytest.mark.skipif(not os.path.isfile(CARPHONE), reason="carphone_pristine.mp4 (shared data) not present")
def test_carphone_has_no_cut():
    frames = list(st.VideoSource(CARPHONE))
    assert {o.segment for o in _run(frames)} == {0}


@pytest.mark.skipif(not os.path.isfile(BIKES), reason="bikes.mp4 (shared data) not present")
def test_montage_cuts_are_found_and_the_clip_is_steadier(tmp_path, capsys):
    """bikes.mp4's first 150 frames hold cuts at 30, 76 and 137 (the data's README)."""
    import json

    metrics = tmp_path / "m.json"
    assert cli.main(["stabilize", BIKES, str(tmp_path / "o.mp4"), "--max-frames", "150",
                     "--metrics", str(metrics)]) == 0
    assert "scene cuts before frames 30, 76, 137" in capsys.readouterr().out
    report = json.loads(metrics.read_text())
    assert report["scene_cuts"] == [30, 76, 137]
    assert [s["frames"] for s in report["shots"]] == [[0, 29], [30, 75], [76, 136], [137, 149]]
    for key in ("stability", "itf"):
        assert report["output"][key] >= report["input"][key], key
