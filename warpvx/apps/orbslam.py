"""ORB-SLAM2's front end (thesis ch. 4, SPEC §8) as a warpvx graph: extraction, matching, motion.

Per frame (``image``, and ``right`` for a stereo sequence)::

    image -> orb (ORB-SLAM2 extractor, GPU role) -> keypoints, descriptors
    descriptors, padded[-1] (a delay) -> match (GPU role: nearest rows both ways) -> padded,
        nearest [, or with a ratio test: match_hamming -> pairs]
    right -> orb_right -> stereo (CPU: ComputeStereoMatches) -> depth per left keypoint
    state[-1] (a delay), keypoints, nearest [, depth] -> track (CPU) -> state, pose, stats

The matching and stereo code is in :mod:`warpvx.apps.orbslam_match`; ``track`` keeps the
mutual best pairs (cross-check) of ``match``'s outputs.

``track`` filters the matches (Hamming distance, ORB-SLAM2's rotation-consistency histogram),
falls back to the last keyframe when the previous frame gives too few, and estimates the motion
from the reference frame: PnP with RANSAC on the reference's stereo 3-D points (metric, the
constant-velocity motion model as the initial guess, ``useExtrinsicGuess``), or for monocular
sequences the essential matrix by MAGSAC++ (OpenCV's USAC) with the cheirality check (as
``cv2.recoverPose``; its four-way choice vectorised).

A monocular camera cannot observe scale: the first step has unit length, and the trajectory
is right up to one global scale -- evaluate it after a Sim(3) alignment. Keeping that one scale
along the sequence is what ORB-SLAM2's map does; here, without a map, the same ingredients:

- depths as map points: each keypoint carries a depth and its variance (from the parallax it
  was triangulated under), carried through the motion to the keypoint it matches in the next
  frame and fused there with the new triangulation (in inverse depth), so depths are refined
  over the frames a point is tracked instead of re-triangulated from one step;
- the step's scale from those depths: the inverse-variance weighted mean of (depth / depth for
  a unit step) over the points seen in both, outliers gated;
- the reference with the most parallax: each keypoint remembers the keyframe keypoint it was
  tracked from, frame to frame; when those tracks give more parallax (median displacement
  times the square root of their count) than the previous frame's matches, the motion is
  estimated from the keyframe (as ORB-SLAM2 triangulates against keyframes), and the points
  matched since then get depths triangulated from the previous frame for the known motion.

Keyframes: every ``keyframe_interval`` frames, when the inliers drop under ``keyframe_ratio``
of those tracked just after the last keyframe, or a lost frame that the next one matches
(a new scene after a cut: the map re-initialises from that pair).

Tracking loss (a cut in a video, a blank or blurred frame), as ORB-SLAM2 detects it: too few
matches or inliers, no essential matrix, or an implausible jump of the step's scale; the lost
frame keeps the constant-velocity pose, the next frame relocalises against the last keyframe
or else re-initialises the depths at the last scene depth (scale continuity); poses stay
finite and their rotations orthonormal (see :func:`track`).

All tracking state is carried from frame to frame through a delay (:class:`TrackState`,
immutable), so every node is a pure function: verification and calibration may run them on
samples, and pipelined frames see the same values as frames run one by one. With
``g.stream(depth >= 2)`` the extraction of frame t+1 (GPU) overlaps the tracking of frame t (CPU
workers); on a machine without CUDA, ``--backend warp-cpu`` gives the GPU role to Warp's CPU device.

Conventions: pixel centres at integers; poses are camera-to-world float64 4x4 (world = first
camera); ``T_cur_ref`` maps points from the reference camera's frame to the current one's.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from ..errors import WarpvxValueError
from .orbslam_depths import (MIN_COMMON, NEW_VAR, backfill, carry_depths, flow, fuse_depths, inv_k, length,
                             lengths, log_depth_var, median, rays, reprojects, row_dots, step_scale)
from .orbslam_match import add_match_node, mutual_pairs, stereo_depth

BACKENDS = ("cpu", "warp-cpu", "cuda")
# ORB-SLAM2's ORBmatcher thresholds (Hamming distance, 256-bit descriptors).
TH_HIGH, TH_LOW = 100, 50
REF_PREVIOUS, REF_KEYFRAME, REF_LOST = 0, 1, 2
# Fewest inliers of a tracked frame (TrackerConfig.min_inliers).
MIN_INLIERS = 12
# Depth (in units of the baseline) beyond which cv2.recoverPose does not count a point.
_FAR = 50.0
STATS = ("n_keypoints", "n_matches", "n_inliers", "keyframe", "reference", "track_ms")


@dataclasses.dataclass(frozen=True)
class TrackerConfig:
    """Parameters of the front end (checked on construction; a warpvx error names the field).

    Attributes
    ----------
    n_features, scale_factor, n_levels, ini_th_fast, min_th_fast
        ORB-SLAM2's extractor (KITTI settings: 2000, 1.2, 8, 20, 7).
    cross_check : bool
        Keep mutual best matches only.
    ratio : float or None
        Lowe's ratio test (ORB-SLAM2's nnratio) when given.
    max_distance : int
        Largest Hamming distance kept (ORB-SLAM2's TH_HIGH = 100; 64 here, tighter since
        frame-to-frame matching has no projection window to restrict the candidates).
    check_orientation : bool
        ORB-SLAM2's rotation-consistency check (``histo_length`` bins of the angle difference,
        the three most populated kept).
    min_matches : int
        Fewer good matches to the previous frame: match to the last keyframe.
    ransac_threshold : float
        Essential-matrix RANSAC threshold (px).
    min_parallax : float
        Median match displacement (px) under which a monocular step is taken as no motion.
    pnp_threshold : float
        PnP RANSAC reprojection threshold (px).
    keyframe_interval, keyframe_ratio
        Keyframe policy (see the module docstring). ORB-SLAM2's ratio is 0.9 of a map's
        tracked points; 0.7 measured best of 0.3, 0.5, 0.7 on rendered sequences (monocular
        ATE), the keyframe being the reference of slow, low-parallax motion.
    stereo_max_distance : int
        Stereo matching's Hamming bound (ORB-SLAM2: (TH_HIGH + TH_LOW) / 2 = 75).
    keyframe_motion : bool
        Monocular: estimate the motion from the last keyframe when the keypoints tracked
        since give more parallax than the previous frame (see the module docstring). Off,
        every frame's motion is from the previous frame, whose essential matrices the
        batched front end (:mod:`~warpvx.apps.orbslam_batch`) works out ahead on its process
        pool: faster there, less accurate on slow, low-parallax motion.
    min_inliers : int
        Fewer essential-matrix (or PnP) inliers: the frame is lost (see :func:`track`).
    max_speed_jump : float
        Monocular: a step whose length per frame is more than this factor above or below the
        last step's (:attr:`TrackState.speed`) is an implausible scale jump: the frame is lost.
    """

    n_features: int = 2000
    scale_factor: float = 1.2
    n_levels: int = 8
    ini_th_fast: int = 20
    min_th_fast: int = 7
    cross_check: bool = True
    ratio: float | None = None
    max_distance: int = 64
    check_orientation: bool = True
    histo_length: int = 30
    min_matches: int = 30
    ransac_threshold: float = 0.5
    min_parallax: float = 1.0
    pnp_threshold: float = 2.0
    keyframe_interval: int = 10
    keyframe_ratio: float = 0.7
    stereo_max_distance: int = (TH_HIGH + TH_LOW) // 2
    keyframe_motion: bool = True
    min_inliers: int = MIN_INLIERS
    max_speed_jump: float = 3.0

    def __post_init__(self):
        from ..check import check_bool, check_float, check_int

        check_bool(self.keyframe_motion, "keyframe_motion")

        check_int(self.n_features, "n_features", min_value=1)
        check_int(self.n_levels, "n_levels", min_value=1)
        check_int(self.max_distance, "max_distance", min_value=0)
        check_int(self.histo_length, "histo_length", min_value=1)
        check_int(self.min_matches, "min_matches", min_value=5)
        check_int(self.keyframe_interval, "keyframe_interval", min_value=1)
        check_int(self.min_inliers, "min_inliers", min_value=6)
        check_float(self.max_speed_jump, "max_speed_jump", min_value=1.0, strict_min=True)
        check_float(self.keyframe_ratio, "keyframe_ratio", min_value=0.0, max_value=1.0)
        check_float(self.ransac_threshold, "ransac_threshold", min_value=0.0, strict_min=True)

    def orb_args(self) -> dict:
        return dict(n_features=self.n_features, scale_factor=self.scale_factor,
                    n_levels=self.n_levels, ini_th_fast=self.ini_th_fast, min_th_fast=self.min_th_fast)


@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole camera: ``K`` float64 3x3, ``size`` (w, h) in px, ``baseline`` (m, stereo
    rectified; None for monocular)."""

    K: np.ndarray
    size: tuple
    baseline: float | None = None

    @property
    def stereo(self) -> bool:
        return self.baseline is not None


