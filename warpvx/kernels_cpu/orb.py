"""ORB-SLAM2's ORB extractor on NumPy/OpenCV, stage by stage.

The stages follow ``ORBextractor::operator()`` of ORB-SLAM2 (``src/ORBextractor.cc``) and are
separate functions so a graph can run them as nodes (SPEC section 6):

``build_pyramid``        level l resized INTER_LINEAR from level l-1 to cvRound(w / s_l)
``detect_cells``         FAST-9/16 per 30x30 cell at the lower threshold, cell-local non-max
``select_cells``         per cell: the points >= iniThFAST if it has any, else those >= minThFAST
``distribute_octtree``   the quadtree (``DistributeOctTree``), sequential, host only
``compute_orientation``  intensity centroid over the radius-15 disc (``IC_Angle``)
``blur_level``           7x7 Gaussian, sigma 2, BORDER_REFLECT_101
``compute_descriptors``  rotated BRIEF with the 256 pairs of the 31x31 pattern
``scale_back``           level coordinates times s_l

What defines the algorithm rather than an implementation (level scales, features per level,
the cell grid, the disc, the pattern, ``fastAtan2``'s coefficients) is in the neutral
:mod:`warpvx._orb_spec`, the host quadtree in :mod:`warpvx._orb_quadtree`; both backends
import them from there.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np

from .._orb_quadtree import distribute_octtree, order_candidates
from .._orb_spec import (DESCRIPTOR_BYTES, HALF_PATCH_SIZE, PATTERN_RADIUS, CellGrid, cell_grid,
                         fast_atan2, features_per_level, keypoint_sizes, level_scales, pattern,
                         refuse_out, umax)
from ..keypoints import Keypoints
from .scale_pyramid import scale_pyramid


# --------------------------------------------------------------------------------------------
# Stages
# --------------------------------------------------------------------------------------------


def padded_centres(img: np.ndarray, x, y, radius: int) -> tuple:
    """(padded image, cx, cy): ``img`` with ``radius`` px of BORDER_REFLECT_101 around it and
    the rounded centres (cvRound(x), cvRound(y)), clamped into the image, in padded
    coordinates."""
    h, w = img.shape
    r = int(radius)
    if r >= min(h, w):  # cv2's reflection needs the image larger than the pad
        padded = np.pad(img, r, mode="reflect") if min(h, w) > 1 else np.pad(img, r, mode="edge")
    else:
        padded = cv2.copyMakeBorder(img, r, r, r, r, cv2.BORDER_REFLECT_101)
    cx = np.clip(np.rint(np.asarray(x, np.float32)).astype(np.intp), 0, w - 1) + r
    cy = np.clip(np.rint(np.asarray(y, np.float32)).astype(np.intp), 0, h - 1) + r
    return padded, cx, cy


def build_pyramid(src: np.ndarray, scale_factor: float, n_levels: int) -> list:
    """ORB-SLAM2's scale pyramid: level l resized INTER_LINEAR from level l-1 to
    cvRound(w / s_l) (``kernels_cpu.scale_pyramid``)."""
    return scale_pyramid(src, n_levels, scale_factor)


@functools.lru_cache(maxsize=16)
def _fast_detector(threshold: int):
    return cv2.FastFeatureDetector_create(int(threshold), True,
                                          cv2.FAST_FEATURE_DETECTOR_TYPE_9_16)


def detect_cells(level: np.ndarray, threshold: int) -> tuple:
    """FAST-9/16 with non-max suppression on each cell, as ComputeKeyPointsOctTree runs it.

    Returns ``(x, y, score)`` int32 arrays in level coordinates and ORB-SLAM2's order. Run at
    the lower of the two thresholds: a point survives non-max suppression at a threshold t
    exactly when it survives at a lower one and scores >= t, so :func:`select_cells` can apply
    the per-cell rule afterwards (the data-flow form of thesis section 3.3.1).
    """
    h, w = level.shape
    grid = cell_grid(w, h)
    detect = _fast_detector(threshold).detect
    # One cv2 call per cell (its own non-max suppression); the keypoints of all cells are
    # converted at once, each shifted by its cell's origin.
    found, x_off, y_off, counts = [], [], [], []
    for y0, y1 in grid.row_spans:
        for x0, x1 in grid.col_spans:
            kps = detect(level[y0:y1, x0:x1])
            if kps:
                found.extend(kps)
                x_off.append(x0)
                y_off.append(y0)
                counts.append(len(kps))
    if not found:
        z = np.zeros(0, np.int32)
        return z, z.copy(), z.copy()
    pts = cv2.KeyPoint_convert(found)
    x = pts[:, 0].astype(np.int32) + np.repeat(np.array(x_off, np.int32), counts)
    y = pts[:, 1].astype(np.int32) + np.repeat(np.array(y_off, np.int32), counts)
    s = np.fromiter((k.response for k in found), np.float32, len(found)).astype(np.int32)
    order = order_candidates(x, y, grid)
    return x[order], y[order], s[order]


def select_cells(x, y, score, grid: CellGrid, ini_th: int, min_th: int) -> np.ndarray:
    """Boolean mask: per cell, the points >= ``ini_th`` when it has one, else >= ``min_th``."""
    if x.size == 0:
        return np.zeros(0, bool)
    cell = grid.row_of_y[y].astype(np.int64) * grid.n_cols + grid.col_of_x[x]
    strong = score >= ini_th
    has_strong = np.bincount(cell, weights=strong, minlength=grid.n_rows * grid.n_cols) > 0
    return np.where(has_strong[cell], strong, score >= min_th)


def compute_orientation(level: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """float32 degrees: ORB-SLAM2's IC_Angle, fastAtan2(m01, m10) over the radius-15 disc.

    m10 = sum u I(x+u, y+v), m01 = sum v I(x+u, y+v) on the unblurred level, centred at the
    rounded keypoint. Reads beyond the level reflect (BORDER_REFLECT_101); extracted
    keypoints never need it.
    """
    if np.asarray(x).size == 0:
        return np.zeros(0, np.float32)
    # Row v of the disc spans |u| <= umax[|v|], column u spans |v| <= umax[|u|] (the disc is
    # symmetric): each row and column sum is four reads of the integral image.
    hp = HALF_PATCH_SIZE
    padded, cx, cy = padded_centres(level, x, y, hp)
    exact_int32 = padded.size * 255 < 2 ** 31
    integral = cv2.integral(padded, sdepth=cv2.CV_32S if exact_int32 else cv2.CV_64F)
    off = np.arange(-hp, hp + 1)
    half = umax()[np.abs(off)].astype(np.intp)
    yy = cy[:, None] + off
    left = cx[:, None] - half
    right = cx[:, None] + half + 1
    row_sums = (integral[yy + 1, right] - integral[yy, right]
                - integral[yy + 1, left] + integral[yy, left])
    xx = cx[:, None] + off
    top = cy[:, None] - half
    bottom = cy[:, None] + half + 1
    col_sums = (integral[bottom, xx + 1] - integral[bottom, xx]
                - integral[top, xx + 1] + integral[top, xx])
    m01 = row_sums.astype(np.int64) @ off  # sum over v of v * (row sum)
    m10 = col_sums.astype(np.int64) @ off  # sum over u of u * (column sum)
    return fast_atan2(m01.astype(np.float32), m10.astype(np.float32))


def blur_level(level: np.ndarray) -> np.ndarray:
    """The 7x7, sigma 2 Gaussian (BORDER_REFLECT_101) ORB-SLAM2 describes on."""
    return cv2.GaussianBlur(level, (7, 7), 2, sigmaY=2, borderType=cv2.BORDER_REFLECT_101)


def compute_descriptors(blurred: np.ndarray, x, y, angle, *, out=None) -> np.ndarray:
    """uint8 [N, 32] rotated BRIEF (ORB-SLAM2's computeOrbDescriptor).

    With a = cos(angle), b = sin(angle) (radians, float), pattern point (px, py) is sampled
    at (cvRound(px a - py b), cvRound(px b + py a)) from the rounded centre; bit i (bit i % 8
    of byte i // 8) is I(p1) < I(p2) of pair i. Reads beyond the level reflect.
    """
    n = int(np.asarray(x).shape[0])
    desc = out if out is not None else np.empty((n, DESCRIPTOR_BYTES), np.uint8)
    if n == 0:
        return desc
    pat = pattern().astype(np.float32)
    px = pat[:, [0, 2]].reshape(-1)  # p1, p2 of each pair, interleaved: 512 points
    py = pat[:, [1, 3]].reshape(-1)
    rad = np.asarray(angle, np.float32) * np.float32(math.pi / 180.0)
    a = np.cos(rad).astype(np.float32)[:, None]
    b = np.sin(rad).astype(np.float32)[:, None]
    padded, cx, cy = padded_centres(blurred, x, y, PATTERN_RADIUS)
    width = np.float32(padded.shape[1])
    # Flat index of (cvRound(px a - py b), cvRound(px b + py a)) from the centre in the padded
    # level; products and differences in float32, as ORB-SLAM2 (integers stay exact).
    dx = px * a
    dx -= py * b
    np.rint(dx, out=dx)
    dy = px * b
    dy += py * a
    np.rint(dy, out=dy)
    dy *= width
    dy += dx
    index = dy.astype(np.int64)
    index += (cy * padded.shape[1] + cx)[:, None]
    vals = np.take(padded.reshape(-1), index)
    bits = vals[:, 0::2] < vals[:, 1::2]
    desc[...] = np.packbits(bits, axis=1, bitorder="little")
    return desc


def scale_back(x, y, octave, scale_factor: float, n_levels: int) -> tuple:
    """Level coordinates to level 0: (x s_l, y s_l) in float32 (level 0 untouched)."""
    s = level_scales(scale_factor, n_levels)[octave]
    return (np.asarray(x, np.float32) * s).astype(np.float32), \
        (np.asarray(y, np.float32) * s).astype(np.float32)


# --------------------------------------------------------------------------------------------
# The extractor
# --------------------------------------------------------------------------------------------


def extract_level(level: np.ndarray, n_wanted: int, ini_th: int, min_th: int) -> tuple:
    """FAST per cell, per-cell threshold and quadtree on one level: (x, y, score) kept."""
    h, w = level.shape
    grid = cell_grid(w, h)
    x, y, s = detect_cells(level, min(ini_th, min_th))
    keep = select_cells(x, y, s, grid, ini_th, min_th)
    x, y, s = x[keep], y[keep], s[keep]
    chosen = distribute_octtree(x, y, s, grid, n_wanted)
    return x[chosen], y[chosen], s[chosen]


def orb(src: np.ndarray, n_features: int, scale_factor: float, n_levels: int,
        ini_th_fast: int, min_th_fast: int, *, out=None) -> tuple:
    """ORB-SLAM2's extractor: (Keypoints at level 0, uint8 [N, 32] descriptors); for a batch
    (a list of HxW images or a [B, H, W] array) a list of such pairs, image by image.

    Keypoints are listed level by level, each level in the quadtree's node order. ``out``
    must be None (UnsupportedError otherwise: the count is data-dependent).
    """
    refuse_out(out)
    if isinstance(src, list) or src.ndim == 3:
        return [orb(img, n_features, scale_factor, n_levels, ini_th_fast, min_th_fast)
                for img in src]
    pyramid = build_pyramid(src, scale_factor, n_levels)
    wanted = features_per_level(n_features, scale_factor, n_levels)
    sizes = keypoint_sizes(scale_factor, n_levels)
    fields = {k: [] for k in ("x", "y", "response", "size", "angle", "octave")}
    descs = []
    for level, img in enumerate(pyramid):
        x, y, s = extract_level(img, wanted[level], ini_th_fast, min_th_fast)
        angle = compute_orientation(img, x, y)
        descs.append(compute_descriptors(blur_level(img), x, y, angle))
        octave = np.full(x.size, level, np.int32)
        sx, sy = scale_back(x, y, octave, scale_factor, n_levels)
        fields["x"].append(sx)
        fields["y"].append(sy)
        fields["response"].append(s.astype(np.float32))
        fields["size"].append(np.full(x.size, sizes[level], np.float32))
        fields["angle"].append(angle)
        fields["octave"].append(octave)
    kps = Keypoints(**{k: np.concatenate(v) for k, v in fields.items()})
    return kps, np.concatenate(descs, axis=0) if descs else np.zeros((0, 32), np.uint8)


def orb_compute(src: np.ndarray, keypoints: Keypoints, scale_factor: float, n_levels: int,
                *, out=None) -> np.ndarray:
    """uint8 [N, 32] descriptors of given keypoints (level-0 coordinates, octave, angle).

    Each keypoint is described on its octave's blurred level of the ORB-SLAM2 pyramid at
    (x, y) / s_octave, in the input order; into ``out`` (uint8 [N, 32]) when given.
    """
    kp = keypoints.to("host")
    n = len(kp)
    desc = out if out is not None else np.zeros((n, DESCRIPTOR_BYTES), np.uint8)
    if n == 0:
        return desc
    pyramid = build_pyramid(src, scale_factor, n_levels)
    inv = (np.float32(1.0) / level_scales(scale_factor, n_levels)).astype(np.float32)
    for level in np.unique(kp.octave):
        idx = np.flatnonzero(kp.octave == level)
        lx = kp.x[idx] * inv[level]
        ly = kp.y[idx] * inv[level]
        desc[idx] = compute_descriptors(blur_level(pyramid[level]), lx, ly, kp.angle[idx])
    return desc


__all__ = ["orb", "orb_compute"]
