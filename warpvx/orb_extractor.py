"""ORB features extracted exactly as ORB-SLAM2's ``ORBextractor`` does (SPEC section 6).

Public functions validate their arguments and dispatch to ``warpvx.kernels_cpu.orb``
(NumPy/OpenCV) or ``warpvx.kernels_warp.orb`` (Warp kernels, the quadtree included: one CUDA
graph per image size and parameter set); see :mod:`warpvx.registry`.
"""

from __future__ import annotations

import functools

import numpy as np

from ._orb_spec import DESCRIPTOR_BYTES, MAX_SIDE, MIN_LEVEL_SIZE
from .backend import resolve_backend
from .arrays import is_warp_array
from .check import check_array, check_float, check_image, check_int, check_out
from .errors import ShapeError, WarpvxTypeError, WarpvxValueError
from .keypoints import Keypoints, check_keypoints
from .pyramid import scale_pyramid_sizes
from .registry import dispatch

# Level sizes of a (width, height, levels, scale) (validation runs on every call).
_level_sizes = functools.lru_cache(maxsize=256)(scale_pyramid_sizes)
# Most pyramid levels: orb's n_levels, and so one more than the largest orb_compute octave.
MAX_LEVELS = 32

def _gray(src, name: str = "src"):
    """A gray uint8 HxW image (HxWx1 viewed as HxW); colour input is refused, not converted."""
    shape = tuple(getattr(src, "shape", ()))
    if len(shape) == 3 and shape[2] in (3, 4):
        raise ShapeError(
            f"{name}: expected a gray uint8 HxW image, got {shape[2]} channels (shape {shape}); "
            f"convert it first, e.g. warpvx.color_convert(src, 'BGR2GRAY')"
        )
    src = check_image(src, name, dtypes=(np.uint8,), channels=(1,))
    if len(src.shape) == 3:
        src = src.reshape(tuple(src.shape[:2]))
    return src


def _gray_batch(src):
    """``(src, h, w)``: one gray HxW image (HxWx1 viewed as HxW), a list of them or a uint8
    [B, H, W] array, validated, and the image size. Every image of a list is checked as
    ``src[i]``: gray uint8, the size of ``src[0]``, of the same kind (all NumPy, or all Warp
    arrays on one device)."""
    if isinstance(src, (list, tuple)):
        if not src:
            raise WarpvxValueError("src: an empty batch (expected at least one image)")
        images = [_gray(img, f"src[{i}]") for i, img in enumerate(src)]
        first = images[0]
        h, w = int(first.shape[0]), int(first.shape[1])
        where = str(first.device) if is_warp_array(first) else None
        for i, img in enumerate(images[1:], 1):
            if (int(img.shape[0]), int(img.shape[1])) != (h, w):
                raise ShapeError(f"src[{i}]: image of {img.shape[1]}x{img.shape[0]} (WxH), but "
                                 f"src[0] is {w}x{h}: a batch holds images of one size")
            if (str(img.device) if is_warp_array(img) else None) != where:
                raise WarpvxTypeError(
                    f"src[{i}]: on {str(img.device) if is_warp_array(img) else 'the host'}, but "
                    f"src[0] is on {where or 'the host'}: a batch's images are all NumPy "
                    f"arrays or all Warp arrays on one device")
        return images, h, w
    shape = tuple(getattr(src, "shape", ()))
    if len(shape) == 3 and shape[2] not in (1, 3, 4):
        stack = check_array(src, "src", dtypes=(np.uint8,), ndim=3)
        if 0 in shape:
            raise ShapeError(f"src: an empty batch of images (shape {shape})")
        return stack, shape[1], shape[2]
    src = _gray(src)
    return src, int(src.shape[0]), int(src.shape[1])