# --------------------------------------------------------------------------- matching


def three_maxima(counts) -> list:
    """Indices of the (up to) three most populated histogram bins, as ORB-SLAM2's
    ``ORBmatcher::ComputeThreeMaxima``: the second and third are dropped when they hold under a
    tenth of the first (the third alone when only it does); empty bins never count."""
    m = [0, 0, 0]
    ind = [-1, -1, -1]
    for i, s in enumerate(np.asarray(counts).tolist()):
        if s > m[0]:
            m, ind = [s, m[0], m[1]], [i, ind[0], ind[1]]
        elif s > m[1]:
            m[1:], ind[1:] = [s, m[1]], [i, ind[1]]
        elif s > m[2]:
            m[2], ind[2] = s, i
    if m[1] < 0.1 * m[0]:
        ind[1] = ind[2] = -1
    elif m[2] < 0.1 * m[0]:
        ind[2] = -1
    return [i for i in ind if i >= 0]


def rotation_consistent(angles1, angles2, histo_length: int = 30) -> np.ndarray:
    """bool [M]: the matches whose keypoint angle difference (degrees, ``angles1 - angles2``
    in [0, 360)) falls in one of the three most populated of ``histo_length`` equal bins
    (:func:`three_maxima`). ORB-SLAM2 bins with ``round(rot / histo_length)`` (a factor that
    gives 13 bins of 30 degrees); here the bins are the intended 360 / ``histo_length`` wide."""
    rot = np.mod(np.asarray(angles1, np.float64) - np.asarray(angles2, np.float64), 360.0)
    bins = np.minimum((rot * histo_length / 360.0).astype(np.int64), histo_length - 1)
    keep = three_maxima(np.bincount(bins, minlength=histo_length))
    return np.isin(bins, keep)


