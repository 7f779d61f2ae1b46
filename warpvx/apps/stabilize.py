"""Video stabilizer: thesis §3.2 (Fig. 3.2, Listing 3.2), NVIDIA VisionWorks' ``video_stabilizer``.

The algorithm, as a warpvx :class:`~warpvx.Graph` (:func:`build_graph`) and as plain OpenCV
calls (the imperative "model", :func:`stabilize_model`, thesis §2's multi-level verification)::

    frame -> [undistort: remap] -> gray -> Gaussian pyramid ---------------------.
                                     \\-> detect (Harris or FAST)                  |
    pyramid[-1], points[-1] (delays) -> pyramidal LK -> [park_lost -> ransac]
    tracked + detections -> refresh_points -> points (delayed to the next frame)
    motion (one host node, :func:`follow_motion`): estimate_motion (H: k-1 -> k),
      cut test, accumulate (trajectory T_k: the shot's first frame -> frame k, T and shot index
      over N frames in delays),
      smooth, truncate (crop) -> warp_perspective

Conventions: images are BGR uint8 HxWx3; points float32 [N, 2] (x, y), pixel centres at
integers; matrices float64 3x3 mapping column vectors (x, y, 1). ``H_k`` maps frame k-1 to frame
k, ``T_k = H_k ... H_1`` maps frame 0 (the first frame of k's shot, after a scene cut) to
frame k. The stabilizing warp of frame j is
``S_j = (sum_i w_i T_i T_j^-1) / sum_i w_i`` (the smoothed path over the actual one, averaged
element-wise as VisionWorks' matrix smoother does), then scaled about the centre by
``1 / (1 - 2 crop)`` and, if it would uncover the border, pulled towards the identity.

Scene cuts (:func:`is_cut`): a motion no camera makes in one frame step (a frame corner moved
by more than ``cut_threshold`` of the frame diagonal, or sent to or past the line at infinity)
is the jump between two shots, not shake. There the trajectory restarts (``T_k = I``) and
the segment index (0 for the first shot) steps up; each segment is smoothed on its own, the
frames of other segments in the window counting as absent, as frames beyond the clip's ends
do. A clip without cuts is one segment, smoothed as a whole.

Smoothing windows (``window`` N frames, ``r = N // 2``, Gaussian weights of sigma 0.7 r):

* ``centered`` -- the thesis / VisionWorks form: weights over frames j-r .. j+r, frame j is
  warped when frame j+r arrives, so the output lags r frames; the last r frames are flushed
  with the window shrinking at the end (the weights of missing frames are dropped).
* ``causal`` -- no look-ahead, what a live camera needs: one-sided weights over frames
  k-N+1 .. k, frame k is warped at once (a smoothed path that trails the camera a little).

Either way the output has one frame per input frame, in order (frame k shows input frame k).

Conditional re-detection in a data-flow graph: the detector runs every frame (as VisionWorks'
``nvxHarrisTrack`` does) and the user node ``refresh_points`` keeps the LK-tracked points,
topping them up with fresh detections away from them only when fewer than ``min_tracked``
survived.

The motion model: homography by RANSAC (the thesis), similarity
(``cv2.estimateAffinePartial2D``) or translation (median displacement), by
:func:`estimate_motion` in the host node ``motion``, except the homography on a Warp backend: there
the lost points are parked far off the image on the device (``park_lost``) and the :func:`warpvx.find_homography`
primitive runs on the device too (``ransac``), so the frame and the points stay there; only the
3x3 matrix comes back for the ``motion`` node (:func:`as_motion`). The graph on ``cpu`` calls the
primitive's CPU backend, the model ``cv2.findHomography``: the same OpenCV call.

Engines (:func:`stabilize`'s ``engine``): the graph above, the reference, on every backend;
and on the Warp backends the device engine (:mod:`warpvx.apps.stabilize_device`), the same
algorithm with the point set, re-detection, RANSAC and the 3x3 chain on the device too,
replayed per frame as one CUDA graph with frames in flight (1 upload and 1 download per
frame). It gives the graph's frames (bit for bit on warp-cpu on the bundled clip); ``auto``
picks it where it applies (homography motion, Harris detector).
"""