def orb(src, n_features: int = 2000, scale_factor: float = 1.2, n_levels: int = 8,
        ini_th_fast: int = 20, min_th_fast: int = 7, *, backend=None, stream=None) -> tuple:
    """ORB keypoints and descriptors, extracted as ORB-SLAM2's ``ORBextractor::operator()``.

    Per pyramid level l (scale s_l = scale_factor^l, size cvRound(w / s_l), resized
    INTER_LINEAR from level l-1):

    1. FAST-9/16 with non-max suppression on 30x30 cells over the level less a 16 px border
       (``ComputeKeyPointsOctTree``'s grid, cells overlapping by 6 px): a cell keeps its points
       scoring >= ``ini_th_fast`` when it has any, else those >= ``min_th_fast``. Computed in
       data-flow form (FAST once at the lower threshold, then the per-cell rule), which gives
       ORB-SLAM2's points exactly, cell-local non-max suppression included.
    2. ``DistributeOctTree``: a quadtree spreads the points and keeps the strongest per node,
       aiming at n_l nodes, n_l = cvRound(n0 f^l), f = 1 / scale_factor,
       n0 = N (1 - f) / (1 - f^L), the last level the remainder (2000, 1.2, 8: 434 362 302 251
       209 175 145 122). It can return a few more than n_l (ORB-SLAM2 stops splitting only
       once n_l is reached) or fewer (not enough corners). Sequential as written; the Warp
       path computes the same result in parallel on the device, from the number of
       quadtree nodes per depth (see :mod:`warpvx.kernels_warp.orb`), and reads back only
       the keypoint count.
    3. Orientation: ``IC_Angle``, the intensity centroid over the radius-15 disc (umax rows
       15 15 15 15 14 14 14 13 13 12 11 10 9 8 6 3) of the unblurred level, angle =
       OpenCV's ``fastAtan2(m01, m10)`` in degrees [0, 360).
    4. Descriptors: the level blurred by a 7x7 Gaussian, sigma 2, BORDER_REFLECT_101; rotated
       BRIEF with the 256 pairs of ORB's 31x31 pattern: a = cos, b = sin of the angle, point
       (x, y) sampled at (cvRound(x a - y b), cvRound(x b + y a)), bit i (bit i % 8 of byte
       i // 8) = I(p1) < I(p2).
    5. Coordinates back to level 0: (x s_l, y s_l).

    Keypoints are never within 19 px (EDGE_THRESHOLD) of their level's border (the cells own
    pixels from 19 px in), so every patch lies inside the level, as in ORB-SLAM2 where the
    level carries a 19 px reflected border.

    Parameters
    ----------
    src : uint8 HxW (or HxWx1), or a batch
        Gray image, NumPy or device array, at most 15000 px a side. Colour images are
        refused: convert first. A batch is a list of equal-sized gray images (all NumPy, or
        all device arrays on one device) or a uint8 [B, H, W] array (a 3-D array whose last
        axis is not 1, 3 or 4); the Warp backend extracts from all of them in the same
        launches (one plan, one CUDA graph), the CPU one image by image.
    n_features : int >= 1
        Features wanted over all levels (N).
    scale_factor : float > 1
        Scale between levels.
    n_levels : int in [1, 32]
        Pyramid levels (L). The smallest level must be at least 62x62 (one 30 px cell plus
        the 16 px borders).
    ini_th_fast, min_th_fast : int in [0, 255]
        FAST thresholds: the preferred one and the per-cell fallback.
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    keypoints : Keypoints
        N keypoints, level by level, each level in the quadtree's node order: x, y at level 0
        (float32), response = FAST score, size = int(31 s_l) (ORB-SLAM2's truncated
        PATCH_SIZE x scale), angle in degrees, octave = level.
    descriptors : uint8 [N, 32]
        For a batch: a list of B (keypoints, descriptors) pairs, in the batch's order, each
        equal to what the image alone gives.

    Raises
    ------
    ShapeError
        ``src`` not a gray HxW image, or too small for ``n_levels`` levels; a batch that is
        empty or whose images differ in size (naming ``src[i]``).
    DTypeError
        ``src`` not uint8.
    WarpvxTypeError, WarpvxValueError
        A parameter of the wrong type or out of range (``n_features`` 0, ``scale_factor`` <= 1).

    Notes
    -----
    Deviations from ORB-SLAM2: it orders equal-sized quadtree nodes by heap address (not
    reproducible; here the later-created node goes first), and it would divide by zero on a
    level more than twice as tall as wide (here: one root node). Reference: ORB-SLAM2
    ``src/ORBextractor.cc`` (Mur-Artal and Tardos 2017); descriptors agree with
    ``cv2.ORB_create().compute`` on the same keypoints and angles.
    """
    src, h, w = _gray_batch(src)
    # A list is no array: its first image decides the backend and the results' kind.
    first = src[0] if isinstance(src, list) else None
    be = resolve_backend(backend, like=src if first is None else first)
    n_features = check_int(n_features, "n_features", min_value=1)
    scale_factor = check_float(scale_factor, "scale_factor", min_value=1.0, strict_min=True)
    n_levels = check_int(n_levels, "n_levels", min_value=1, max_value=MAX_LEVELS)
    ini_th_fast = check_int(ini_th_fast, "ini_th_fast", min_value=0, max_value=255)
    min_th_fast = check_int(min_th_fast, "min_th_fast", min_value=0, max_value=255)
    if max(h, w) > MAX_SIDE:
        raise ShapeError(f"src: image of {w}x{h} (WxH) is larger than {MAX_SIDE} px a side")
    lw, lh = _level_sizes(w, h, n_levels, scale_factor)[-1]
    if lw < MIN_LEVEL_SIZE or lh < MIN_LEVEL_SIZE:
        raise ShapeError(
            f"src: image of {w}x{h} (WxH) is too small for n_levels={n_levels} at scale_factor "
            f"{scale_factor}: level {n_levels - 1} would be {lw}x{lh}, every level must be at "
            f"least {MIN_LEVEL_SIZE}x{MIN_LEVEL_SIZE} (a 30 px FAST cell plus 16 px borders); "
            f"use fewer levels or a larger image"
        )
    return dispatch("orb", be, src, n_features, scale_factor, n_levels, ini_th_fast,
                    min_th_fast, stream=stream, template=first)