def filter_matches(pairs, distances, angles_q, angles_t, config: TrackerConfig) -> np.ndarray:
    """The good (query, train) pairs, int32 [M, 2]: Hamming distance <= ``max_distance``, then
    the rotation-consistency check on the keypoint angles (float [Nq], [Nt], degrees)."""
    pairs = np.asarray(pairs).reshape(-1, 2)
    pairs = pairs[np.asarray(distances).reshape(-1) <= config.max_distance]
    if config.check_orientation and len(pairs):
        pairs = pairs[rotation_consistent(np.asarray(angles_q)[pairs[:, 0]],
                                          np.asarray(angles_t)[pairs[:, 1]], config.histo_length)]
    return pairs


# --------------------------------------------------------------------------- tracking


@dataclasses.dataclass(frozen=True)
class FrameRecord:
    """What tracking keeps of a frame: ``pts`` float64 [N, 2], ``angles`` float [N] (deg),
    ``depth`` float [N] (camera z, m for stereo, the sequence's running scale for monocular;
    NaN unknown) and ``depth_var`` float [N] (variance of its log), ``desc`` uint8 [N, 32]
    (kept for keyframes), ``pose`` 4x4, ``index``, and ``kf_index`` int [N]: the keypoint of
    the last keyframe each one was tracked from, frame to frame (-1 none)."""

    pts: np.ndarray
    angles: np.ndarray
    depth: np.ndarray
    depth_var: np.ndarray
    desc: np.ndarray
    pose: np.ndarray
    index: int
    kf_index: np.ndarray


@dataclasses.dataclass(frozen=True)
class TrackState:
    """Tracking state carried by a delay from frame to frame: the previous frame, the last
    keyframe, the motion model (``velocity`` = T_prev_prevprev, 4x4), the inliers tracked just
    after the keyframe (``keyframe_inliers``), the frame count, and:

    - ``speed``: the length per frame of the last step that moved (at the map's scale; the
      first step's is 1): the yardstick of an implausible scale jump, and the step a
      monocular frame whose reference has no depths takes when the motion model's is
      implausible (~0 after a stop);
    - ``scene_depth``: the median depth of the last frame with depths (at the map's scale;
      NaN none yet), the scale a re-initialisation after a loss keeps;
    - ``lost``: how many frames in a row up to the previous one were lost;
    - ``speeds``: the lengths per frame of the last :data:`SPEED_HISTORY` steps that moved:
      their median is the yardstick of an implausible scale jump (the last step alone let a
      run of steps, each up to ``max_speed_jump`` times the one before, compound: a hand-held
      clip's steps grew 5000x in 120 frames)."""

    frames: int = 0
    previous: FrameRecord | None = None
    keyframe: FrameRecord | None = None
    velocity: np.ndarray = dataclasses.field(default_factory=lambda: np.eye(4))
    keyframe_inliers: int = 0
    speed: float = 1.0
    scene_depth: float = np.nan
    lost: int = 0
    speeds: tuple = ()


#: Moving steps whose median length bounds the next step's (:attr:`TrackState.speeds`).
SPEED_HISTORY = 10


def _inv(T):
    R, t = T[:3, :3], T[:3, 3]
    out = np.empty((4, 4))
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


def _orthonormal(T):
    """``T`` (4x4) with its rotation projected onto SO(3) (the nearest rotation, by SVD).
    :func:`_inv` transposes the rotation: on one that is orthonormal only to rounding, a pose
    composed with its own inverse again and again (lost frames, frames that did not move)
    doubles the rounding each time, and the rotation blows up within ~50 frames."""
    u, _, vt = np.linalg.svd(T[:3, :3])
    out = T.copy()
    out[:3, :3] = u @ vt
    return out


def _rt(R, t):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t).reshape(3)
    return T


def _pose_pnp(ref, cur_pts, pairs, K, guess, config):
    """T_cur_ref by PnP RANSAC on the reference's 3-D points; (T, inlier count) or None."""
    import cv2

    z = ref.depth[pairs[:, 1]]
    ok = np.isfinite(z) & (z > 0)
    if ok.sum() < 6:
        return None
    p = ref.pts[pairs[ok, 1]]
    X = rays(p, inv_k(K)) * z[ok, None]
    rvec, _ = cv2.Rodrigues(guess[:3, :3])
    tvec = guess[:3, 3].reshape(3, 1).copy()
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        X, cur_pts[pairs[ok, 0]], K, None, rvec, tvec, useExtrinsicGuess=True,
        iterationsCount=100, reprojectionError=config.pnp_threshold, confidence=0.99,
        flags=cv2.SOLVEPNP_ITERATIVE)
    if not found or inliers is None or len(inliers) < 6:
        return None
    return _rt(cv2.Rodrigues(rvec)[0], tvec), len(inliers), None


def _ray_depths(x1, x2, R, t):
    """Depths (z1, z2), float64 [M] each, of the points whose normalised rays are ``x1`` in the
    reference camera and ``x2`` in the current one (float64 [M, 3], z = 1), for the motion
    X_cur = R X_ref + t: the least-squares solution of z2 x2 = z1 R x1 + t (midpoint
    triangulation); z2 is the current depth of the point on the reference ray. NaN when the
    rays are parallel."""
    a = x1 @ R.T
    aa, bb, ab = row_dots(a, a), row_dots(x2, x2), row_dots(a, x2)
    at, bt = a @ t, x2 @ t
    with np.errstate(divide="ignore", invalid="ignore"):
        z1 = (ab * bt - bb * at) / (aa * bb - ab * ab)
    return z1, z1 * a[:, 2] + t[2]