from __future__ import annotations

import dataclasses
import functools
from collections import deque

import numpy as np

from ..errors import WarpvxValueError
from .placement import schedule
from .video_io import VideoSource, open_writer  # noqa: F401  (public API: frames in, video out)

MOTIONS = ("homography", "similarity", "translation")
MODES = ("causal", "centered")
DETECTORS = ("harris", "fast")
BACKENDS = ("cpu", "warp-cpu", "cuda")
ENGINES = ("auto", "graph", "device")

# Fewest matched points that determine each motion model.
_MIN_POINTS = {"homography": 4, "similarity": 2, "translation": 1}
_NAN3 = np.full((3, 3), np.nan)
LOST = -1.0e5  # where park_lost moves the points LK lost (px, x and y)
# Off-image points, the padding of point sets to the 4 a homography needs (find_homography
# refuses fewer): LK reports them lost (status 0). Empty point sets are avoided too, because
# Warp reports empty arrays as non-contiguous.
_NO_POINTS = np.full((4, 2), -1e4, np.float32)
_SEGMENT0 = np.zeros(1, np.int64)  # the segment index before the video


@dataclasses.dataclass(frozen=True)
class StabilizerConfig:
    """Parameters of the stabilizer (checked on construction; a warpvx error names the field).

    Attributes
    ----------
    window : int
        Smoothing window N >= 1 in frames (centred: r = N // 2 on each side).
    mode : str
        ``"centered"`` (thesis, lags r frames) or ``"causal"`` (no look-ahead).
    crop : float
        Fraction R in [0, 0.5) cut from each side: the output is scaled about the centre by
        1 / (1 - 2R). 0 disables the border clamp (black borders may show).
    motion : str
        ``"homography"`` (RANSAC, thesis), ``"similarity"`` or ``"translation"``.
    detector : str
        ``"harris"`` (goodFeaturesToTrack-style) or ``"fast"``.
    max_corners, quality_level, min_distance : int, float, float
        Harris detection (also the cap and spacing of the merged point set).
    fast_threshold : int
        FAST threshold (gray levels).
    min_tracked : int
        Re-detect when fewer tracked points survive.
    levels, lk_win : int
        Pyramid levels (LK uses levels - 1 as its highest) and LK window side (px).
    ransac_threshold : float
        RANSAC reprojection threshold (px).
    ransac_iters : int
        RANSAC hypotheses (OpenCV stops earlier once 99.5% confident; the Warp backends score
        all of them). LK tracks of one frame pair are mostly inliers: 500 still finds an
        all-inlier sample with 99% confidence at 30% inliers, at a quarter of the device
        cost of OpenCV's default 2000.
    camera_matrix, dist_coeffs : array, optional
        3x3 intrinsics and OpenCV distortion coefficients: undistort every frame first.
    cut_threshold : float or None
        Scene cut detection (:func:`is_cut`): an inter-frame motion moving a frame corner by
        more than this fraction (> 0) of the frame diagonal starts a new segment. Real
        hand-held motion moves corners by under 0.14 (bikes.mp4), the cuts there by 0.52 or
        more. None: no detection (one segment).
    """

    window: int = 15
    mode: str = "centered"
    crop: float = 0.1
    motion: str = "homography"
    detector: str = "harris"
    max_corners: int = 400
    quality_level: float = 0.001
    min_distance: float = 8.0
    fast_threshold: int = 20
    min_tracked: int = 150
    levels: int = 3
    lk_win: int = 21
    ransac_threshold: float = 3.0
    ransac_iters: int = 500
    camera_matrix: object = None
    dist_coeffs: object = None
    cut_threshold: float | None = 0.3

    def __post_init__(self):
        from ..check import check_choice, check_float, check_int

        check_int(self.window, "window", min_value=1)
        check_choice(self.mode, "mode", MODES)
        crop = check_float(self.crop, "crop", min_value=0.0)
        if crop >= 0.5:
            raise WarpvxValueError(f"crop: expected a value in [0, 0.5), got {crop}")
        check_choice(self.motion, "motion", MOTIONS)
        check_choice(self.detector, "detector", DETECTORS)
        check_int(self.max_corners, "max_corners", min_value=1)
        check_int(self.min_tracked, "min_tracked", min_value=0)
        check_int(self.levels, "levels", min_value=1)
        check_int(self.lk_win, "lk_win", min_value=3)
        check_int(self.ransac_iters, "ransac_iters", min_value=1)
        if self.cut_threshold is not None:
            check_float(self.cut_threshold, "cut_threshold", min_value=0.0, strict_min=True)
        if (self.camera_matrix is None) != (self.dist_coeffs is None):
            raise WarpvxValueError("camera_matrix, dist_coeffs: give both or neither")

    @property
    def lag(self) -> int:
        """Frames of output latency: r in centred mode, 0 in causal mode."""
        return self.window // 2 if self.mode == "centered" else 0

    def weights(self) -> np.ndarray:
        """Smoothing weights, float64, oldest frame first (2r + 1 centred, N causal)."""
        r = self.window // 2
        offsets = np.arange(-r, r + 1) if self.mode == "centered" else np.arange(1 - self.window, 1)
        if r == 0:
            return np.ones(len(offsets))
        return np.exp(-0.5 * (offsets / (0.7 * r)) ** 2)


