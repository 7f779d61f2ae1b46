"""Benchmark cases, one module per primitive (``warpvx.bench.cases.<primitive>``).

Each module has ``cases(image_bgr) -> list[BenchCase]``, named by the primitive's ``bench=``
entry in :mod:`warpvx.registry`: the warpvx call at the photo's size, OpenCV's equivalent
beside it, and the GPU peers' (CV-CUDA, Kornia) where they have one. Peer code imports its
library inside its prepare function, so a missing library only skips that peer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ...arrays import to_warp
from ...backend import resolve_backend


@dataclass
class BenchCase:
    """One benchmark row: a primitive call at one size, with OpenCV (and peers) beside it.

    Attributes
    ----------
    primitive : str
        Registry name.
    label : str
        What is run, e.g. ``"BGR2GRAY"``.
    size : (int, int)
        (width, height) of the input.
    prepare : callable(backend_name) -> callable() -> object
        Allocates inputs (and ``out=`` buffers) on the backend's device once and returns a
        zero-argument function doing one call; the harness warms it up and times it.
    opencv : callable() -> callable() -> object, optional
        The same for the OpenCV reference on host data.
    peers : dict of name -> callable() -> callable() or None
        Other libraries (CV-CUDA, Kornia); each prepare may raise ImportError to be skipped.
    bytes_moved : int, optional
        Bytes read plus written by one call, for the memory-bandwidth floor.
    """

    primitive: str
    label: str
    size: tuple
    prepare: Callable
    opencv: Callable | None = None
    peers: dict = field(default_factory=dict)
    bytes_moved: int | None = None


def place(host: np.ndarray, backend):
    """``host`` where ``backend`` (a name or :class:`~warpvx.backend.Backend`) computes: the
    NumPy array itself for ``"cpu"``, else a copy as a ``wp.array`` on the backend's device."""
    be = resolve_backend(backend)
    return host if be.kind == "cpu" else to_warp(host, be.device)


__all__ = ["BenchCase", "place"]