def _cheirality(E, x1, x2):
    """(R, t) of the four motions that decompose ``E``: the one with the most points in front
    of both cameras, as ``cv2.recoverPose`` chooses (depth in (0, ``_FAR``) in both, unit
    baseline; midpoint depths, vectorised, instead of its four DLT triangulations)."""
    import cv2

    R1, R2, t = cv2.decomposeEssentialMat(E)
    best = None
    for R, tt in ((R1, t), (R2, t), (R1, -t), (R2, -t)):
        tt = tt.reshape(3)
        z1, z2 = _ray_depths(x1, x2, R, tt)
        front = np.count_nonzero((z1 > 0) & (z1 < _FAR) & (z2 > 0) & (z2 < _FAR))
        if best is None or front > best[0]:
            best = front, R, tt
    return best[1:]


def _triangulate_known(ref, cur_pts, pairs, T, K):
    """Depths of matched points for a known motion ``T`` (T_cur_ref, at the map's scale):
    midpoint triangulation of the ``pairs`` (this frame's index, the reference's), kept where
    in front of both cameras, reprojecting near this frame's keypoint (:func:`reprojects`),
    seen under enough parallax (``NEW_VAR``), then :func:`fuse_depths`, whose result it returns."""
    Kinv = inv_k(K)
    x1, x2 = rays(ref.pts[pairs[:, 1]], Kinv), rays(cur_pts[pairs[:, 0]], Kinv)
    R, t = T[:3, :3], T[:3, 3]
    z1, z2 = _ray_depths(x1, x2, R, t)
    with np.errstate(invalid="ignore"):  # parallel rays' depths are not finite: X too, not ok
        X = (x1 * z1[:, None]) @ R.T + t
    ok = (z1 > 0) & (z2 > 0) & reprojects(X, K, cur_pts[pairs[:, 0]])
    var = log_depth_var(x1[ok], x2[ok], R, K[0, 0])
    keep = var <= NEW_VAR
    ok[ok] = keep
    return fuse_depths(ref, pairs[ok], x1[ok], x2[ok], R, t, X[ok, 2], K[0, 0], var[keep])


def essential_core(p1, p2, K, config):
    """The state-free core of a monocular step: the motion between matched points ``p1``
    (reference) and ``p2`` (current), float64 [M, 2] px, for intrinsics ``K`` (float64 3x3,
    contiguous): the essential matrix by MAGSAC++, the cheirality check and the DLT
    triangulation of its inliers. Returns (R float64 3x3, t float64 [3] unit length, inl int
    [F] indices into the matches of the F points in front of both cameras, z_ref, z_cur
    float64 [F] their depths in units of the baseline, x1, x2 float64 [F, 3] their normalised
    rays (:func:`~warpvx.apps.orbslam_depths.rays`) in the reference and current camera, var
    float64 [F] their log-depth variances (:func:`~warpvx.apps.orbslam_depths.log_depth_var`):
    what the tracking chain needs of them, worked out off it) or None (no model, fewer than 8 in
    front). Depends only on its arguments (the batched front end runs it in worker processes:
    :mod:`warpvx.apps.orbslam_batch`)."""
    import cv2

    # MAGSAC++ (OpenCV's USAC): ~10x fewer hypotheses than plain RANSAC at this threshold,
    # and more accurate (its inlier scoring is not a hard 0/1 at the threshold).
    E, mask = cv2.findEssentialMat(p1, p2, K, cv2.USAC_MAGSAC, 0.999, config.ransac_threshold)
    if E is None or E.shape != (3, 3):
        return None
    inl = np.flatnonzero(mask.reshape(-1))
    Kinv = inv_k(K)
    x1, x2 = rays(p1[inl], Kinv), rays(p2[inl], Kinv)
    R, t = _cheirality(E, x1, x2)
    # The points in front, as recoverPose counts them: DLT triangulation, depth in (0, 50).
    X = cv2.triangulatePoints(np.eye(3, 4), np.c_[R, t], x1[:, :2].T, x2[:, :2].T)
    X = (X[:3] / X[3]).T
    z_ref, z_cur = X[:, 2], X @ R[2] + t[2]
    front = (z_ref > 0) & (z_ref < _FAR) & (z_cur > 0) & (z_cur < _FAR)
    if np.count_nonzero(front) < 8:
        return None
    inl = inl[front]
    x1, x2 = rays(p1[inl], Kinv), rays(p2[inl], Kinv)
    return R, t, inl, z_ref[front], z_cur[front], x1, x2, log_depth_var(x1, x2, R, K[0, 0])


def parallax_points(ref_pts, cur_pts, pairs, config):
    """(p1, p2, moved): the reference's and this frame's points float64 [M, 2] of ``pairs``
    (this frame's index, the reference's), and whether their median displacement reaches
    ``config.min_parallax`` px (else the frame did not move: no essential matrix)."""
    p1, p2 = ref_pts[pairs[:, 1]], cur_pts[pairs[:, 0]]
    return p1, p2, not median(lengths(p2 - p1)) < config.min_parallax


