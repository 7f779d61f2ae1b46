"""Camera trajectories: TUM and KITTI files, Umeyama alignment, ATE, RPE and KITTI's t_rel/r_rel.

Conventions: a trajectory is float64 [N, 4, 4] camera-to-world poses ``T_wc`` (a point in camera
coordinates ``X_c`` is at ``T_wc @ X_c`` in the world), translations in the units of the
sequence (metres for KITTI, TUM; arbitrary for monocular estimates). Rotations in degrees
wherever an error is reported.

References: Umeyama 1991 ("Least-squares estimation of transformation parameters between two
point patterns"); Sturm et al. 2012 (the TUM RGB-D benchmark's ATE and RPE); Geiger et al. 2012
(the KITTI odometry devkit's t_rel, r_rel over 100..800 m segments). The ``evo`` package
computes the same numbers (``evo_ape``/``evo_rpe`` with ``--align [--correct_scale]``).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ..errors import WarpvxValueError

#: Segment lengths (m) of KITTI's odometry devkit.
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


# --------------------------------------------------------------------------- rotations


def quaternion_from_matrix(R) -> np.ndarray:
    """Unit quaternion (qx, qy, qz, qw), qw >= 0, of a 3x3 rotation matrix (float64 [4])."""
    R = np.asarray(R, np.float64)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s, s / 4]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(max(1.0 + R[i, i] - R[j, j] - R[k, k], 1e-300))
        q = [0.0, 0.0, 0.0, (R[k, j] - R[j, k]) / s]
        q[i] = s / 4
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
    q = np.asarray(q)
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quaternion(q) -> np.ndarray:
    """3x3 rotation (float64) of a quaternion (qx, qy, qz, qw), normalized first."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def rotation_angle(R) -> float:
    """Angle of a rotation matrix, degrees in [0, 180]."""
    c = (np.trace(np.asarray(R)[:3, :3]) - 1.0) / 2.0
    return math.degrees(math.acos(min(1.0, max(-1.0, c))))


# --------------------------------------------------------------------------- files


