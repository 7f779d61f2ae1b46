"""ORB-SLAM2's ORB extractor: the constants and tables that define the algorithm.

Neutral module shared by both backends (``kernels_cpu.orb``, ``kernels_warp.orb``) and the
public :mod:`warpvx.orb_extractor`: level scales and sizes, features per level, the FAST cell
grid, the radius-15 disc (``umax``), the 31x31 BRIEF pattern, ``fastAtan2``'s coefficients and
the quadtree's root nodes. References: ORB-SLAM2 ``src/ORBextractor.cc``; OpenCV
``core/src/mathfuncs_core.simd.hpp`` (``fastAtan2``).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np

from .errors import UnsupportedError

PATCH_SIZE = 31
HALF_PATCH_SIZE = 15
EDGE_THRESHOLD = 19
# ComputeKeyPointsOctTree: cells are laid over [EDGE_THRESHOLD - 3, size - EDGE_THRESHOLD + 3).
MIN_BORDER = EDGE_THRESHOLD - 3
FAST_CELL = 30
# A level needs one whole cell inside its borders (nCols = width / 30 >= 1).
MIN_LEVEL_SIZE = 2 * MIN_BORDER + FAST_CELL
DESCRIPTOR_BYTES = 32
# Largest image side accepted (the Warp candidate keys hold 16-bit coordinates and 2^18 cells).
MAX_SIDE = 15000
# Rotated pattern points land within 18 px of the centre on each axis (|(13, 13)| < 18.4).
PATTERN_RADIUS = 19


def level_scales(scale_factor: float, n_levels: int) -> np.ndarray:
    """float32 [n_levels]: s_0 = 1, s_l = s_(l-1) * scale_factor in float (mvScaleFactor)."""
    scales = np.ones(n_levels, np.float32)
    f = np.float32(scale_factor)
    for level in range(1, n_levels):
        scales[level] = np.float32(scales[level - 1] * f)
    return scales


def c_round(v: float) -> int:
    """cvRound of a float: round half to even (what lrint does in the default mode)."""
    return int(np.rint(np.float32(v)))


def features_per_level(n_features: int, scale_factor: float, n_levels: int) -> list:
    """Features wanted per level, ORB-SLAM2's rule (float arithmetic, cvRound, remainder last).

    n0 = N (1 - f) / (1 - f^L) with f = 1 / scale_factor, level l gets cvRound(n0 f^l), the
    last level ``max(N - sum, 0)``. For N = 2000, 1.2, 8: 434 362 302 251 209 175 145 122.
    """
    factor = np.float32(1.0) / np.float32(scale_factor)
    per_scale = np.float32(
        np.float32(n_features) * (np.float32(1.0) - factor)
        / (np.float32(1.0) - np.float32(math.pow(float(factor), float(n_levels))))
    )
    counts = []
    total = 0
    for _ in range(n_levels - 1):
        c = c_round(per_scale)
        counts.append(c)
        total += c
        per_scale = np.float32(per_scale * factor)
    counts.append(max(n_features - total, 0))
    return counts


def keypoint_sizes(scale_factor: float, n_levels: int) -> np.ndarray:
    """float32 [n_levels]: ORB-SLAM2's ``int(PATCH_SIZE * s_l)`` (truncated to an integer)."""
    return np.array([int(np.float32(PATCH_SIZE) * s) for s in level_scales(scale_factor, n_levels)],
                    np.float32)


@dataclass(frozen=True)
class CellGrid:
    """ComputeKeyPointsOctTree's cells for one level of ``width`` x ``height``.

    FAST runs on cell (i, j) over rows ``row_spans[i]`` and columns ``col_spans[j]`` (each
    ``[start, stop)``, cells overlapping by 6 px); FAST reports corners 3 px inside its input,
    so each cell *owns* the pixels of ``[start + 3, stop - 3)``; those inner areas tile the
    level without overlap. ``row_of_y[y]`` / ``col_of_x[x]`` give the owning cell row / column
    of a pixel, -1 where no cell owns it.
    """

    width: int
    height: int
    row_spans: tuple
    col_spans: tuple
    row_of_y: np.ndarray
    col_of_x: np.ndarray

    @property
    def n_rows(self) -> int:
        return len(self.row_spans)

    @property
    def n_cols(self) -> int:
        return len(self.col_spans)

    @property
    def max_border_x(self) -> int:
        return self.width - EDGE_THRESHOLD + 3

    @property
    def max_border_y(self) -> int:
        return self.height - EDGE_THRESHOLD + 3


def _spans(size: int, skip_margin: int) -> tuple:
    """Cell spans along one axis (ComputeKeyPointsOctTree, float arithmetic as there)."""
    max_border = size - EDGE_THRESHOLD + 3
    extent = np.float32(max_border - MIN_BORDER)
    n = int(extent / np.float32(FAST_CELL))
    if n < 1:
        return ()
    step = int(math.ceil(np.float32(extent / np.float32(n))))
    spans = []
    for i in range(n):
        start = MIN_BORDER + i * step
        if start >= max_border - skip_margin:
            continue
        spans.append((start, min(start + step + 6, max_border)))
    return tuple(spans)


