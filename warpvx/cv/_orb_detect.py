"""OpenCV's ORB (``ORB_Impl::detectAndCompute``) on warpvx primitives: detection and description.

What :class:`warpvx.cv.ORB` detects with, so that code tuned on ``cv2.ORB_create`` gets cv2's
keypoints: per pyramid level, FAST at ``fastThreshold``, the ``edgeThreshold`` border, the best
by FAST score, then the best by Harris score, intensity-centroid angles. The image work runs on
the backend (OpenCV's INTER_LINEAR_EXACT pyramid and float blur, :mod:`warpvx.cv._orb_levels`;
:func:`warpvx.fast_corners`; rotated BRIEF); the per-point work on the host, on the downloaded
level, as OpenCV computes it per point: Harris at the (at most 2 n_l) FAST corners in OpenCV's
integer arithmetic (a full :func:`warpvx.harris_response` map cost 5x more and rounds
differently), the ranking, the angles (integral images). ``WTA_K`` 2, ``patchSize`` 31.

Reference: OpenCV ``features2d/src/orb.cpp`` (``computeKeyPoints``, ``HarrisResponses``,
``ICAngles``) and ``keypoint.cpp`` (``KeyPointsFilter::retainBest``, ``runByImageBorder``).
"""

from __future__ import annotations

import numpy as np

from .. import features
from .._orb_spec import PATCH_SIZE, features_per_level
from ..arrays import to_numpy, to_warp
from ..backend import resolve_backend
from ..keypoints import Keypoints
from ..kernels_cpu.orb import compute_orientation, padded_centres
from ._orb_levels import blur_level, describe, exact_pyramid, resize_exact

HARRIS_SCORE = 0
FAST_SCORE = 1
# OpenCV's HarrisResponses: 7x7 window, Sobel 3x3, k = 0.04 (orb.cpp HARRIS_K).
_HARRIS_BLOCK = 7
_HARRIS_K = np.float32(0.04)
# FAST reads a radius-3 circle: a level smaller than 7x7 has no corner.
_FAST_MIN_SIDE = 7


def layer_scales(scale_factor: float, n_levels: int) -> np.ndarray:
    """float32 [n_levels]: OpenCV's ORB level scales, ``(float)pow(scale_factor, l)`` (in
    double; the float product of :func:`warpvx._orb_spec.level_scales` can differ in the
    last bit)."""
    return np.array([float(scale_factor) ** level for level in range(n_levels)], np.float32)


def level_sizes(width: int, height: int, scales: np.ndarray) -> list:
    """(w, h) of each level as OpenCV's ORB: ``cvRound(cols * (1.0f / scale))`` in float32."""
    inv = np.float32(1.0) / scales
    return [(int(np.rint(np.float32(width) * i)), int(np.rint(np.float32(height) * i)))
            for i in inv]


def retain_best(response: np.ndarray, n: int) -> np.ndarray:
    """Boolean mask of ``KeyPointsFilter::retainBest``: all when at most ``n``, else those
    scoring at least the ``n``-th best score (ties at that score all kept, so possibly more
    than ``n``), none when ``n`` is 0."""
    if response.size <= n:
        return np.ones(response.size, bool)
    if n <= 0:
        return np.zeros(response.size, bool)
    nth = np.partition(response, response.size - n)[response.size - n]
    return response >= nth