def _poses(poses, name="poses") -> np.ndarray:
    P = np.asarray(poses, np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or len(P) == 0:
        raise WarpvxValueError(f"{name}: expected float [N, 4, 4] poses (N >= 1), got shape {P.shape}")
    if not np.isfinite(P).all():
        raise WarpvxValueError(f"{name}: poses must be finite")
    return P


def write_tum(path, times, poses) -> None:
    """Write ``timestamp tx ty tz qx qy qz qw`` lines (TUM RGB-D format) for [N] times and
    [N, 4, 4] camera-to-world poses."""
    P = _poses(poses)
    with open(path, "w") as f:
        for t, T in zip(np.asarray(times, np.float64), P):
            q = quaternion_from_matrix(T[:3, :3])
            f.write(" ".join(f"{v:.9g}" for v in (t, *T[:3, 3], *q)) + "\n")


def write_kitti(path, poses) -> None:
    """Write the first three rows of each [N, 4, 4] pose, row-major, 12 numbers a line (KITTI)."""
    P = _poses(poses)
    with open(path, "w") as f:
        for T in P:
            f.write(" ".join(f"{v:.9e}" for v in T[:3].reshape(-1)) + "\n")


def _rows(path, what):
    if not os.path.isfile(path):
        raise WarpvxValueError(f"{what}: no such file {os.fspath(path)!r}")
    rows = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            try:
                rows.append([float(v) for v in line.replace(",", " ").split()])
            except ValueError:
                raise WarpvxValueError(f"{what}: {os.fspath(path)!r} line {n}: not numbers: {line[:60]!r}") from None
    if not rows:
        raise WarpvxValueError(f"{what}: {os.fspath(path)!r} holds no pose")
    return rows


def read_kitti(path, what="gt") -> np.ndarray:
    """Poses of a KITTI file (12 numbers a line), float64 [N, 4, 4]."""
    rows = _rows(path, what)
    if any(len(r) != 12 for r in rows):
        raise WarpvxValueError(f"{what}: {os.fspath(path)!r}: expected 12 numbers a line (KITTI)")
    P = np.tile(np.eye(4), (len(rows), 1, 1))
    P[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    return P


def read_tum(path, what="gt") -> tuple:
    """(times float64 [N], poses float64 [N, 4, 4]) of a TUM file (8 numbers a line)."""
    rows = _rows(path, what)
    if any(len(r) != 8 for r in rows):
        raise WarpvxValueError(f"{what}: {os.fspath(path)!r}: expected 8 numbers a line "
                               f"(timestamp tx ty tz qx qy qz qw)")
    a = np.asarray(rows)
    P = np.tile(np.eye(4), (len(a), 1, 1))
    P[:, :3, 3] = a[:, 1:4]
    for T, q in zip(P, a[:, 4:8]):
        T[:3, :3] = matrix_from_quaternion(q)
    return a[:, 0], P


def read_trajectory(path, what="gt") -> tuple:
    """(times or None, poses [N, 4, 4]) of a KITTI (12 numbers) or TUM (8 numbers) file."""
    first = _rows(path, what)[0]
    if len(first) == 12:
        return None, read_kitti(path, what)
    if len(first) == 8:
        return read_tum(path, what)
    raise WarpvxValueError(f"{what}: {os.fspath(path)!r}: expected KITTI (12 numbers a line) or "
                           f"TUM (8 numbers a line) poses, got {len(first)} numbers")


def associate(times, gt_times, gt_poses, max_dt=0.02) -> tuple:
    """Indices into ``times`` and the matching ground-truth poses, nearest timestamp within
    ``max_dt`` seconds (TUM's ``associate.py``). Returns (int [M], float64 [M, 4, 4])."""
    times = np.asarray(times, np.float64)
    gt_times = np.asarray(gt_times, np.float64)
    n = len(gt_times)
    hi = np.clip(np.searchsorted(gt_times, times), 0, n - 1)
    lo = np.clip(hi - 1, 0, n - 1)
    j = np.where(np.abs(gt_times[lo] - times) <= np.abs(gt_times[hi] - times), lo, hi)
    ok = np.abs(gt_times[j] - times) <= max_dt
    return np.flatnonzero(ok), gt_poses[j[ok]]


# --------------------------------------------------------------------------- alignment


def umeyama(src, dst, with_scale: bool = True) -> tuple:
    """The similarity (s, R, t) minimizing sum ||dst_i - (s R src_i + t)||^2 (Umeyama 1991).

    ``src``, ``dst``: float [N, 3] corresponding points (N >= 3, not all collinear for a
    unique R). ``with_scale`` False fixes s = 1 (SE(3)). Returns (float, float64 3x3, float64 [3]).
    """
    X = np.asarray(src, np.float64).reshape(-1, 3)
    Y = np.asarray(dst, np.float64).reshape(-1, 3)
    if len(X) != len(Y) or len(X) < 3:
        raise WarpvxValueError(f"src, dst: expected two [N, 3] point sets of one length N >= 3, "
                               f"got {len(X)} and {len(Y)}")
    mx, my = X.mean(0), Y.mean(0)
    Xc, Yc = X - mx, Y - my
    cov = Yc.T @ Xc / len(X)
    U, d, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var = (Xc ** 2).sum() / len(X)
    s = float(np.trace(np.diag(d) @ S) / var) if with_scale and var > 0 else 1.0
    return s, R, my - s * R @ mx


def align(est, gt, with_scale: bool) -> tuple:
    """``est`` [N, 4, 4] mapped onto ``gt`` by the Umeyama similarity of their positions:
    (aligned poses [N, 4, 4] with scaled translations, s)."""
    s, R, t = umeyama(est[:, :3, 3], gt[:, :3, 3], with_scale)
    out = est.copy()
    out[:, :3, :3] = R @ est[:, :3, :3]
    out[:, :3, 3] = s * est[:, :3, 3] @ R.T + t
    return out, s


def _pair(est, gt):
    est, gt = _poses(est, "est"), _poses(gt, "gt")
    if len(est) != len(gt):
        raise WarpvxValueError(f"est, gt: expected trajectories of one length, got {len(est)} and {len(gt)}")
    return est, gt


def ate(est, gt, with_scale: bool = True) -> dict:
    """Absolute trajectory error: RMSE (and mean, median, max) of the position residuals after
    aligning ``est`` onto ``gt`` (Sim(3) when ``with_scale``, else SE(3)); plus the scale."""
    est, gt = _pair(est, gt)
    if len(est) < 3:
        raise WarpvxValueError(f"est: ATE needs at least 3 poses, got {len(est)}")
    aligned, s = align(est, gt, with_scale)
    e = np.linalg.norm(aligned[:, :3, 3] - gt[:, :3, 3], axis=1)
    return {"rmse": float(np.sqrt((e ** 2).mean())), "mean": float(e.mean()),
            "median": float(np.median(e)), "max": float(e.max()), "scale": s}


def rpe(est, gt, delta: int = 1, scale: float = 1.0) -> dict | None:
    """Relative pose error over ``delta`` frames (Sturm et al. 2012): for each i,
    E_i = (Q_i^-1 Q_{i+d})^-1 (P_i^-1 P_{i+d}) with ground truth Q and estimate P (its
    translations times ``scale``, the Sim(3) scale for monocular estimates). Returns RMSE of
    the translation parts (units of gt) and of the rotation angles (degrees), with the count;
    None when the trajectory is shorter than ``delta`` + 1."""
    est, gt = _pair(est, gt)
    if len(est) <= delta:
        return None
    P = est.copy()
    P[:, :3, 3] *= scale
    inv = np.linalg.inv
    dt, dr = [], []
    for i in range(len(P) - delta):
        E = inv(inv(gt[i]) @ gt[i + delta]) @ (inv(P[i]) @ P[i + delta])
        dt.append(np.linalg.norm(E[:3, 3]))
        dr.append(rotation_angle(E))
    dt, dr = np.asarray(dt), np.asarray(dr)
    return {"delta": delta, "pairs": len(dt), "trans_rmse": float(np.sqrt((dt ** 2).mean())),
            "rot_rmse_deg": float(np.sqrt((dr ** 2).mean()))}


def path_length(poses) -> float:
    """Length of the camera path (sum of the position steps)."""
    p = np.asarray(poses)[:, :3, 3]
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def kitti_errors(est, gt, scale: float = 1.0, lengths=KITTI_LENGTHS, step: int = 10) -> dict | None:
    """KITTI odometry devkit errors: over segments of each length in ``lengths`` (m) starting
    every ``step`` frames, the relative pose error per metre; averaged. Returns ``t_rel`` (%)
    and ``r_rel`` (deg per 100 m), or None when the path is shorter than the shortest length."""
    est, gt = _pair(est, gt)
    P = est.copy()
    P[:, :3, 3] *= scale
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :3, 3], axis=0), axis=1))])
    inv = np.linalg.inv
    te, re = [], []
    for first in range(0, len(gt), step):
        for length in lengths:
            last = int(np.searchsorted(d, d[first] + length))
            if last >= len(gt):
                continue
            E = inv(inv(gt[first]) @ gt[last]) @ (inv(P[first]) @ P[last])
            te.append(np.linalg.norm(E[:3, 3]) / length)
            re.append(math.radians(rotation_angle(E)) / length)
    if not te:
        return None
    return {"t_rel_percent": 100.0 * float(np.mean(te)),
            "r_rel_deg_per_100m": math.degrees(float(np.mean(re))) * 100.0, "segments": len(te)}