def _pose_essential(ref, cur_pts, pairs, K, config, essential=essential_core, *, parallax=parallax_points,
                    step=1.0, scene_depth=np.nan, bounds=(0.0, np.inf)):
    """T_cur_ref from the essential matrix (:func:`essential_core`, or ``essential`` with its
    signature and results; the points by :func:`parallax_points` or ``parallax``, likewise),
    the translation scaled by the reference's depths
    (:func:`~warpvx.apps.orbslam_depths.step_scale`); when too few are shared (the first
    step, a re-initialisation after a loss), scaled so that the median depth of the points is
    ``scene_depth`` (that of the last frame with depths, as ORB-SLAM2 scales a new map by its
    median depth), or to length ``step`` when there is none (NaN). Returns (T, inliers, (this
    frame's indices, depths, log-depth variances)) or None (no model, or a scale from depths
    outside ``bounds``, (low, high): an implausible jump; a scene depth's scale outside them
    takes ``step``): the depths of the points in front
    (:func:`~warpvx.apps.orbslam_depths.fuse_depths`), or the reference's when it did not
    move."""
    p1, p2, moved = parallax(ref.pts, cur_pts, pairs, config)
    if not moved:
        return np.eye(4), len(pairs), (pairs[:, 0], ref.depth[pairs[:, 1]], ref.depth_var[pairs[:, 1]])
    core = essential(p1, p2, K, config)
    if core is None:
        return None
    R, t, inl, z_ref, z_cur, x1, x2, var = core
    scale = step_scale(ref, pairs[inl], x1, x2, R, z_ref, K[0, 0], np.nan, var)
    if np.isnan(scale):
        scale = scene_depth / median(z_cur) if np.isfinite(scene_depth) else step
        if not bounds[0] <= scale <= bounds[1]:
            # A re-initialisation whose scene depth implies an implausible step (the new
            # scene is nearer or farther): the step the motion model allows, as without depths.
            scale = step
    elif not bounds[0] <= scale <= bounds[1]:
        return None
    tri = fuse_depths(ref, pairs[inl], x1, x2, R, scale * t, scale * z_cur, K[0, 0], var)
    return _rt(R, scale * t), len(inl), tri


def _record(pts, angles, desc, depth, depth_var, pose, index, kf_index):
    return FrameRecord(pts, angles, depth, depth_var, np.asarray(desc), pose, index, kf_index)


def keypoint_xy(kps):
    """(positions float64 [N, 2], angles float64 [N] (deg)) of keypoints ``kps``: what
    :class:`FrameRecord` keeps of them."""
    return np.stack([np.asarray(kps.x, np.float64), np.asarray(kps.y, np.float64)], 1), \
        np.asarray(kps.angle, np.float64)


def keyframe_pairs(kf_pts, prev_pts, prev_kf_index, prev_is_kf: bool, cur_pts, good, config):
    """(tracked, pairs): ``tracked`` int [G], the keyframe keypoint each pair of ``good`` (this
    frame's index, the previous frame's; the filtered matches) reaches through the previous
    frame's ``prev_kf_index`` (-1: none); ``pairs`` int [M, 2] (this frame's index, the
    keyframe's) when the monocular motion is to be taken from the keyframe (``keyframe_motion``
    on, the previous frame not the keyframe, enough tracks, and more parallax x sqrt(count)
    than the previous frame's matches), else None. Points float64 [N, 2]."""
    tracked = prev_kf_index[good[:, 1]]
    on = tracked >= 0
    count = np.count_nonzero(on)
    if not config.keyframe_motion or prev_is_kf or count < config.min_matches:
        return tracked, None
    pairs = np.stack([good[on, 0], tracked[on]], 1)
    if flow(kf_pts, cur_pts, pairs) * np.sqrt(count) > flow(prev_pts, cur_pts, good) * np.sqrt(len(good)):
        return tracked, pairs
    return tracked, None


def keyframe_due(since: int, inliers: int, kf_inliers: int, config) -> bool:
    """A tracked frame becomes the keyframe (the policy of :class:`TrackerConfig`): ``since``
    frames after the last keyframe, with ``inliers`` against its reference and the last
    keyframe's ``kf_inliers`` (:func:`track`'s rule, which the batched front end's look-ahead
    follows)."""
    return since >= config.keyframe_interval or inliers < config.keyframe_ratio * kf_inliers