# --------------------------------------------------------------------------- node functions
# Pure functions shared by the graph's user nodes and the imperative model.


def estimate_motion(prev_pts, next_pts, status, *, model="homography", threshold=3.0,
                    max_iters=500, backend=None):
    """The inter-frame motion from matched points: float64 3x3 mapping ``prev_pts`` to ``next_pts``.

    ``prev_pts``, ``next_pts``: float32 [N, 2]; ``status``: uint8 [N] (1 = tracked). Models:
    homography by RANSAC (reprojection threshold ``threshold`` px, ``max_iters`` hypotheses),
    similarity (RANSAC) or translation (median displacement). Identity when too few points or no model is found.
    ``backend``: None calls ``cv2.findHomography`` (the model), a name runs
    :func:`warpvx.find_homography` there.
    """
    ok = np.asarray(status).reshape(-1).astype(bool)
    p = np.asarray(prev_pts, np.float32).reshape(-1, 2)[ok]
    q = np.asarray(next_pts, np.float32).reshape(-1, 2)[ok]
    finite = np.isfinite(p).all(1) & np.isfinite(q).all(1)
    p, q = p[finite], q[finite]
    if len(p) < _MIN_POINTS[model]:
        return np.eye(3)
    import cv2

    if model == "homography" and backend is not None:
        from ..homography import find_homography

        H, _ = find_homography(p, q, ransac_reproj_threshold=threshold, max_iters=max_iters,
                               backend=backend)
    elif model == "homography":
        H, _ = cv2.findHomography(p, q, cv2.RANSAC, threshold, maxIters=max_iters,
                                  confidence=0.995)
    elif model == "similarity":
        A, _ = cv2.estimateAffinePartial2D(p, q, method=cv2.RANSAC, ransacReprojThreshold=threshold)
        H = None if A is None else np.vstack([A, [0.0, 0.0, 1.0]])
    else:
        H = np.eye(3)
        H[:2, 2] = np.median(q - p, axis=0)
    return as_motion(H)


def as_motion(H):
    """``H`` (3x3) normalised to ``H[2, 2] = 1`` (float64); the identity for no model (None,
    :func:`warpvx.find_homography`'s zeros, non-finite or singular)."""
    H = None if H is None else np.asarray(H, np.float64)
    if H is None or not np.isfinite(H).all() or H[2, 2] == 0 or abs(np.linalg.det(H)) < 1e-9:
        return np.eye(3)
    return H / H[2, 2]


def park_lost(next_pts, status):
    """``next_pts`` (float32 [N, 2]) with every lost point (``status`` 0) moved to one point
    :data:`LOST` far off the image, so :func:`warpvx.find_homography` can take all N points
    (no host filtering): a homography is invertible, so it maps at most one of them there
    (one inlier at most), and a sample of parked points is degenerate."""
    pts = np.array(next_pts, np.float32).reshape(-1, 2)
    pts[np.asarray(status).reshape(-1) == 0] = LOST
    return pts


