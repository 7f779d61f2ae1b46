"""Trajectory evaluation (warpvx.apps.trajectory_eval): Umeyama, ATE, RPE, KITTI errors, files."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from warpvx.apps import trajectory_eval as te
from warpvx.errors import WarpvxValueError


def _rot(axis, deg):
    import cv2

    return cv2.Rodrigues(np.asarray(axis, float) / np.linalg.norm(axis) * math.radians(deg))[0]


def _path(n=30, seed=0):
    """A hand-made wavy path: camera-to-world poses [n, 4, 4]."""
    rng = np.random.default_rng(seed)
    P = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        P[i, :3, :3] = _rot([0.1, 1, 0.2], 3 * i + rng.normal())
        P[i, :3, 3] = [math.sin(i / 5), 0.1 * i, 0.5 * i]
    return P


def _similar(P, s, R, t):
    Q = P.copy()
    Q[:, :3, :3] = R @ P[:, :3, :3]
    Q[:, :3, 3] = s * P[:, :3, 3] @ R.T + t
    return Q


def test_umeyama_recovers_a_known_similarity():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(50, 3))
    R, s, t = _rot([1, -2, 0.5], 40), 2.5, np.array([1.0, -3.0, 0.25])
    s2, R2, t2 = te.umeyama(X, s * X @ R.T + t)
    assert s2 == pytest.approx(s, rel=1e-9)
    np.testing.assert_allclose(R2, R, atol=1e-9)
    np.testing.assert_allclose(t2, t, atol=1e-9)
    s3, R3, _ = te.umeyama(X, X @ R.T + t, with_scale=False)  # SE(3): no scale
    assert s3 == 1.0
    np.testing.assert_allclose(R3, R, atol=1e-9)


def test_identical_trajectories_have_zero_error():
    P = _path()
    assert te.ate(P, P)["rmse"] == pytest.approx(0, abs=1e-9)
    for d in (1, 10):
        r = te.rpe(P, P, d)
        assert r["trans_rmse"] == pytest.approx(0, abs=1e-9)
        assert r["rot_rmse_deg"] == pytest.approx(0, abs=1e-5)


def test_similar_trajectory_aligns_to_zero_with_sim3_not_with_se3():
    P = _path()
    Q = _similar(P, 0.3, _rot([0, 1, 0], 70), np.array([5.0, 1, 2]))
    a = te.ate(Q, P, with_scale=True)
    assert a["rmse"] == pytest.approx(0, abs=1e-9) and a["scale"] == pytest.approx(1 / 0.3)
    assert te.ate(Q, P, with_scale=False)["rmse"] > 0.1
    # RPE is invariant to a rigid change of world frame; with the Sim(3) scale it is zero.
    assert te.rpe(Q, P, 1, scale=a["scale"])["trans_rmse"] == pytest.approx(0, abs=1e-9)


def test_pure_translation_offset_by_hand():
    # Estimate = ground truth + a constant 0.1 m step error along x per frame: RPE(1) = 0.1.
    P = np.tile(np.eye(4), (11, 1, 1))
    P[:, 2, 3] = np.arange(11)
    Q = P.copy()
    Q[:, 0, 3] = 0.1 * np.arange(11)
    r = te.rpe(Q, P, 1)
    assert r["trans_rmse"] == pytest.approx(0.1) and r["rot_rmse_deg"] == pytest.approx(0)
    assert te.rpe(Q, P, 10)["trans_rmse"] == pytest.approx(1.0)
    assert te.rpe(Q, P, 11) is None


def test_kitti_errors_need_100_m_and_measure_per_metre():
    P = np.tile(np.eye(4), (301, 1, 1))
    P[:, 2, 3] = np.arange(301)  # 1 m a frame
    assert te.kitti_errors(P[:50], P[:50]) is None
    Q = P.copy()
    Q[:, 2, 3] *= 1.02  # 2% too long everywhere
    k = te.kitti_errors(Q, P)
    assert k["t_rel_percent"] == pytest.approx(2.0) and k["r_rel_deg_per_100m"] == pytest.approx(0)
    assert "n/a" in te.evaluate(P[:50], P[:50], True)["kitti"]


@pytest.mark.parametrize("fmt", ["tum", "kitti"])
def test_writers_round_trip(tmp_path, fmt):
    P = _path(12)
    times = np.arange(12) * 0.1 + 1e3
    path = tmp_path / f"t.{fmt}.txt"
    if fmt == "tum":
        te.write_tum(path, times, P)
        t2, P2 = te.read_tum(path)
        np.testing.assert_allclose(t2, times)
        assert len(path.read_text().splitlines()[0].split()) == 8
    else:
        te.write_kitti(path, P)
        P2 = te.read_kitti(path)
    np.testing.assert_allclose(P2, P, atol=1e-6)
    assert te.read_trajectory(path)[1].shape == P.shape


def test_quaternion_round_trip_near_180_degrees():
    for R in (_rot([1, 0, 0], 179.9), _rot([0, 1, 1], 180), np.eye(3), _rot([1, 2, 3], 37)):
        np.testing.assert_allclose(te.matrix_from_quaternion(te.quaternion_from_matrix(R)), R, atol=1e-9)


def test_associate_by_nearest_timestamp():
    gt_t = np.arange(10) * 0.1
    gt = np.tile(np.eye(4), (10, 1, 1))
    gt[:, 0, 3] = np.arange(10)
    idx, poses = te.associate(np.array([0.01, 0.51, 5.0]), gt_t, gt)
    assert idx.tolist() == [0, 1] and poses[:, 0, 3].tolist() == [0, 5]


def test_bad_files_are_clear_errors(tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(WarpvxValueError, match="gt"):
        te.read_trajectory(bad)
    with pytest.raises(WarpvxValueError, match="no such file"):
        te.read_kitti(tmp_path / "none.txt")
    with pytest.raises(WarpvxValueError, match="one length"):
        te.ate(_path(5), _path(6))


@pytest.mark.parametrize("with_scale", [True, False], ids=["sim3", "se3"])
def test_ate_rpe_agree_with_evo(tmp_path, with_scale):
    """Our ATE and RPE (delta 1 and 10) against evo's (``evo_ape`` / ``evo_rpe``'s functions),
    both reading the trajectories from the files our writers produce (KITTI for the ground
    truth, TUM for the estimate): a noisy, scaled, re-framed copy of a wavy path."""
    evo_file = pytest.importorskip("evo.tools.file_interface", reason="evo (test extra) not installed")
    from evo import main_ape, main_rpe
    from evo.core.metrics import PoseRelation, Unit

    rng = np.random.default_rng(7)
    gt = _path(40, seed=3)
    est = _similar(gt, 0.4 if with_scale else 1.0, _rot([1, 2, -1], 35), np.array([2.0, -1, 0.5]))
    for T in est:  # per-pose noise: 2 degrees and 5 cm (x the scale)
        T[:3, :3] = _rot(rng.normal(size=3), rng.normal(0, 2)) @ T[:3, :3]
        T[:3, 3] += rng.normal(0, 0.05, 3)
    times = 0.1 * np.arange(len(gt))
    te.write_kitti(tmp_path / "gt.txt", gt)
    te.write_tum(tmp_path / "est.tum", times, est)
    ref = evo_file.read_kitti_poses_file(str(tmp_path / "gt.txt"))
    traj = evo_file.read_tum_trajectory_file(str(tmp_path / "est.tum"))
    _, gt_read = te.read_trajectory(tmp_path / "gt.txt")
    _, est_read = te.read_trajectory(tmp_path / "est.tum")

    ours = te.evaluate(est_read, gt_read, with_scale)
    # evo's functions may trim the trajectories they are given: each call gets copies.
    ape = main_ape.ape(copy.deepcopy(ref), copy.deepcopy(traj), PoseRelation.translation_part,
                       align=True, correct_scale=with_scale)
    assert ours["ate"]["rmse"] == pytest.approx(ape.stats["rmse"], rel=1e-6)
    assert ours["ate"]["rmse"] > 0.01  # the noise is seen: the comparison is not of zeros
    # RPE of the estimate aligned by evo (the Sim(3) scale in its translations); ours takes
    # every overlapping pair (i, i + d): evo's all_pairs.
    aligned = copy.deepcopy(traj)
    aligned.align(ref, correct_scale=with_scale)
    for d in (1, 10):
        for rel, key in ((PoseRelation.translation_part, "trans_rmse"),
                         (PoseRelation.rotation_angle_deg, "rot_rmse_deg")):
            theirs = main_rpe.rpe(copy.deepcopy(ref), copy.deepcopy(aligned), rel, delta=d,
                                  delta_unit=Unit.frames, all_pairs=True).stats["rmse"]
            assert ours["rpe"][f"delta_{d}"][key] == pytest.approx(theirs, rel=1e-6), (d, key)