def track(state: TrackState, kps, desc, pairs, distances, depth=None, *, K,
          config: TrackerConfig = TrackerConfig(), essential=essential_core, good=None, points=None,
          tracks=keyframe_pairs, parallax=parallax_points):
    """One frame of tracking (the graph's ``track`` node; pure).

    A frame is lost when it has fewer than 8 good matches, no motion model (no essential
    matrix, fewer than 8 points in front, PnP failing), fewer than ``config.min_inliers``
    inliers, a non-finite motion, or (monocular) a step whose length per frame jumps by more
    than ``config.max_speed_jump`` from :attr:`TrackState.speed`: its pose is then the
    constant-velocity guess, the velocity and speed are kept, and the last keyframe stays: the
    next frame, matching the lost one poorly, is matched to that keyframe (relocalised), or
    else, matching the lost frame (a new scene), makes that frame the keyframe and
    re-initialises the depths from the pair at the carried scene depth.

    Parameters
    ----------
    state : TrackState
        The previous frame's state (a delay).
    kps, desc : Keypoints [N], uint8 [N, 32]
        This frame's ORB features.
    pairs, distances : int32 [M, 2], int32 [M]
        ``match_hamming(desc, previous desc)``: (this frame's index, previous frame's index).
    depth : float32 [N], optional
        Stereo depth (m) of each keypoint, NaN unknown; None for monocular.
    K : float64 3x3
        Intrinsics.
    essential : callable
        :func:`essential_core` or a stand-in with its results (the batched front end's look-up
        of cores computed ahead in worker processes).
    tracks : callable
        :func:`keyframe_pairs` or a stand-in with its signature and results (the batched front
        end's look-up of the tracks its keyframe speculation worked out).
    parallax : callable
        :func:`parallax_points` or a stand-in with its signature and results (the batched front
        end's look-up of those worked out ahead with the cores).
    good : int [G, 2], optional
        ``filter_matches`` of ``pairs`` when already worked out (the batched front end's
        worker processes do); else filtered here.
    points : tuple, optional
        :func:`keypoint_xy` of ``kps`` when already worked out (the batched front end's
        ``pose_batch`` does): its arrays become this frame's record's (not copied).

    Returns
    -------
    state : TrackState
    pose : float64 4x4
        Camera-to-world pose of this frame.
    stats : float64 [6]
        n_keypoints, n_matches, n_inliers, keyframe (0/1), reference (0 previous frame,
        1 keyframe, 2 lost: the motion model's pose), milliseconds in this node.
    """
    t0 = time.perf_counter()
    # Contiguous: OpenCV's USAC estimators return no model for a strided K (a view of P0).
    K = np.ascontiguousarray(K, np.float64)
    n = len(kps)
    stereo = depth is not None
    cur_depth = np.asarray(depth, np.float64) if stereo else np.full(n, np.nan)
    # Stereo depths weigh alike (their disparities are not kept); monocular ones are unknown.
    cur_var = np.full(n, 1.0 / K[0, 0] ** 2 if stereo else np.inf)
    cur_pts, angles = keypoint_xy(kps) if points is None else points
    if state.previous is None:
        rec = _record(cur_pts, angles, desc, cur_depth, cur_var, np.eye(4), state.frames, np.arange(n))
        new = TrackState(state.frames + 1, rec, rec, np.eye(4), 0)
        return new, np.eye(4), np.array([n, 0, 0, 1, REF_PREVIOUS, 1e3 * (time.perf_counter() - t0)])
    prev, kf = state.previous, state.keyframe
    if good is None:
        good = filter_matches(pairs, distances, angles, prev.angles, config) if n else np.zeros((0, 2), int)
    if state.lost and len(good) >= config.min_matches:
        # Re-initialisation after a loss (a new scene): the lost frame, which this one matches,
        # becomes the keyframe and gets its depths from this pair (backfill, below).
        kf, kf_inliers = prev, 0
    else:
        kf_inliers = state.keyframe_inliers
    ref, reference, prev_good = prev, REF_PREVIOUS, good
    _, kf_good = tracks(kf.pts, prev.pts, prev.kf_index, kf.index == prev.index, cur_pts, good, config)
    if not stereo and kf_good is not None:
        # Monocular motion from the last keyframe, through the keypoints tracked since, as
        # ORB-SLAM2 triangulates against keyframes: several frames of parallax where the
        # previous frame alone gives little (the essential matrix then degenerates).
        good, ref, reference = kf_good, kf, REF_KEYFRAME
    elif len(good) < config.min_matches and kf.index != prev.index and n:
        import warpvx

        kp, kd = warpvx.match_hamming(np.asarray(desc), kf.desc, config.cross_check, config.ratio,
                                      backend="cpu")
        kgood = filter_matches(kp, kd, angles, kf.angles, config)
        if len(kgood) > len(good):
            good, ref, reference = kgood, kf, REF_KEYFRAME
    from_kf = ref is kf  # (the previous frame may be the keyframe)
    # Constant-velocity guess of T_cur_ref: T_cur_prev = velocity, T_prev_ref from the poses.
    guess = state.velocity @ _inv(prev.pose) @ ref.pose
    result = None
    if len(good) >= 8:
        if stereo:
            result = _pose_pnp(ref, cur_pts, good, K, guess, config)
        if result is None:
            back, jump = state.frames - ref.index, config.max_speed_jump
            expected = state.speed * back
            yardstick = (median(np.asarray(state.speeds)) if state.speeds else state.speed) * back
            bounds = (yardstick / jump, yardstick * jump)
            # The scale when the reference has no depths: after a loss, the last scene depth's
            # (the motion model is a guess there); else the motion model's step, unless it is
            # implausible (a stop gives ~0: carry the last step's length). Measured: the
            # scene depth in place of the motion model while tracking is worse (ATE 10.6 mm
            # against 9.3 on the 60-frame seed-5 sequence of benchmarks/orbslam_accuracy.py).
            step = length(guess[:3, 3])
            step = step if bounds[0] <= step <= bounds[1] else expected
            result = _pose_essential(ref, cur_pts, good, K, config, essential, parallax=parallax, step=step,
                                     scene_depth=state.scene_depth if state.lost else np.nan, bounds=bounds)
    if result is not None and (result[1] < config.min_inliers or not np.isfinite(result[0]).all()):
        result = None
    if result is None:
        # Lost (too few matches or inliers, no model, an implausible scale jump): the motion
        # model's pose, as ORB-SLAM2 keeps it, and no depths. Composed from the
        # previous pose (not through the reference) and orthonormal: a run of lost frames
        # must not compound rounding (see _orthonormal).
        inliers, reference = 0, REF_LOST
        pose, velocity, speed = _orthonormal(prev.pose @ _inv(state.velocity)), state.velocity, state.speed
    else:
        T, inliers, tri = result
        if not stereo and tri is not None:
            idx, cur_depth[idx], cur_var[idx] = tri
            carry_depths(ref, cur_pts, good, T, K, cur_depth, cur_var)
            if from_kf and not state.lost:
                # The points matched since the keyframe only: from the previous frame (not a
                # lost one: its pose is a guess).
                rest = prev_good[np.isnan(cur_depth[prev_good[:, 0]])]
                idx, z, v = _triangulate_known(prev, cur_pts, rest, T @ _inv(kf.pose) @ prev.pose, K)
                cur_depth[idx], cur_var[idx] = z, v
            if from_kf and np.isnan(kf.depth).all():
                # A keyframe without depths (the first, or one after a loss): as ORB-SLAM2's
                # map initialisation, both frames of its first triangulation get them.
                kf = backfill(kf, cur_pts, good, T, K, cur_depth, cur_var)
        pose = _orthonormal(ref.pose @ _inv(T))
        velocity = _inv(pose) @ prev.pose
        moved = length(T[:3, 3]) / (state.frames - ref.index)
        speed = moved if moved > 0 else state.speed
    speeds = (*state.speeds, moved)[-SPEED_HISTORY:] if result is not None and moved > 0 else state.speeds
    since = state.frames - kf.index
    kf_inliers = kf_inliers or inliers
    lost = reference == REF_LOST
    # A lost frame keeps the last keyframe: the next frame relocalises against it, as
    # ORB-SLAM2 does against its keyframes, unless it matches the lost frame (see above).
    is_kf = not lost and keyframe_due(since, inliers, kf_inliers, config)
    if is_kf:
        kf_index = np.arange(n)
    else:
        kf_index = np.full(n, -1)
        if not lost:  # (no keyframe tracks through a lost frame)
            kf_index[good[:, 0]] = good[:, 1] if from_kf else prev.kf_index[good[:, 1]]
    rec = _record(cur_pts, angles, desc, cur_depth, cur_var, pose, state.frames, kf_index)
    known = cur_depth[np.isfinite(cur_depth)]
    scene_depth = median(known) if len(known) >= MIN_COMMON else state.scene_depth
    new = TrackState(state.frames + 1, rec, rec if is_kf else kf, velocity, 0 if is_kf else kf_inliers, speed,
                     scene_depth, state.lost + 1 if lost else 0, speeds)
    stats = np.array([n, len(good), inliers, float(is_kf), reference, 1e3 * (time.perf_counter() - t0)])
    return new, pose, stats


