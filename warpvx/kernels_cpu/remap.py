"""CPU remap: ``cv2.remap`` with float32 maps, coordinates tamed to the Warp sampler's rule.

OpenCV converts a coordinate to int without a range check (|v| >= 2^31 wraps to INT_MIN) and
reflects an out-of-image coordinate one period per loop iteration (seconds per pixel at
1e9). The rule of :mod:`warpvx.kernels_warp._sampling` is applied first: non-finite
coordinates give the border value, finite ones are clamped to +-:data:`COORD_LIMIT`, and
under ``reflect101`` a coordinate at least one period ``2(n - 1)`` out is moved back by
whole periods (exact in float32, the same taps). A fast range check skips all this for the
usual maps.
"""

from __future__ import annotations

import cv2
import numpy as np

#: Finite coordinates are clamped to +-COORD_LIMIT (as the Warp sampler's ``COORD_LIMIT``).
COORD_LIMIT = 1.0e9
#: Under reflect101, OpenCV loops about |v| / (n - 1) times per tap: coordinates within this
#: many periods of the image are passed on untouched.
REFLECT_PERIODS = 16


def remap(src: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, interpolation: int, border: int,
          border_value, *, out=None) -> np.ndarray:
    """Remap a uint8 image with OpenCV.

    Arguments are those of :func:`warpvx.kernels_warp.remap.remap` on host arrays
    (``interpolation`` and ``border`` are OpenCV's integer values, ``border_value`` a
    4-tuple). Returns ``out`` when given. Coordinates follow the module's rule (as the Warp
    backends): NaN/inf give ``border_value`` under every border mode.
    """
    bval = tuple(float(v) for v in border_value)
    h, w = src.shape[0], src.shape[1]
    bad = None
    if not (_tame(map_x, w, border) and _tame(map_y, h, border)):
        bad = ~(np.isfinite(map_x) & np.isfinite(map_y))
        map_x, map_y = _tamed(map_x, w, border), _tamed(map_y, h, border)
    elif map_x.ctypes.data == map_y.ctypes.data:
        # OpenCV >= 4.11 takes one buffer passed as both maps for an interleaved (x, y) map.
        map_y = map_y.copy()
    res = cv2.remap(src, map_x, map_y, interpolation, dst=out, borderMode=border, borderValue=bval)
    if out is not None:
        res = out
    if bad is not None:
        res[bad] = np.asarray(bval[: 1 if res.ndim == 2 else res.shape[2]], dtype=np.uint8)
    return res


def coord_limit(n: int, border: int) -> float:
    """Largest |coordinate| on an axis of ``n`` pixels that OpenCV handles as the rule says,
    quickly."""
    if border == cv2.BORDER_REFLECT_101 and n > 1:
        return float(REFLECT_PERIODS * 2 * (n - 1))
    return COORD_LIMIT


def _tame(m: np.ndarray, n: int, border: int) -> bool:
    """Whether every entry of ``m`` is finite and within :func:`coord_limit` (a fast multi-threaded
    scan: the usual case costs no copy)."""
    lim = coord_limit(n, border)
    return bool(cv2.checkRange(m, True, -lim, lim)[0])


def _tamed(m: np.ndarray, n: int, border: int) -> np.ndarray:
    """A copy of ``m`` with the rule applied (non-finite entries become 0: the caller paints
    those pixels with the border value)."""
    m = np.clip(np.nan_to_num(m, nan=0.0, posinf=0.0, neginf=0.0), -COORD_LIMIT, COORD_LIMIT)
    if border == cv2.BORDER_REFLECT_101 and n > 1:
        period = 2 * (n - 1)
        far = np.abs(m) >= period
        v = m[far].astype(np.float64)
        f = np.floor(v)
        # Whole periods off keep the taps (reflect101 is periodic) and the fraction; the
        # result, smaller than |v|, is a multiple of v's float32 spacing: exact in float32.
        m[far] = (np.mod(f, period) + (v - f)).astype(np.float32)
    return m