@functools.cache
def _park_lost_kernel():
    import warp as wp

    @wp.kernel
    def park_lost_kernel(pts: wp.array2d(dtype=wp.float32), status: wp.array(dtype=wp.uint8),
                         out: wp.array2d(dtype=wp.float32)):
        i = wp.tid()
        lost = status[i] == wp.uint8(0)
        out[i, 0] = wp.where(lost, wp.float32(LOST), pts[i, 0])
        out[i, 1] = wp.where(lost, wp.float32(LOST), pts[i, 1])

    return park_lost_kernel


def _park_lost_warp(next_pts, status):
    """:func:`park_lost` on the device (``wp.array`` in, ``wp.array`` out, no sync)."""
    import warp as wp

    out = wp.empty_like(next_pts)
    wp.launch(_park_lost_kernel(), dim=next_pts.shape[0], inputs=[next_pts, status],
              outputs=[out], device=next_pts.device)
    return out


def _as_points(detections, max_corners):
    """Detections as float32 [M, 2], strongest first: Harris points already are; FAST
    :class:`~warpvx.Keypoints` are sorted by response."""
    if hasattr(detections, "response"):
        order = np.argsort(-np.asarray(detections.response), kind="stable")[:max_corners]
        return np.stack([np.asarray(detections.x)[order], np.asarray(detections.y)[order]], 1)
    return np.asarray(detections, np.float32).reshape(-1, 2)[:max_corners]


def refresh_points(next_pts, status, detections, *, min_tracked=150, max_corners=400,
                   min_distance=8.0):
    """The points to track into the next frame, float32 [M, 2] (M <= ``max_corners``).

    Keeps the points LK tracked (``status`` 1); when fewer than ``min_tracked`` survived, adds
    the strongest ``detections`` (float32 [K, 2] or Keypoints) lying at least
    ``min_distance`` px from every kept point (tracked points have priority, as in
    VisionWorks' Harris tracker). Padded to 4 points with off-image points that LK loses.
    """
    ok = np.asarray(status).reshape(-1).astype(bool)
    tracked = np.asarray(next_pts, np.float32).reshape(-1, 2)[ok]
    tracked = tracked[np.isfinite(tracked).all(1)]
    if len(tracked) >= min_tracked:
        return np.ascontiguousarray(tracked[:max_corners])
    fresh = _as_points(detections, max_corners)
    if len(tracked) and len(fresh):
        d2 = ((fresh[:, None, :] - tracked[None, :, :]) ** 2).sum(-1).min(1)
        fresh = fresh[d2 >= min_distance ** 2]
    merged = np.concatenate([tracked, fresh])[:max_corners]
    if len(merged) < len(_NO_POINTS):
        merged = np.concatenate([merged, _NO_POINTS[len(merged):]])
    return np.ascontiguousarray(merged, np.float32)


def is_cut(motion, size, threshold):
    """Whether the inter-frame motion ``motion`` (float64 3x3, frame k-1 -> k) is a scene cut.

    True when it moves a corner of the frame (``size`` (w, h); corners (0, 0) .. (w-1, h-1))
    by more than ``threshold`` times the frame diagonal, or maps one to or past the line at
    infinity (homogeneous w <= 0); never for ``threshold`` None.
    """
    if threshold is None:
        return False
    w, h = size
    corners = np.array([[0, w - 1, w - 1, 0], [0, 0, h - 1, h - 1], [1, 1, 1, 1]], np.float64)
    p = np.asarray(motion, np.float64) @ corners
    if not (p[2] > 0).all():
        return True
    shift = np.hypot(p[0] / p[2] - corners[0], p[1] / p[2] - corners[1])
    return bool(shift.max() > threshold * np.hypot(w, h))


def accumulate(motion, prev_trajectory, live, cut=False):
    """``T_k = H_k T_{k-1}`` (float64 3x3); the identity on the first frame (``T_{k-1}`` NaN)
    and at a scene cut (``cut``); NaN for the padding frames that flush the centred window
    (``live`` [1] uint8 0)."""
    if not np.asarray(live).reshape(-1)[0]:
        return _NAN3.copy()
    prev = np.asarray(prev_trajectory, np.float64)
    if cut or not np.isfinite(prev).all():
        return np.eye(3)
    T = np.asarray(motion, np.float64) @ prev
    return T / T[2, 2]


