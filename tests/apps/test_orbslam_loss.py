"""Tracking loss in the ORB-SLAM2 front end (warpvx.apps.orbslam.track): lost frames are flagged,
keep finite motion-model poses and never corrupt the frames after them.

Rendered sequences (warpvx.apps.orbslam_synth, exact poses) with forced losses: blank, noise
and flat frames (tracking relocalises against the last keyframe), a camera that stops and then
a cut to another scene (re-initialisation at the carried scale), a long run of blank frames
(constant velocity), a blank stereo frame; and the real bikes clip with its cuts and hand-held shots through the
command line, which diverged to non-finite poses before (frame ~106) and wrote nothing.
"""

from __future__ import annotations

import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tests.images import bgr, gray
from warpvx.apps import orbslam as o
from warpvx.apps import orbslam_batch as ob
from warpvx.apps import orbslam_cli
from warpvx.apps import trajectory_eval as te
from warpvx.apps.orbslam_synth import render_sequence, write_kitti_sequence
from warpvx.errors import WarpvxValueError

ROOT = os.path.join(os.path.dirname(__file__), "..", "..")
BIKES = "/work/shared/data/real/bikes.mp4"
SIZE = (640, 480)


def _track(images, K, batched=False):
    """(poses float64 [N, 4, 4], stats int [N, 5]) of the default monocular front end."""
    frames, camera = [{"image": im} for im in images], o.Camera(K, SIZE)
    run = ob.track_frames_batched(frames, camera, batch=5, workers=1) if batched else o.track_frames(frames, camera)
    out = list(run)
    return np.array([f.pose for f in out]), np.array([[f.stats[k] for k in o.STATS[:5]] for f in out]).astype(int)


def _lost(stats):
    return np.flatnonzero(stats[:, 4] == o.REF_LOST).tolist()


def _orthonormal(poses):
    R = poses[:, :3, :3]
    return np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max()


@pytest.fixture(scope="module")
def moving():
    """24 rendered frames (640x480, 0.08 m a frame forward, sway and turns) and their poses."""
    left, _, K, gt = render_sequence(24, SIZE, step=0.08, supersample=1)
    return left, K, gt


def test_blank_noise_and_flat_frames_are_lost_and_tracking_relocalises(moving):
    left, K, gt = moving
    images = list(left)
    images[9] = np.zeros_like(left[9])
    images[10] = np.random.default_rng(0).integers(0, 256, left[10].shape, dtype=np.uint8)
    images[16] = np.full_like(left[16], 128)
    poses, stats = _track(images, K)
    assert _lost(stats) == [9, 10, 16]
    assert np.isfinite(poses).all() and _orthonormal(poses) < 1e-9
    # The frames after each loss are matched to the last keyframe (reference 1), whose depths
    # keep the scale: the good frames are as accurate as without the losses. Measured: ATE
    # 6.3 mm with the losses, 6.4 mm without.
    assert stats[11, 4] == o.REF_KEYFRAME and stats[17, 4] == o.REF_KEYFRAME
    good = np.setdiff1d(np.arange(len(images)), _lost(stats))
    clean, _ = _track(left, K)
    ate = te.ate(poses[good], gt[good], with_scale=True)["rmse"]
    assert ate < 0.02 and ate < 1.5 * te.ate(clean[good], gt[good], with_scale=True)["rmse"]
    # The lost frames' poses are the motion model's: the last good step repeated.
    step = np.linalg.inv(poses[7]) @ poses[8]
    np.testing.assert_allclose(np.linalg.inv(poses[8]) @ poses[9], step, atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(poses[9]) @ poses[10], step, atol=1e-9)
    # The batched front end carries the same state through track(): the same poses.
    np.testing.assert_allclose(_track(images, K, batched=True)[0], poses, atol=1e-9)


def test_a_long_loss_keeps_constant_velocity_and_finite_poses(moving):
    left, K, _ = moving
    blank = np.zeros_like(left[0])
    poses, stats = _track(list(left[:6]) + [blank] * 60, K)
    assert _lost(stats) == list(range(6, 66))
    assert np.isfinite(poses).all() and _orthonormal(poses) < 1e-9
    step = np.linalg.inv(poses[4]) @ poses[5]
    for a in (6, 30, 64):
        np.testing.assert_allclose(np.linalg.inv(poses[a]) @ poses[a + 1], step, atol=1e-6)


def _other_scene(n):
    """``n`` frames of the same room textured with other real photos (scikit-image's), its poses."""
    tex = [gray(name) for name in ("camera", "brick", "text")]
    tex += [cv2.cvtColor(bgr(name), cv2.COLOR_BGR2GRAY) for name in ("coffee", "chelsea", "rocket")]
    left, _, _, gt = render_sequence(n, SIZE, step=0.08, textures=tex, supersample=1)
    return left, gt