@functools.lru_cache(maxsize=64)
def cell_grid(width: int, height: int) -> CellGrid:
    """The cell grid of a ``width`` x ``height`` level (cached per size)."""
    # ORB-SLAM2 skips a row of cells starting within 3 px of the bottom border, a column
    # within 6 px of the right one.
    rows = _spans(height, 3)
    cols = _spans(width, 6)
    row_of_y = np.full(height, -1, np.int32)
    col_of_x = np.full(width, -1, np.int32)
    for i, (a, b) in enumerate(rows):
        row_of_y[a + 3:max(b - 3, a + 3)] = i
    for j, (a, b) in enumerate(cols):
        col_of_x[a + 3:max(b - 3, a + 3)] = j
    row_of_y.setflags(write=False)
    col_of_x.setflags(write=False)
    return CellGrid(width, height, rows, cols, row_of_y, col_of_x)


@functools.lru_cache(maxsize=1)
def umax() -> np.ndarray:
    """int32 [16]: half-width of each row of the radius-15 disc (ORB-SLAM2's umax)."""
    hp = HALF_PATCH_SIZE
    u = np.zeros(hp + 1, np.int32)
    vmax = int(math.floor(hp * math.sqrt(2.0) / 2 + 1))
    vmin = int(math.ceil(hp * math.sqrt(2.0) / 2))
    for v in range(vmax + 1):
        u[v] = c_round(math.sqrt(hp * hp - v * v))
    v0 = 0
    for v in range(hp, vmin - 1, -1):  # make the disc symmetric in u and v
        while u[v0] == u[v0 + 1]:
            v0 += 1
        u[v] = v0
        v0 += 1
    u.setflags(write=False)
    return u


@functools.lru_cache(maxsize=1)
def pattern() -> np.ndarray:
    """int32 [256, 4]: the (x1, y1, x2, y2) point pairs of ORB's 31x31 pattern (package data)."""
    text = resources.files("warpvx").joinpath("data/orb_pattern_31.txt").read_text()
    rows = [line.split() for line in text.splitlines() if line.strip() and not line.startswith("#")]
    table = np.array(rows, np.int32)
    if table.shape != (256, 4):
        raise RuntimeError(f"orb_pattern_31.txt: expected 256 rows of 4 integers, got "
                           f"{table.shape}")
    table.setflags(write=False)
    return table


# OpenCV's fastAtan2 (atan_f32 in core/src/mathfuncs_core.simd.hpp): a 7th-order polynomial in
# degrees, float arithmetic; each coefficient is a float product as there.
_DEG = np.float32(180.0 / math.pi)
ATAN_P1 = float(np.float32(np.float32(0.9997878412794807) * _DEG))
ATAN_P3 = float(np.float32(np.float32(-0.3258083974640975) * _DEG))
ATAN_P5 = float(np.float32(np.float32(0.1555786518463281) * _DEG))
ATAN_P7 = float(np.float32(np.float32(-0.04432655554792128) * _DEG))
ATAN_EPS = float(np.float32(np.finfo(np.float64).eps))


def fast_atan2(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """float32 degrees in [0, 360): OpenCV's ``cv::fastAtan2(y, x)``, elementwise."""
    y = np.asarray(y, np.float32)
    x = np.asarray(x, np.float32)
    ax, ay = np.abs(x), np.abs(y)
    wide = ax >= ay
    eps = np.float32(ATAN_EPS)
    c = np.where(wide, ay, ax) / (np.where(wide, ax, ay) + eps)
    c2 = c * c
    p = (((np.float32(ATAN_P7) * c2 + np.float32(ATAN_P5)) * c2 + np.float32(ATAN_P3)) * c2
         + np.float32(ATAN_P1)) * c
    a = np.where(wide, p, np.float32(90.0) - p)
    a = np.where(x < 0, np.float32(180.0) - a, a)
    a = np.where(y < 0, np.float32(360.0) - a, a)
    return a.astype(np.float32)


def root_geometry(grid: CellGrid) -> tuple:
    """DistributeOctTree's root nodes of a level: ``(n_ini, hX, bounds, height)``.

    The quadtree spans ``[MIN_BORDER, maxBorder)`` on each axis; ``n_ini = round(w / h)``
    root nodes (at least 1) of width ``hX`` (float32) side by side, ``bounds`` the n_ini + 1
    integer column boundaries ``int(hX i)`` relative to MIN_BORDER, ``height`` the root nodes'
    height (maxBorderY - MIN_BORDER).
    """
    width = grid.max_border_x - MIN_BORDER
    height = grid.max_border_y - MIN_BORDER
    n_ini = max(1, int(math.floor(float(np.float32(width) / np.float32(height)) + 0.5)))
    hx = np.float32(np.float32(width) / np.float32(n_ini))
    bounds = [int(np.float32(hx * np.float32(i))) for i in range(n_ini + 1)]
    return n_ini, hx, bounds, height


def refuse_out(out) -> None:
    """Both backends' ``orb`` take ``out=`` (the registry's calling convention) but cannot
    honour it: the keypoint count is data-dependent, so the outputs are always new arrays."""
    if out is not None:
        raise UnsupportedError("out: orb returns a data-dependent number of keypoints and "
                               "allocates its outputs; call it without out=")