def smooth_transform(*trajectory, weights, lag, segments=None):
    """The stabilizing warp of frame j (float64 3x3, frame j -> smoothed frame j).

    ``trajectory``: the window's T matrices, oldest first (``len(weights)`` of them; NaN for
    frames outside the video); frame j is ``lag`` frames before the newest. ``segments``:
    their segment indices (ints, same order; None: one segment).
    ``S_j = sum_i w_i T_i T_j^-1 / sum_i w_i`` over the frames present in frame j's segment;
    identity when frame j itself is absent (the centred window before frame r).
    """
    j = len(trajectory) - 1 - lag
    Tj = trajectory[j]
    if not np.isfinite(Tj).all():
        return np.eye(3)
    if segments is None:
        segments = [0] * len(trajectory)
    inv = np.linalg.inv(Tj)
    acc, total = np.zeros((3, 3)), 0.0
    for T, w, seg in zip(trajectory, weights, segments):
        if np.isfinite(T).all() and seg == segments[j]:
            M = T @ inv
            acc += w * (M / M[2, 2])
            total += w
    return acc / total


def _crop_matrix(size, crop):
    """Scale by 1 / (1 - 2 crop) about the image centre (float64 3x3); ``size`` (w, h)."""
    w, h = size
    s = 1.0 / (1.0 - 2.0 * crop)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    return np.array([[s, 0, cx * (1 - s)], [0, s, cy * (1 - s)], [0, 0, 1.0]])


def _covers(M, size):
    """Whether the output of warping by ``M`` takes every pixel from inside the input."""
    w, h = size
    corners = np.array([[0, 0, 1], [w - 1, 0, 1], [w - 1, h - 1, 1], [0, h - 1, 1]], float).T
    src = np.linalg.solve(M, corners)
    src = src[:2] / src[2]
    eps = 1e-6
    return bool((src[0] >= -eps).all() and (src[0] <= w - 1 + eps).all()
                and (src[1] >= -eps).all() and (src[1] <= h - 1 + eps).all())


def truncate_transform(transform, *, size, crop):
    """The warp applied to the frame: crop scaling after ``transform`` (float64 3x3).

    With ``crop`` > 0 the transform is pulled towards the identity (the least blend, found by
    bisection) until the cropped output takes no pixel from outside the frame, as
    VisionWorks' ``truncateStabTransform``; ``size`` is (w, h).
    """
    C = _crop_matrix(size, crop)
    S = np.asarray(transform, np.float64)
    if crop == 0 or _covers(C @ S, size):
        return C @ S
    lo, hi = 0.0, 1.0  # blend towards the identity: lo fails, hi (the identity) covers
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if _covers(C @ ((1 - mid) * S + mid * np.eye(3)), size):
            hi = mid
        else:
            lo = mid
    return C @ ((1 - hi) * S + hi * np.eye(3))


def follow_motion(*inputs, motion_fn, n_motion, config, size):
    """The host side of a frame: (H_k, T_k, segment_k, smoothing transform, warp): float64
    3x3 matrices but segment_k, the segment index of frame k (int64 [1]).

    ``inputs``: ``motion_fn``'s ``n_motion`` inputs (H_k = ``motion_fn(*those)``), ``live``
    (uint8 [1]), then the trajectory's delay slots T_{k-m} .. T_{k-1}, oldest first (m >= 1),
    then the segment indices of the same frames (int64 [1] each, 0 before the video).
    Chains :func:`is_cut` (a live frame after another one), :func:`accumulate`,
    :func:`smooth_transform` over the last ``len(weights)`` frames and
    :func:`truncate_transform` (``size`` (w, h)), as the model does.
    """
    motion = motion_fn(*inputs[:n_motion])
    live, slots = inputs[n_motion], inputs[n_motion + 1:]
    m = len(slots) // 2
    slots, segments = slots[:m], [int(s[0]) for s in slots[m:]]
    cut = (bool(np.asarray(live).reshape(-1)[0]) and np.isfinite(slots[-1]).all()
           and is_cut(motion, size, config.cut_threshold))
    T = accumulate(motion, slots[-1], live, cut)
    segment = segments[-1] + int(cut)
    weights = config.weights()
    first = m + 1 - len(weights)  # the window: the last len(weights) - 1 slots, then frame k
    transform = smooth_transform(*slots[first:], T, weights=weights, lag=config.lag,
                                 segments=segments[first:] + [segment])
    return (motion, T, np.array([segment], np.int64), transform,
            truncate_transform(transform, size=size, crop=config.crop))


