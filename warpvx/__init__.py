"""warpvx: embedded-vision primitives on NumPy/OpenCV and NVIDIA Warp, OpenVX-style graphs
over them, and a HEFT/XEFT scheduler that overlaps CPU workers with a CUDA stream.

Public names are imported lazily (PEP 562), so ``import warpvx`` neither imports Warp nor
compiles a kernel; the first call of a Warp backend does.
"""

from __future__ import annotations

import importlib

from .backend import available_backends, cuda_available, get_backend, set_backend
from .errors import (
    BackendError,
    CaptureAllocationError,
    DTypeError,
    GraphError,
    NodeExecutionError,
    ScheduleError,
    ShapeError,
    UnsupportedError,
    WarpvxError,
    WarpvxTypeError,
    WarpvxValueError,
)
from .keypoints import Keypoints

__version__ = "0.1.0"

_LAZY = {
    "color_convert": "warpvx.color",
    "remap": "warpvx.geometry",
    "warp_perspective": "warpvx.geometry",
    "gaussian_pyramid": "warpvx.pyramid",
    "scale_pyramid": "warpvx.pyramid",
    "resize": "warpvx.pyramid",
    "gaussian_blur": "warpvx.filters",
    "fast_corners": "warpvx.features",
    "harris_response": "warpvx.features",
    "harris_corners": "warpvx.features",
    "optical_flow_pyr_lk": "warpvx.flow",
    "build_optical_flow_pyramid": "warpvx.flow",
    "orb": "warpvx.orb_extractor",
    "orb_compute": "warpvx.orb_extractor",
    "match_hamming": "warpvx.matching",
    "knn_match_hamming": "warpvx.matching",
    "find_homography": "warpvx.homography",
    "Graph": "warpvx.graph",
    "orb_graph": "warpvx.graph.orb_graph",
    "Delay": "warpvx.graph",
    "cv": "warpvx.cv",
    "sched": "warpvx.sched",
    "registry": "warpvx.registry",
}


def __getattr__(name):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'warpvx' has no attribute {name!r}")
    mod = importlib.import_module(module)
    value = mod if module == f"warpvx.{name}" else getattr(mod, name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + list(_LAZY))


__all__ = [
    "__version__",
    "available_backends",
    "cuda_available",
    "get_backend",
    "set_backend",
    "Keypoints",
    "WarpvxError",
    "WarpvxValueError",
    "WarpvxTypeError",
    "ShapeError",
    "DTypeError",
    "BackendError",
    "UnsupportedError",
    "GraphError",
    "ScheduleError",
    "NodeExecutionError",
    "CaptureAllocationError",
    *_LAZY,
]
