"""Monocular depths kept as ORB-SLAM2's map points keep them, for :mod:`warpvx.apps.orbslam`.

A monocular front end sees the scale of the scene only through the depths it has triangulated
so far; these helpers keep one scale along a sequence. Each keypoint of a frame carries a
depth (camera z, the sequence's running scale; NaN unknown) and the variance of its log (from
the parallax it was triangulated under, 1 px on a ray): a step's length is taken from those
depths (:func:`step_scale`), and each point's depth is carried through the motion to the
keypoint it matches in the next frame and fused there with the new triangulation
(:func:`fuse_depths`, :func:`carry_depths`), so depths are refined over the frames a point is
tracked instead of re-triangulated from one step. Frames are
:class:`~warpvx.apps.orbslam.FrameRecord`; rays are normalised (z = 1) float64 [M, 3];
``pairs`` are int [M, 2] (this frame's keypoint, the reference's).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

# Monocular scale: the fewest points with a depth to take a step's scale from, and the gate
# (standard deviations) past which a depth ratio is an outlier.
MIN_COMMON, GATE = 5, 3.0
# Reprojection error (px) within which a matched point keeps its depth (see carry_depths).
CARRY_PX = 2.0
# Largest log-depth variance (10 % depth error) of a point triangulated for a known motion:
# less parallax than that and its depth (1 / parallax, biased long) does more harm than good.
NEW_VAR = 0.1 ** 2


def median(x) -> float:
    """``np.median`` of a 1-D float array without NaNs (the same value, bit for bit: the middle
    element, or the mean of the two middle ones), without its generic-axis overhead: the
    tracking chain takes several per frame. NaN when empty."""
    n = len(x)
    if n == 0:
        return float("nan")
    k = n // 2
    if n % 2:
        return float(np.partition(x, k)[k])
    part = np.partition(x, (k - 1, k))
    return float((part[k - 1] + part[k]) / 2)


def row_dots(a, b):
    """Row dot products, float64 [M], of ``a`` and ``b`` float64 [M, D] (``(a * b).sum(1)``, the
    same sums, without the method's Python wrapper: the chain takes several per frame)."""
    return np.add.reduce(a * b, axis=1)


def lengths(v):
    """Row lengths, float64 [M], of ``v`` float64 [M, D] (``np.linalg.norm(v, axis=1)``, the
    same sums, without its argument handling)."""
    return np.sqrt(row_dots(v, v))


def length(v) -> float:
    """``float(np.linalg.norm(v))`` of a float64 vector (a translation), bit for bit (the same
    contiguous copy and dot product), without its argument handling."""
    v = v.ravel(order="K")
    return math.sqrt(v.dot(v))


def inv_k(K):
    """``np.linalg.inv(K)`` of the intrinsics (float64 3x3), computed once per camera: the
    tracking of one frame needs it several times."""
    return _inv_of(np.ascontiguousarray(K, np.float64).tobytes())


@functools.lru_cache(maxsize=16)  # (a few cameras; bounded, unlike a plain dict)
def _inv_of(k_bytes: bytes):
    Kinv = np.linalg.inv(np.frombuffer(k_bytes, np.float64).reshape(3, 3))
    Kinv.flags.writeable = False  # shared by every caller
    return Kinv


def rays(pts, Kinv):
    """Normalised rays (z = 1), float64 [M, 3], of the pixels ``pts`` float64 [M, 2] (``Kinv``:
    :func:`inv_k`)."""
    h = np.empty((len(pts), 3))
    h[:, :2] = pts
    h[:, 2] = 1.0
    return h @ Kinv.T


def log_depth_var(x1, x2, R, f):
    """Variance of log depth, float64 [M], of points triangulated from the normalised rays
    ``x1`` (reference) and ``x2`` (current), float64 [M, 3], for the rotation ``R``: a ray's
    direction is known to 1 px (1/``f`` rad), so the relative depth error is that over the sine
    of the parallax angle (points near the epipole, seen under little parallax, weigh little)."""
    a = x1 @ R.T
    cos = row_dots(a, x2) / (lengths(a) * lengths(x2))
    return 1.0 / (f * f * np.maximum(1.0 - cos * cos, 1e-12))


def robust_mean(r, var):
    """Inverse-variance weighted mean of the positive ratios ``r`` (float64 [M]; ``var`` the
    variance of log ``r``) over those within ``GATE`` standard deviations of the weighted
    median (mismatches, moving points); NaN when none."""
    w = 1.0 / var
    order = np.argsort(r)
    cw = np.cumsum(w[order])
    med = r[order[np.searchsorted(cw, 0.5 * cw[-1])]]
    keep = np.abs(np.log(r / med)) <= GATE * np.sqrt(var)
    return float((w[keep] * r[keep]).sum() / w[keep].sum()) if keep.any() else float("nan")


def step_scale(ref, pairs, x1, x2, R, z_ref, f, step, var=None):
    """The scale of a monocular step from the essential matrix (unit translation): the
    inverse-variance weighted mean of (reference depth / ``z_ref``) over the ``pairs`` (this
    frame's index, the reference's) whose reference keypoint has a depth (log-depth variances
    of both, from the parallax of the rays ``x1``, ``x2``: :func:`log_depth_var`); ``step``
    when fewer than ``MIN_COMMON``. The ratio is linear in the inverse depth, which is linear
    in the parallax: a triangulated depth itself (1 / parallax) is biased long, and log or
    median ratios of it shrink the scale a little at every step. ``var``: :func:`log_depth_var`
    of all the rays when the caller has it."""
    prior = ref.depth[pairs[:, 1]]
    common = np.isfinite(prior) & (prior > 0) & (z_ref > 0)
    if np.count_nonzero(common) < MIN_COMMON:
        return step
    own = log_depth_var(x1[common], x2[common], R, f) if var is None else var[common]
    var = own + ref.depth_var[pairs[common, 1]]
    scale = robust_mean(prior[common] / z_ref[common], var)
    return scale if np.isfinite(scale) else step


def fuse_depths(ref, pairs, x1, x2, R, t, depth, f, var=None):
    """This frame's depths of triangulated points, refined as map points are.

    ``pairs`` (this frame's index, the reference's), their rays ``x1``, ``x2`` (float64
    [M, 3]), the motion ``R``, ``t`` (reference to current, at the map's scale) and the
    triangulated depths ``depth`` in this frame. Where the reference had a depth, it is
    carried through the motion and fused with the new one, linearly in inverse depth, with
    inverse-variance weights (:func:`log_depth_var`), unless they differ by more than
    ``GATE`` standard deviations; so depths are refined over the frames a point is tracked
    and the scale stays tied to long-lived points instead of the last triangulation alone (a
    random walk of the scale). ``var``: :func:`log_depth_var` of the rays when the caller has
    it. Returns (this frame's indices, depths, log-depth variances)."""
    var = log_depth_var(x1, x2, R, f) if var is None else var.copy()
    prior, prior_var = ref.depth[pairs[:, 1]], ref.depth_var[pairs[:, 1]]
    pred = prior * (x1 @ R[2]) + t[2]  # z of R (prior x1) + t
    ok = np.isfinite(pred) & (pred > 0)
    ok[ok] = np.abs(np.log(pred[ok] / depth[ok])) <= GATE * np.sqrt(prior_var[ok] + var[ok])
    rho1, rho2 = 1.0 / pred[ok], 1.0 / depth[ok]  # inverse depths: var(rho) = rho^2 var(log z)
    w1, w2 = 1.0 / (rho1 ** 2 * prior_var[ok]), 1.0 / (rho2 ** 2 * var[ok])
    rho = (w1 * rho1 + w2 * rho2) / (w1 + w2)
    depth = depth.copy()
    depth[ok] = 1.0 / rho
    var[ok] = 1.0 / ((w1 + w2) * rho ** 2)
    return pairs[:, 0], depth, var


def reprojects(X, K, pts):
    """bool [M]: the points ``X`` (float64 [M, 3], camera frame) project within ``CARRY_PX``
    of the keypoints ``pts`` (float64 [M, 2])."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return lengths((X @ K.T)[:, :2] / X[:, 2:] - pts) <= CARRY_PX


def carry_depths(ref, cur_pts, pairs, T, K, depth, depth_var):
    """Carry the reference's depths through the motion ``T`` (T_cur_ref) to the matched points
    of this frame that got none from the triangulation (``depth`` NaN; both arrays updated in
    place): those that reproject within ``CARRY_PX`` of their keypoint keep their depth and its
    variance, as a map point stays in the map while it is tracked. Without this a point drops
    out at the first step where it is not an essential-matrix inlier, and the scale is taken
    from ever newer points."""
    prior = ref.depth[pairs[:, 1]]
    ok = np.isfinite(prior) & np.isnan(depth[pairs[:, 0]])
    if not ok.any():
        return
    p = pairs[ok]
    X = rays(ref.pts[p[:, 1]], inv_k(K)) * prior[ok, None]
    X = X @ T[:3, :3].T + T[:3, 3]
    near = (X[:, 2] > 0) & reprojects(X, K, cur_pts[p[:, 0]])
    depth[p[near, 0]] = X[near, 2]
    depth_var[p[near, 0]] = ref.depth_var[p[near, 1]]


def flow(ref_pts, cur_pts, pairs):
    """Median displacement (px) of the matched keypoints ``pairs`` (this frame's, the reference's)."""
    return median(lengths(cur_pts[pairs[:, 0]] - ref_pts[pairs[:, 1]]))


def backfill(kf, cur_pts, pairs, T, K, depth, depth_var):
    """The keyframe ``kf`` with depths for its keypoints that had none, from this frame's
    (``depth``, ``depth_var`` of this frame's keypoints ``cur_pts``, float64 [N, 2];
    ``pairs``: this frame's index, the keyframe's; ``T``: T_cur_kf). A keyframe's points are
    triangulated only by the frames after it: without this, a keyframe stays without depths
    for the points it first saw, and the frames referred to it take their scale from the
    motion model."""
    i, j = pairs[:, 0], pairs[:, 1]
    ok = np.isnan(kf.depth[j]) & np.isfinite(depth[i])
    if not ok.any():
        return kf
    i, j = i[ok], j[ok]
    X = rays(cur_pts[i], inv_k(K)) * depth[i, None]
    z = (X - T[:3, 3]) @ T[:3, 2]  # z of T^-1 X: R^T (X - t), third row
    front = z > 0
    d, v = kf.depth.copy(), kf.depth_var.copy()
    d[j[front]], v[j[front]] = z[front], depth_var[i[front]]
    return dataclasses.replace(kf, depth=d, depth_var=v)


__all__ = ["median", "row_dots", "lengths", "length", "inv_k", "rays", "backfill",
           "log_depth_var", "robust_mean", "step_scale", "fuse_depths", "reprojects",
           "carry_depths", "flow"]