def undistort_maps(config, size):
    """float32 HxW remap maps undoing the lens distortion (``cv2.initUndistortRectifyMap``)."""
    import cv2

    K = np.asarray(config.camera_matrix, np.float64).reshape(3, 3)
    D = np.asarray(config.dist_coeffs, np.float64).reshape(-1)
    return cv2.initUndistortRectifyMap(K, D, None, K, tuple(size), cv2.CV_32FC1)


# --------------------------------------------------------------------------- the graph


def build_graph(size, config: StabilizerConfig = StabilizerConfig(), *, backend="cpu"):
    """The stabilizer graph for frames of ``size`` (w, h), BGR uint8.

    Inputs: ``frame`` (uint8 HxWx3) and ``live`` (uint8 [1]: 1 for video frames, 0 for the
    padding frames that flush the centred window). Outputs: ``stabilized`` (uint8 HxWx3,
    frame k - lag), ``warp`` (its float64 3x3 warp, input -> output), ``transform`` (the
    stabilizing warp before crop), ``trajectory`` (T_k), ``motion`` (H_k) and ``segment``
    (int64 [1], frame k's segment index: scene cuts step it).

    ``backend``: ``"cpu"`` runs every node on CPU workers; ``"warp-cpu"``/``"cuda"`` pins the
    primitive nodes to the Warp device (user nodes stay on the CPU). Schedule with
    :func:`schedule`.
    """
    from ..check import check_choice, check_size
    from ..graph import Graph

    w, h = check_size(size, "size")
    check_choice(backend, "backend", BACKENDS)
    pin = None if backend == "cpu" else "gpu"
    c = config
    g = Graph("stabilize")
    frame = g.input("frame", shape=(h, w, 3), dtype=np.uint8)
    live = g.input("live", shape=(1,), dtype=np.uint8)
    if c.camera_matrix is not None:
        mx, my = undistort_maps(c, (w, h))
        frame = g.remap(frame, mx, my, name="undistort", target=pin)
    gray = g.color_convert(frame, code="BGR2GRAY", name="gray", target=pin)
    pyr = g.gaussian_pyramid(gray, levels=c.levels, name="pyramid", target=pin)
    if c.detector == "harris":
        detections = g.harris_corners(gray, max_corners=c.max_corners, quality_level=c.quality_level,
                                      min_distance=c.min_distance, name="detect", target=pin)
    else:
        detections = g.fast_corners(gray, threshold=c.fast_threshold, name="detect", target=pin)
    points = g.virtual("points")
    prev_points = g.delay(points, init=_NO_POINTS)[-1]
    next_pts, status, _ = g.optical_flow_pyr_lk(
        g.delay(pyr)[-1], pyr, prev_points, win_size=(c.lk_win, c.lk_win),
        max_level=c.levels - 1, name="track", target=pin)
    if c.motion == "homography" and pin is not None:
        dst = g.user(park_lost, [next_pts, status], warp_fn=_park_lost_warp, name="park_lost",
                     target=pin)
        H, _ = g.find_homography(prev_points, dst, ransac_reproj_threshold=c.ransac_threshold,
                                 max_iters=c.ransac_iters, name="ransac", target=pin)
        motion_fn, motion_inputs = as_motion, [H]
    else:
        motion_fn = functools.partial(estimate_motion, model=c.motion, backend="cpu",
                                      threshold=c.ransac_threshold, max_iters=c.ransac_iters)
        motion_inputs = [prev_points, next_pts, status]
    g.user(functools.partial(refresh_points, min_tracked=c.min_tracked, max_corners=c.max_corners,
                             min_distance=c.min_distance),
           [next_pts, status, detections], [points], name="refresh_points")
    trajectory, segment = g.virtual("trajectory"), g.virtual("segment")
    m = max(1, len(c.weights()) - 1)
    history, segments = g.delay(trajectory, m, init=_NAN3), g.delay(segment, m, init=_SEGMENT0)
    # One host node for the whole 3x3 chain (motion, cut test, accumulate, smooth, truncate):
    # one executor hand-off per frame instead of five.
    chain = functools.partial(follow_motion, motion_fn=motion_fn, n_motion=len(motion_inputs),
                              config=c, size=(w, h))
    slots = [d[-i] for d in (history, segments) for i in range(m, 0, -1)]
    motion, _, _, transform, warp = g.user(
        chain, motion_inputs + [live] + slots, ["motion", trajectory, segment, "transform", "warp"],
        name="motion")
    src = g.delay(frame, c.lag)[-c.lag] if c.lag else frame
    out = g.warp_perspective(src, warp, dsize=(w, h), name="warp", target=pin)
    g.output("stabilized", out)
    g.output("warp", warp)
    g.output("transform", transform)
    g.output("trajectory", trajectory)
    g.output("motion", motion)
    g.output("segment", segment)
    return g