def harris_at(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """float32 [N]: OpenCV ORB's ``HarrisResponses`` at integer points of a uint8 level.

    Over the 7x7 window centred at (x, y): Sobel 3x3 ``Ix``, ``Iy`` (integers), ``a = S Ix^2``,
    ``b = S Iy^2``, ``c = S Ix Iy`` (exact int sums), then in float32 as OpenCV
    ``R = (a b - c^2 - k (a + b)^2) / (4 * 7 * 255)^4``, k = 0.04 (cv2.cornerHarris's
    scaling, block 7). Reads past the level reflect (BORDER_REFLECT_101, OpenCV's bordered
    pyramid).
    """
    r = _HARRIS_BLOCK // 2 + 1  # the window plus the Sobel's 1 px
    padded, cx, cy = padded_centres(level, x, y, r)
    off = np.arange(-r, r + 1)
    p = padded[(cy[:, None] + off)[:, :, None], (cx[:, None] + off)[:, None, :]].astype(np.int32)
    dx = p[:, :, 2:] - p[:, :, :-2]
    dy = p[:, 2:, :] - p[:, :-2, :]
    ix = dx[:, :-2] + 2 * dx[:, 1:-1] + dx[:, 2:]
    iy = dy[:, :, :-2] + 2 * dy[:, :, 1:-1] + dy[:, :, 2:]
    a = (ix * ix).sum((1, 2)).astype(np.float32)
    b = (iy * iy).sum((1, 2)).astype(np.float32)
    c = (ix * iy).sum((1, 2)).astype(np.float32)
    scale = np.float32(1.0) / np.float32(4 * _HARRIS_BLOCK * 255)
    return (a * b - c * c - _HARRIS_K * (a + b) * (a + b)) * (scale * scale * scale * scale)


def _mask_levels(mask, sizes) -> list:
    """OpenCV 5.0's mask pyramid: the mask made binary (nonzero -> 255), each level resized
    INTER_LINEAR_EXACT from the previous one and only 255 kept (``threshold(.., 254, 0,
    THRESH_TOZERO)``): a level keeps the points whose whole neighbourhood is inside. Measured
    against cv2 (a mask of 1s is all-pass there too); host arrays (a mask is a host input)."""
    levels = [np.where(mask != 0, 255, 0).astype(np.uint8)]
    for size in sizes[1:]:
        m = resize_exact(levels[-1], size)
        levels.append(np.where(m > 254, m, 0).astype(np.uint8))
    return levels


def _used_levels(sizes, edge: int) -> int:
    """How many leading levels can hold a keypoint: FAST needs 7x7, ``runByImageBorder``
    empties a level no wider or taller than twice the border. Levels only shrink."""
    n = 0
    for w, h in sizes:
        if min(w, h) < _FAST_MIN_SIDE or (edge > 0 and min(w, h) <= 2 * edge):
            break
        n += 1
    return n


def _level_points(img, mask, edge: int, fast_threshold: int, backend) -> tuple:
    """FAST corners of one level (NMS), in raster order, masked and off the border:
    (x, y int32 level coordinates, float32 FAST score)."""
    kps = features.fast_corners(img, fast_threshold, True, backend=backend).to("host")
    x = kps.x.astype(np.int32)
    y = kps.y.astype(np.int32)
    order = np.lexsort((x, y))  # cv::FAST's raster order (retainBest keeps ties: set-exact)
    x, y, score = x[order], y[order], kps.response[order]
    h, w = int(img.shape[0]), int(img.shape[1])
    keep = (x >= edge) & (x < w - edge) & (y >= edge) & (y < h - edge)
    if mask is not None:
        keep &= mask[y, x] != 0
    return x[keep], y[keep], score[keep]


def detect(gray, nfeatures: int, scale_factor: float, nlevels: int, edge: int,
           score_type: int, fast_threshold: int, mask=None, *, backend=None) -> tuple:
    """OpenCV's ORB keypoints of a gray uint8 HxW image (NumPy or device array).

    Level l: the image resized INTER_LINEAR_EXACT from level l-1 (scale ``scale_factor^l``,
    :func:`layer_scales`; sizes :func:`level_sizes`); FAST-9/16 with non-max suppression at
    ``fast_threshold``; those within ``edge`` px of the level's border dropped; with a uint8
    HxW ``mask``, those where its level (:func:`_mask_levels`) is zero dropped; ``retainBest``
    by FAST score to 2 n_l (Harris score) or n_l (FAST score), n_l = ORB's features per level
    (``nfeatures`` split geometrically, the last level the remainder); for the Harris score,
    :func:`harris_at` each point and ``retainBest`` to n_l; the intensity-centroid angle over
    the radius-15 disc of the unblurred level (``patchSize`` 31; ``fastAtan2(m01, m10)``,
    degrees).

    Returns
    -------
    levels : list of arrays
        The pyramid levels used (NumPy, or ``wp.array`` on the backend's device), for
        :func:`describe_keypoints`.
    keypoints : Keypoints
        Host arrays, level by level, each level in raster order (cv2 leaves ``retainBest``'s
        ``nth_element`` order: the same set, another order): x, y at level 0 (level
        coordinates times s_l, float32), response (Harris or FAST score), size
        ``31 s_l``, angle in degrees [0, 360), octave = level.
    """
    scales = layer_scales(scale_factor, nlevels)
    sizes = level_sizes(int(gray.shape[1]), int(gray.shape[0]), scales)
    used = _used_levels(sizes, edge)
    if used == 0:
        return [], Keypoints.empty()
    be = resolve_backend(backend, like=gray)
    levels = exact_pyramid(on_backend(gray, be), sizes[:used])
    masks = _mask_levels(mask, sizes[:used]) if mask is not None else [None] * used
    wanted = features_per_level(nfeatures, scale_factor, nlevels)
    fields = {k: [] for k in ("x", "y", "response", "size", "angle", "octave")}
    for level, (img, m) in enumerate(zip(levels, masks)):
        x, y, score = _level_points(img, m, edge, fast_threshold, be)
        harris = score_type == HARRIS_SCORE
        keep = retain_best(score, 2 * wanted[level] if harris else wanted[level])
        x, y, score = x[keep], y[keep], score[keep]
        host = to_numpy(img)
        if harris and x.size:
            score = harris_at(host, x, y)
            keep = retain_best(score, wanted[level])
            x, y, score = x[keep], y[keep], score[keep]
        fields["angle"].append(compute_orientation(host, x, y))
        fields["x"].append(x.astype(np.float32) * scales[level])
        fields["y"].append(y.astype(np.float32) * scales[level])
        fields["response"].append(score.astype(np.float32))
        fields["size"].append(np.full(x.size, PATCH_SIZE * scales[level], np.float32))
        fields["octave"].append(np.full(x.size, level, np.int32))
    return levels, Keypoints(**{k: np.concatenate(v) for k, v in fields.items()})


def on_backend(gray, be):
    """``gray`` where backend ``be`` computes: NumPy for ``cpu``, else on its Warp device."""
    return to_numpy(gray) if be.kind == "cpu" else to_warp(gray, be.device)


def describe_keypoints(levels: list, kps: Keypoints, scale_factor: float) -> np.ndarray:
    """uint8 [N, 32] (host): OpenCV's ORB descriptors of host ``kps`` on ``levels``.

    Keypoint i is described on level ``octave`` blurred (:func:`~warpvx.cv._orb_levels.
    blur_level`), centred at ``cvRound(p * (1 / s_octave))`` (float32, OpenCV's), with its own
    ``angle``; every octave must have a level.
    """
    desc = np.zeros((len(kps), 32), np.uint8)
    inv = np.float32(1.0) / layer_scales(scale_factor, len(levels))
    for level in np.unique(kps.octave):
        idx = np.flatnonzero(kps.octave == level)
        cx = np.rint(kps.x[idx] * inv[level]).astype(np.int32)
        cy = np.rint(kps.y[idx] * inv[level]).astype(np.int32)
        desc[idx] = describe(blur_level(levels[level]), cx, cy, kps.angle[idx])
    return desc


__all__ = ["HARRIS_SCORE", "FAST_SCORE", "describe_keypoints", "detect", "harris_at",
           "layer_scales", "level_sizes", "on_backend", "retain_best"]
