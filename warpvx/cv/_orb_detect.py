"""OpenCV's ORB keypoint detection (``ORB_Impl::detectAndCompute``) on warpvx primitives.

What :class:`warpvx.cv.ORB` detects with, so that code tuned on ``cv2.ORB_create`` gets cv2's
keypoints: per pyramid level, FAST at ``fastThreshold``, the ``edgeThreshold`` border, the best
by FAST score, then the best by Harris score, intensity-centroid angles. The image work runs on
the backend (OpenCV's INTER_LINEAR_EXACT pyramid, :mod:`warpvx.cv._pyramid_exact`;
:func:`warpvx.fast_corners`, :func:`warpvx.harris_response`); the ranking (a sort of a few
thousand scores) and the angles (integral images) on the host. Descriptors are
:func:`warpvx.orb_compute`'s (rotated BRIEF on the 7x7, sigma 2 blurred level, as OpenCV's
with ``WTA_K=2``, ``patchSize=31``).

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
from ..kernels_cpu.orb import compute_orientation
from ._pyramid_exact import exact_pyramid, resize_exact

HARRIS_SCORE = 0
FAST_SCORE = 1
# OpenCV's HarrisResponses: 7x7 window, Sobel 3x3, k = 0.04 (orb.cpp HARRIS_K).
_HARRIS_BLOCK = 7
_HARRIS_K = 0.04
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
           score_type: int, fast_threshold: int, mask=None, *, backend=None) -> Keypoints:
    """OpenCV's ORB keypoints of a gray uint8 HxW image (NumPy or device array).

    Level l: the image resized INTER_LINEAR_EXACT from level l-1 (scale ``scale_factor^l``,
    :func:`layer_scales`, sizes :func:`level_sizes`); FAST-9/16 with non-max suppression at ``fast_threshold``; those within
    ``edge`` px of the level's border dropped; with a uint8 HxW ``mask``, those where its level
    (OpenCV's mask pyramid) is zero dropped; ``retainBest`` by FAST score to 2 n_l (Harris
    score) or n_l (FAST score), n_l = ORB's features per level (``nfeatures`` split
    geometrically, the last level the remainder); for the Harris score, the Harris response
    (7x7 window, Sobel 3x3, k 0.04, cv2.cornerHarris's scaling) at each point and
    ``retainBest`` to n_l; the intensity-centroid angle over the radius-15 disc of the
    unblurred level (``patchSize`` 31) (``fastAtan2(m01, m10)``, degrees).

    Returns
    -------
    Keypoints
        Host arrays, level by level, each level in raster order (cv2 leaves ``retainBest``'s
        ``nth_element`` order: the same set, another order): x, y at level 0 (level
        coordinates times s_l, float32), response (Harris or FAST score), size
        ``31 s_l``, angle in degrees [0, 360), octave = level.
    """
    scales = layer_scales(scale_factor, nlevels)
    sizes = level_sizes(int(gray.shape[1]), int(gray.shape[0]), scales)
    used = _used_levels(sizes, edge)
    if used == 0:
        return Keypoints.empty()
    be = resolve_backend(backend, like=gray)
    src = to_numpy(gray) if be.kind == "cpu" else to_warp(gray, be.device)
    levels = exact_pyramid(src, sizes[:used])
    masks = _mask_levels(mask, sizes[:used]) if mask is not None else [None] * used
    wanted = features_per_level(nfeatures, scale_factor, nlevels)
    fields = {k: [] for k in ("x", "y", "response", "size", "angle", "octave")}
    for level, (img, m) in enumerate(zip(levels, masks)):
        x, y, score = _level_points(img, m, edge, fast_threshold, be)
        harris = score_type == HARRIS_SCORE
        keep = retain_best(score, 2 * wanted[level] if harris else wanted[level])
        x, y, score = x[keep], y[keep], score[keep]
        if harris and x.size:
            resp = to_numpy(features.harris_response(img, _HARRIS_BLOCK, 3, _HARRIS_K,
                                                     backend=be))
            score = resp.reshape(resp.shape[:2])[y, x]
            keep = retain_best(score, wanted[level])
            x, y, score = x[keep], y[keep], score[keep]
        fields["angle"].append(compute_orientation(to_numpy(img), x, y))
        fields["x"].append(x.astype(np.float32) * scales[level])
        fields["y"].append(y.astype(np.float32) * scales[level])
        fields["response"].append(score.astype(np.float32))
        fields["size"].append(np.full(x.size, PATCH_SIZE * scales[level], np.float32))
        fields["octave"].append(np.full(x.size, level, np.int32))
    return Keypoints(**{k: np.concatenate(v) for k, v in fields.items()})


__all__ = ["HARRIS_SCORE", "FAST_SCORE", "detect", "layer_scales", "level_sizes", "retain_best"]