def track_nearest(state: TrackState, kps, desc, nearest, distance, back, depth=None, *, K,
                  config: TrackerConfig = TrackerConfig()):
    """:func:`track` fed by the ``match`` node's nearest rows both ways (see
    :func:`~warpvx.apps.orbslam_match.mutual_pairs`) instead of the pairs."""
    n_prev = 0 if state.previous is None else len(state.previous.pts)
    pairs, distances = mutual_pairs(nearest, distance, back, len(kps), n_prev)
    return track(state, kps, desc, pairs, distances, depth, K=K, config=config)


# --------------------------------------------------------------------------- the graph


def spread_cpu_nodes(dag):
    """Scheduling policy for pipelined frames: ``best`` (HEFT/XEFT), then, when there are at
    least as many CPU workers as CPU nodes, each CPU node on a worker of its own (same
    predicted times: CPU workers share memory and costs). A single-frame schedule stacks
    dependent CPU nodes (``stereo`` -> ``track``) on one worker; in a stream that worker then
    runs both for every frame, where two workers run ``stereo`` of frame t+1 beside ``track``
    of frame t. Falls back to ``best``'s schedule if the spread one is not feasible."""
    from .. import sched
    from ..errors import ScheduleError

    best = sched.schedule(dag, "best")
    cpus = [p for p in best.processors if p.startswith("cpu")]
    on_cpu = sorted((t for t in best.tasks.values() if t.processor in cpus), key=lambda t: t.start)
    if len(on_cpu) < 2 or len(on_cpu) > len(cpus):
        return best
    tasks = dict(best.tasks)
    for t, cpu in zip(on_cpu, cpus):
        tasks[t.task] = sched.ScheduledTask(t.task, cpu, t.start, t.finish)
    spread = sched.Schedule(tasks, best.processors, "spread", best.priority,
                            dict(best.info, chosen=f"{best.info.get('chosen', 'best')}, spread"))
    try:
        sched.validate_schedule(dag, spread)
    except ScheduleError:
        return best
    return spread


def schedule(graph, backend="cpu"):
    """Place the front-end graph (:func:`spread_cpu_nodes` on CPU workers, plus the Warp
    device unless ``backend`` is ``"cpu"``); returns the plan."""
    return graph.schedule(spread_cpu_nodes, gpu=False if backend == "cpu" else backend)