def test_a_stop_then_a_cut_reinitialises_at_the_carried_scale(moving):
    left, K, gt = moving
    b, gt_b = _other_scene(10)
    # 8 frames moving, 3 still (the motion model's velocity drops to zero: before, the step
    # after it took that ~1e-16 length as its scale), then a cut to another scene.
    images = list(left[:8]) + [left[7]] * 3 + list(b)
    poses, stats = _track(images, K)
    assert _lost(stats) == [11]
    assert np.isfinite(poses).all()
    # Re-initialised from frames 11 and 12 at the last scene depth: the new scene's trajectory
    # is right (Sim(3)) and at the scale of the first one. Measured: ATE 8 mm; scales (m per
    # unit) 0.235 and 0.238.
    _, s_a = te.align(poses[:8], gt[:8], True)
    _, s_b = te.align(poses[12:], gt_b[1:], True)
    assert te.ate(poses[12:], gt_b[1:], with_scale=True)["rmse"] < 0.02
    assert s_b == pytest.approx(s_a, rel=0.15)


def test_stereo_blank_frame_is_lost_and_tracking_relocalises():
    left, right, K, gt = render_sequence(12, SIZE, baseline=0.2, supersample=1)
    left[5], right[5] = np.zeros_like(left[5]), np.zeros_like(right[5])
    out = list(o.track_frames([{"image": a, "right": b} for a, b in zip(left, right)], o.Camera(K, SIZE, 0.2)))
    poses = np.array([f.pose for f in out])
    stats = np.array([[f.stats[k] for k in o.STATS[:5]] for f in out]).astype(int)
    assert _lost(stats) == [5] and np.isfinite(poses).all()
    # Frame 6 by PnP on the keyframe's stereo depths: metric. Measured: ATE 2 mm (SE(3)).
    assert stats[6, 4] == o.REF_KEYFRAME
    good = np.setdiff1d(np.arange(12), [5])
    assert te.ate(poses[good], gt[good], with_scale=False)["rmse"] < 0.01


def test_loss_settings_are_checked_by_name():
    with pytest.raises(WarpvxValueError, match="min_inliers"):
        o.TrackerConfig(min_inliers=3)
    with pytest.raises(WarpvxValueError, match="max_speed_jump"):
        o.TrackerConfig(max_speed_jump=1.0)


def test_cli_writes_the_frames_tracked_before_an_error(tmp_path, moving, capsys):
    left, K, gt = moving
    seq = write_kitti_sequence(tmp_path / "seq", left[:5], K, gt[:5])
    cv2.imwrite(str(seq / "image_0" / "000003.png"), np.zeros((10, 10), np.uint8))
    out = tmp_path / "out"
    assert orbslam_cli.main([str(seq), "--out", str(out), "--quiet", "--no-plot"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "10x10" in err[0] and "3 frames before it" in err[0]
    assert te.read_kitti(out / "trajectory.kitti.txt").shape == (3, 4, 4)
    assert len((out / "frames.csv").read_text().splitlines()) == 4


@pytest.mark.skipif(not os.path.isfile(BIKES), reason="bikes.mp4 (shared data) not present")
def test_bikes_clip_with_cuts_through_the_cli_gives_finite_poses(tmp_path):
    out = tmp_path / "bikes"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        p for p in (os.path.abspath(ROOT), os.environ.get("PYTHONPATH", "")) if p)}
    run = subprocess.run([sys.executable, "-m", "warpvx", "orbslam", BIKES, "--intrinsics", "500,500,320,180",
                          "--max-frames", "120", "--out", str(out), "--quiet", "--no-plot"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert run.returncode == 0, run.stderr
    kitti = te.read_kitti(out / "trajectory.kitti.txt")
    _, tum = te.read_trajectory(out / "trajectory.tum.txt")
    assert kitti.shape == (120, 4, 4) and np.isfinite(kitti).all() and np.isfinite(tum).all()
    rows = [r.split(",") for r in (out / "frames.csv").read_text().splitlines()]
    lost = [int(r[0]) for r in rows[1:] if r[rows[0].index("lost")] == "1"]
    # The clip cuts to another shot at frames 30 and 76 (its README): lost there.
    assert {30, 76} <= set(lost) and len(lost) < 60
    assert f"{len(lost)} lost" in run.stdout and f"tracking lost on {len(lost)} of 120 frames" in run.stderr
    # Before, the rotation of the poses blew up through the lost and still frames of the
    # hand-held shots (overflow at frame ~106). The scale still drifts on this footage (guessed
    # intrinsics, moving bikes, little translation): a step is bounded against the median of
    # the last moving steps, a re-initialisation's scene-depth scale too (measured: steps up
    # to ~180 times the first, the relocalisations' corrections; ~5e3 when the bound was the
    # last step alone and re-initialisations were unbounded).
    steps = np.linalg.norm(np.diff(kitti[:, :3, 3], axis=0), axis=1)
    assert steps.max() < 1e3 * steps[0]