# --------------------------------------------------------------------------- running


@dataclasses.dataclass
class StabilizedFrame:
    """One output frame: ``index`` k (it shows input frame k), ``image`` (uint8 HxWx3),
    ``warp`` (float64 3x3, input -> output), ``transform`` (the smoothing warp before the crop),
    ``trajectory`` (T_k, from the first frame of k's segment to frame k) and ``segment`` (the
    index of k's shot: 0 first, one more after each scene cut)."""

    index: int
    image: np.ndarray
    warp: np.ndarray
    transform: np.ndarray
    trajectory: np.ndarray
    segment: int = 0


_LIVE, _PAD = np.ones(1, np.uint8), np.zeros(1, np.uint8)


def _check_frame(frame, size=None):
    from ..check import check_image

    check_image(frame, "frame", dtypes=(np.uint8,), channels=(3,))
    if size is not None and frame.shape[1::-1] != tuple(size):
        raise WarpvxValueError(f"frame: expected every frame of size {size[0]}x{size[1]}, got "
                               f"{frame.shape[1]}x{frame.shape[0]}")


def _drive(frames, config, run):
    """Feed ``frames`` (then ``lag`` padding frames) to ``run(feed) -> iterator of output
    dicts`` and yield :class:`StabilizedFrame` in input order."""
    frames = iter(frames)
    first = next(frames, None)
    if first is None:
        raise WarpvxValueError("frames: the video has no frames")
    _check_frame(first)
    size = first.shape[1::-1]
    lag = config.lag
    trajectories, segments = [], []

    def feed():
        last = first
        for f in _chain_first(first, frames):
            _check_frame(f, size)
            last = f
            yield {"frame": f, "live": _LIVE}
        for _ in range(lag):
            yield {"frame": last, "live": _PAD}

    for k, out in enumerate(run(feed(), size)):
        if out["trajectory"] is not None and np.isfinite(out["trajectory"]).all():
            trajectories.append(out["trajectory"])
            segments.append(int(np.asarray(out["segment"]).reshape(-1)[0]))
        j = k - lag
        if j >= 0:
            yield StabilizedFrame(j, out["stabilized"], out["warp"], out["transform"], trajectories[j],
                                  segments[j])


def _chain_first(first, rest):
    yield first
    yield from rest