def orb_compute(src, keypoints, scale_factor: float = 1.2, *, out=None, backend=None,
                stream=None):
    """Descriptors of given keypoints, as :func:`orb` computes them (cv2's ``ORB.compute``).

    Each keypoint is described on level ``octave`` of ORB-SLAM2's pyramid (as many levels as
    the largest octave needs), blurred 7x7 sigma 2, at centre cvRound((x, y) / s_octave), with
    its own ``angle``. Patch reads past the level's edge reflect (BORDER_REFLECT_101), as on
    OpenCV's bordered pyramid; drop keypoints near the border first if that matters
    (``warpvx.cv.ORB_create().compute`` drops them as cv2 does).

    Parameters
    ----------
    src : uint8 HxW
        Gray image.
    keypoints : Keypoints or list of cv2.KeyPoint
        Level-0 coordinates (finite), ``octave`` in [0, 32) (orb's ``n_levels`` limit) and
        a level that exists for the image, ``angle`` in degrees (finite). Validated on every
        call (:func:`warpvx.keypoints.check_keypoints`): fields of one length and dtype.
    scale_factor : float > 1
    out : uint8 [N, 32], optional
        Writable, C-contiguous; receives the descriptors (N = the number of keypoints).
    backend, stream
        See :mod:`warpvx.backend`.

    Returns
    -------
    uint8 [N, 32]
        In the keypoints' order (``out`` when given).

    Raises
    ------
    WarpvxTypeError
        ``keypoints`` neither Keypoints nor a list of cv2.KeyPoint.
    ShapeError, DTypeError, WarpvxValueError
        Keypoints fields of different lengths or wrong dtypes, NaN/inf coordinates or angles,
        an octave out of range; ``out`` of the wrong shape or dtype, not contiguous, or
        read-only.
    """
    be = resolve_backend(backend, like=src)
    src = _gray(src)
    scale_factor = check_float(scale_factor, "scale_factor", min_value=1.0, strict_min=True)
    if isinstance(keypoints, (list, tuple)):
        keypoints = Keypoints.from_cv(keypoints)
    elif not isinstance(keypoints, Keypoints):
        raise WarpvxTypeError(f"keypoints: expected Keypoints or a list of cv2.KeyPoint, got "
                              f"{type(keypoints).__name__}")
    # Octaves are bounded before any pyramid size is computed (one list entry per level).
    host = check_keypoints(keypoints, n_levels=MAX_LEVELS)
    if len(host) and not np.all(np.isfinite(host.angle)):
        raise WarpvxValueError("keypoints.angle: expected finite angles (degrees), got NaN or inf")
    n_levels = int(host.octave.max()) + 1 if len(host) else 1
    h, w = int(src.shape[0]), int(src.shape[1])
    lw, lh = scale_pyramid_sizes(w, h, n_levels, scale_factor)[-1]
    if lw < 1 or lh < 1:
        raise ShapeError(f"src: image of {w}x{h} (WxH) has no pyramid level {n_levels - 1} "
                         f"(keypoints: octave {n_levels - 1}) at scale_factor {scale_factor}")
    check_out(out, (len(host), DESCRIPTOR_BYTES))
    return dispatch("orb_compute", be, src, keypoints, scale_factor, n_levels, out=out,
                    stream=stream)


__all__ = ["orb", "orb_compute"]