def evaluate(est, gt, with_scale: bool, deltas=(1, 10)) -> dict:
    """ATE, RPE for each delta, and KITTI's t_rel/r_rel (or the reason they are n/a), as a
    JSON-ready dict. ``with_scale``: Sim(3) alignment (monocular) or SE(3) (stereo)."""
    a = ate(est, gt, with_scale)
    out = {"alignment": "Sim(3)" if with_scale else "SE(3)", "frames": len(est), "ate": a,
           "rpe": {f"delta_{d}": rpe(est, gt, d, a["scale"]) or "n/a: sequence too short"
                   for d in deltas},
           "gt_path_length": path_length(gt)}
    k = kitti_errors(est, gt, a["scale"])
    out["kitti"] = k if k is not None else (
        f"n/a: the ground-truth path ({out['gt_path_length']:.3g}) is shorter than "
        f"{KITTI_LENGTHS[0]:.0f} m, KITTI's shortest segment")
    return out


def save_plot(path, est, gt=None, title="trajectory") -> None:
    """Top view (x, z) of ``est`` [N, 4, 4], against ``gt`` when given (``est`` already
    aligned), as a PNG. Needs matplotlib."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise WarpvxValueError("plot: matplotlib is not installed (pip install 'warpvx[plot]')") from None
    fig, ax = plt.subplots(figsize=(6, 6))
    if gt is not None:
        ax.plot(gt[:, 0, 3], gt[:, 2, 3], "k-", label="ground truth")
    ax.plot(est[:, 0, 3], est[:, 2, 3], "-", color="tab:red", label="estimate")
    ax.plot(est[:1, 0, 3], est[:1, 2, 3], "o", color="tab:red")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


__all__ = ["quaternion_from_matrix", "matrix_from_quaternion", "rotation_angle", "write_tum",
           "write_kitti", "read_tum", "read_kitti", "read_trajectory", "associate", "umeyama",
           "align", "ate", "rpe", "path_length", "kitti_errors", "evaluate", "save_plot",
           "KITTI_LENGTHS"]