def stabilize(frames, config: StabilizerConfig = StabilizerConfig(), *, backend="cpu",
              depth: int | None = None, engine: str = "auto"):
    """Stabilize a video with warpvx; a generator of :class:`StabilizedFrame`.

    ``frames``: an iterable of BGR uint8 HxWx3 frames of one size. ``backend``: ``"cpu"``,
    ``"warp-cpu"`` or ``"cuda"``; ``depth`` frames in flight (default 2 in the graph, 3 in the
    device engine). ``engine``: ``"graph"`` (the warpvx graph, :func:`build_graph`),
    ``"device"`` (every step on the Warp device, replayed per frame:
    :mod:`warpvx.apps.stabilize_device`; Warp backends, homography + Harris) or ``"auto"``
    (the device engine where it applies, else the graph).
    """
    from ..check import check_choice

    check_choice(backend, "backend", BACKENDS)
    check_choice(engine, "engine", ENGINES)
    if engine != "graph" and backend != "cpu":
        from .stabilize_device import run_device, supports

        reason = supports(config)
        if reason is None:
            return _drive(frames, config, run_device(backend, config, 3 if depth is None else depth))
        if engine == "device":
            raise WarpvxValueError(f"engine: the device engine does not run {reason}; use 'graph'")
    elif engine == "device":
        raise WarpvxValueError("engine: the device engine needs a Warp backend (warp-cpu, cuda)")

    def run(feed, size):
        g = build_graph(size, config, backend=backend)
        schedule(g, backend)
        with g:
            yield from g.stream(feed, depth=2 if depth is None else depth)

    return _drive(frames, config, run)


def stabilize_model(frames, config: StabilizerConfig = StabilizerConfig()):
    """The same algorithm as plain OpenCV calls (the imperative "model" of thesis §2 and
    §3.2.1); a generator of :class:`StabilizedFrame`, as :func:`stabilize`."""
    import cv2

    c = config
    motion_fn = functools.partial(estimate_motion, model=c.motion, threshold=c.ransac_threshold,
                                  max_iters=c.ransac_iters)

    def run(feed, size):
        maps = undistort_maps(c, size) if c.camera_matrix is not None else None
        window = deque([_NAN3] * len(c.weights()), maxlen=len(c.weights()))
        segments = deque([_SEGMENT0] * len(c.weights()), maxlen=len(c.weights()))
        sources = deque(maxlen=c.lag + 1)
        prev_gray, points = None, _NO_POINTS
        lk = dict(winSize=(c.lk_win, c.lk_win), maxLevel=c.levels - 1,
                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01),
                  minEigThreshold=1e-4)
        fast = cv2.FastFeatureDetector_create(c.fast_threshold, True) if c.detector == "fast" else None
        for item in feed:
            frame = item["frame"]
            if maps is not None:
                frame = cv2.remap(frame, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            gray = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            if fast is None:
                det = cv2.goodFeaturesToTrack(gray, c.max_corners, c.quality_level, c.min_distance,
                                              blockSize=3, useHarrisDetector=True, k=0.04)
                det = np.zeros((0, 2), np.float32) if det is None else det.reshape(-1, 2)
            else:
                kps = sorted(fast.detect(gray), key=lambda kp: -kp.response)[:c.max_corners]
                det = np.float32([kp.pt for kp in kps]).reshape(-1, 2)
            if prev_gray is None:
                nxt, status = points, np.zeros(len(points), np.uint8)
            else:
                nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, points, None, **lk)
            _, T, segment, transform, warp = follow_motion(
                points, nxt, status, item["live"], *window, *segments, motion_fn=motion_fn,
                n_motion=3, config=c, size=size)
            points = refresh_points(nxt, status, det, min_tracked=c.min_tracked,
                                    max_corners=c.max_corners, min_distance=c.min_distance)
            prev_gray = gray
            window.append(T)
            segments.append(segment)
            sources.append(frame)
            out = cv2.warpPerspective(sources[0], warp, tuple(size), flags=cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT)
            yield {"stabilized": out, "warp": warp, "transform": transform, "trajectory": T,
                   "segment": segment}

    return _drive(frames, config, run)


def demo_clip() -> str:
    """Path of the bundled real hand-held clip (46 frames, 640x272; data/LICENSE-bikes.md)."""
    from importlib.resources import files

    return str(files("warpvx") / "data" / "bikes_shaky.mp4")


__all__ = [
    "StabilizerConfig", "StabilizedFrame", "build_graph", "schedule", "stabilize", "stabilize_model",
    "estimate_motion", "follow_motion", "is_cut", "as_motion", "park_lost", "refresh_points", "accumulate", "smooth_transform", "truncate_transform",
    "undistort_maps", "demo_clip", "VideoSource", "open_writer",
    "MOTIONS", "MODES", "DETECTORS", "BACKENDS", "ENGINES",
]