def build_graph(camera: Camera, config: TrackerConfig = TrackerConfig(), *, backend="cpu"):
    """The front-end graph for gray uint8 frames of ``camera.size``.

    Inputs: ``image`` (uint8 HxW) and, for a stereo camera, ``right``. Outputs: ``pose``
    (float64 4x4, camera to world) and ``stats`` (float64 [6], see :func:`track`).
    ``backend``: ``"cpu"`` runs every node on CPU workers; ``"warp-cpu"``/``"cuda"`` pins the
    extractors and the matcher to the Warp device (the GPU role); ``stereo`` and ``track``
    are CPU user nodes. With ``cross_check`` and no ``ratio`` (the defaults) the ``match``
    node finds the nearest rows both ways and ``track`` keeps the mutual best pairs (no host
    sync on the device); otherwise it is the ``match_hamming`` primitive.
    """
    from ..check import check_choice
    from ..graph import Graph

    check_choice(backend, "backend", BACKENDS)
    w, h = camera.size
    pin = None if backend == "cpu" else "gpu"
    g = Graph("orbslam")
    image = g.input("image", shape=(h, w), dtype=np.uint8)
    kps, desc = g.orb(image, **config.orb_args(), name="orb", target=pin)
    if config.cross_check and config.ratio is None:
        # Mutual best pairs from the nearest rows both ways (no host sync, see orbslam_match).
        nearest = add_match_node(g, desc, target=pin)
        track_fn = track_nearest
    else:
        nearest = g.match_hamming(desc, g.delay(desc)[-1], cross_check=config.cross_check,
                                  ratio=config.ratio, name="match", target=pin)
        track_fn = track
    extra = []
    if camera.stereo:
        right = g.input("right", shape=(h, w), dtype=np.uint8)
        kps_r, desc_r = g.orb(right, **config.orb_args(), name="orb_right", target=pin)
        extra = [g.user(functools.partial(stereo_depth, fx=float(camera.K[0, 0]),
                                          baseline=float(camera.baseline),
                                          scale_factor=config.scale_factor,
                                          max_distance=config.stereo_max_distance),
                        [kps, desc, kps_r, desc_r, image, right], name="stereo")]
    state = g.virtual("state")
    previous = g.delay(state, init=TrackState())[-1]
    _, pose, stats = g.user(functools.partial(track_fn, K=camera.K, config=config),
                            [previous, kps, desc, *nearest] + extra, [state, "pose", "stats"],
                            name="track")
    g.output("pose", pose)
    g.output("stats", stats)
    return g


@dataclasses.dataclass
class TrackedFrame:
    """One tracked frame: ``index``, ``pose`` (float64 4x4 camera to world), ``stats``
    (dict of :data:`STATS`), ``ms`` (wall time since the previous frame came out)."""

    index: int
    pose: np.ndarray
    stats: dict
    ms: float


def track_frames(frames, camera: Camera, config: TrackerConfig = TrackerConfig(), *,
                 backend="cpu", depth: int = 2, on_finish=None):
    """Run the front-end graph over ``frames`` (an iterable of input dicts: ``image`` and, for
    stereo, ``right``; gray uint8); a generator of :class:`TrackedFrame` in order. ``depth``
    frames in flight (>= 2 overlaps extraction of frame t+1 with tracking of frame t).
    ``on_finish(plan)``, if given, is called with the scheduler's plan after the last frame
    (for its placement, predicted vs measured makespans and Gantt charts)."""
    frames = iter(frames)
    first = [f for _, f in zip(range(2), frames)]
    if not first:
        raise WarpvxValueError("frames: the sequence has no frames")
    g = build_graph(camera, config, backend=backend)
    # Verify on two real frames so calibration times matching and tracking on real motion.
    g.verify(first if len(first) == 2 else first[0])
    plan = schedule(g, backend)

    def feed():
        yield from first
        yield from frames

    t = time.perf_counter()
    with g:
        for k, out in enumerate(g.stream(feed(), depth=depth)):
            now = time.perf_counter()
            stats = dict(zip(STATS, out["stats"].tolist()))
            yield TrackedFrame(k, out["pose"], stats, 1e3 * (now - t))
            t = now
        if on_finish is not None:
            on_finish(plan)


# --------------------------------------------------------------------------- the OpenCV baseline


def baseline_step(cur, prev, matcher, K) -> np.ndarray:
    """One step of the OpenCV baseline: T_cur_prev (4x4, unit translation; identity when it
    fails) from ``(keypoints, descriptors)`` of ``detectAndCompute`` for both frames."""
    import cv2

    (kp, des), (kp0, des0) = cur, prev
    if des is None or des0 is None:
        return np.eye(4)
    m = matcher.match(des, des0)
    if len(m) < 8:
        return np.eye(4)
    p2 = np.float64([kp[x.queryIdx].pt for x in m])
    p1 = np.float64([kp0[x.trainIdx].pt for x in m])
    E, mask = cv2.findEssentialMat(p1, p2, K, cv2.RANSAC, 0.999, 1.0)
    if E is None or E.shape != (3, 3):
        return np.eye(4)
    _, R, t, _ = cv2.recoverPose(E, p1, p2, K, mask=mask)
    return _rt(R, t)


def opencv_baseline(images, K):
    """The monocular front end a user writes with OpenCV alone (the issue's baseline):
    ``cv2.ORB_create(2000, 1.2, 8)``, ``BFMatcher(NORM_HAMMING, crossCheck=True)``,
    ``findEssentialMat`` (RANSAC) + ``recoverPose``, poses chained with unit steps. Returns
    camera-to-world poses float64 [N, 4, 4]."""
    import cv2

    orb = cv2.ORB_create(2000, 1.2, 8)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    poses, prev = [np.eye(4)], None
    for img in images:
        cur = orb.detectAndCompute(img, None)
        if prev is not None:
            poses.append(poses[-1] @ _inv(baseline_step(cur, prev, bf, K)))
        prev = cur
    return np.asarray(poses[:len(images)])


__all__ = [
    "TrackerConfig", "Camera", "TrackState", "FrameRecord", "TrackedFrame", "three_maxima",
    "rotation_consistent", "filter_matches", "stereo_depth", "essential_core", "keyframe_due", "track", "track_nearest",
    "build_graph",
    "spread_cpu_nodes", "keyframe_pairs", "schedule", "track_frames", "opencv_baseline", "baseline_step", "BACKENDS", "STATS",
]
