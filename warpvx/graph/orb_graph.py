"""ORB extraction as a graph of per-level stages, and the DAG of thesis Table 5.1 (SPEC §6-7).

:func:`orb_graph` builds a :class:`~warpvx.graph.Graph` with, for each camera and pyramid
level l, the nodes of SPEC §6:

- ``Scale[l]``: level l resized INTER_LINEAR from level l-1 (the ``resize`` primitive: cpu
  and Warp); level 0 is the camera's input;
- ``FAST[l]``: FAST-9/16 per 30x30 cell at the lower threshold;
- ``Grid[l]``: the per-cell threshold (a cell keeps its points >= ``ini_th_fast`` when it has
  any, else >= ``min_th_fast``);
- ``Quadtree[l]``: ORB-SLAM2's ``DistributeOctTree``: sequential on a CPU worker, the fused
  extractor's parallel quadtree on the GPU role (``gpu_quadtree=False``: CPU-exclusive, as
  in the thesis);
- ``Angle[l]``: intensity-centroid orientation;
- ``Blur[l]``: the 7x7, sigma 2 Gaussian (the ``gaussian_blur`` primitive);
- ``Descriptor[l]``: rotated BRIEF;
- ``ScaleBack[l]``: coordinates to level 0 and the keypoint fields;

and one ``Handoff`` per camera joining the levels into the outputs ``cam{i}.x``, ``.y``,
``.response``, ``.size``, ``.angle``, ``.octave`` (float32 / int32 [N]) and ``.descriptors``
(uint8 [N, 32]), equal to ``warpvx.orb(image)``. With ``dl_node_ms`` a GPU-only ``DL`` node
after camera 0's input does real GPU work for that long (:func:`dl_workload`): the thesis'
deep-learning node.

Every stage has a CPU implementation (the CPU extractor's own per-level functions,
:mod:`warpvx.kernels_cpu.orb`) and a Warp one (:mod:`warpvx.kernels_warp.orb_stages`, the
quadtree being the fused Warp extractor's device quadtree run on one level); both compute
ORB-SLAM2's features exactly, so the outputs equal ``warpvx.orb`` whichever side each node is
placed on. The DL node is GPU-only; with ``gpu_quadtree=False`` the quadtree is CPU-only.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from .._orb_spec import cell_grid, features_per_level, keypoint_sizes
from .._pyramid_sizes import scale_pyramid_sizes
from ..check import check_float, check_int
from ..errors import WarpvxValueError
from ..kernels_cpu import orb as orb_cpu
from .graph import Graph

#: The camera counts of thesis Table 5.1: monocular, stereo, four stereo pairs.
CAMERAS = (1, 2, 8)
KEYPOINT_FIELDS = ("x", "y", "response", "size", "angle", "octave")


def orb_graph(cameras: int = 1, levels: int = 8, dl_node_ms=None, *, width: int = 1241,
              height: int = 376, n_features: int = 2000, scale_factor: float = 1.2,
              ini_th_fast: int = 20, min_th_fast: int = 7, gpu_quadtree: bool = True) -> Graph:
    """The ORB extraction DAG of thesis Table 5.1 as a graph of per-level stage nodes.

    Parameters
    ----------
    cameras : int
        1, 2 or 8 extractions (inputs ``cam0`` ..), each a gray uint8 [height, width] image.
    levels : int
        Pyramid levels, >= 1 (ORB-SLAM2: 8).
    dl_node_ms : float or None
        Milliseconds of GPU work of the GPU-only ``DL`` node (thesis: 15, 20, 25); None for no
        node. Its output ``dl`` is a float32 [256] array.
    width, height : int
        Camera image size (KITTI: 1241x376).
    n_features, scale_factor, ini_th_fast, min_th_fast
        As :func:`warpvx.orb`.
    gpu_quadtree : bool
        True: ``Quadtree`` nodes have both implementations, the sequential one on a CPU worker
        and the fused extractor's parallel one on the GPU role. False: CPU-exclusive, the
        sequential quadtree only (the thesis' Table 5.1 setting).

    Returns
    -------
    Graph
        Named ``orb-{cameras}cam`` (``+dl{ms}``); outputs ``cam{i}.{field}`` (see the module
        docstring) and ``dl``.

    Raises
    ------
    WarpvxValueError
        A bad count, size or time (the message names the argument).
    """
    cameras = check_int(cameras, "cameras", min_value=1)
    levels = check_int(levels, "levels", min_value=1)
    width = check_int(width, "width", min_value=1)
    height = check_int(height, "height", min_value=1)
    n_features = check_int(n_features, "n_features", min_value=1)
    scale_factor = check_float(scale_factor, "scale_factor", min_value=1.0, strict_min=True)
    sizes = scale_pyramid_sizes(width, height, levels, scale_factor)
    if min(min(s) for s in sizes) < 1:
        raise WarpvxValueError(f"levels: {levels} levels of {width}x{height} reach an empty level")
    wanted = features_per_level(n_features, scale_factor, levels)
    name = f"orb-{cameras}cam"
    if dl_node_ms is not None:
        dl_node_ms = check_float(dl_node_ms, "dl_node_ms", min_value=0.0, strict_min=True)
        name += f"+dl{dl_node_ms:g}"
    g = Graph(name)
    ths = (int(ini_th_fast), int(min_th_fast))
    for cam in range(cameras):
        src = g.input(f"cam{cam}", shape=(height, width), dtype=np.uint8)
        if cam == 0 and dl_node_ms is not None:
            g.output("dl", g.user(None, [src], warp_fn=dl_workload(dl_node_ms), name="DL"))
        parts, prev = [], src
        for lvl in range(levels):
            tag = f"{cam}.{lvl}"
            img = prev if lvl == 0 else g.resize(prev, dsize=sizes[lvl], name=f"Scale{tag}")
            prev = img
            fast, fast_warp = _fast(min(ths))
            x, y, s = g.user(fast, [img], 3, warp_fn=fast_warp, name=f"FAST{tag}")
            grid, grid_warp = _grid(ths)
            x, y, s = g.user(grid, [img, x, y, s], 3, warp_fn=grid_warp, name=f"Grid{tag}")
            tree, tree_warp = _quadtree(wanted[lvl], scale_factor, gpu_quadtree)
            x, y, s = g.user(tree, [img, x, y, s], 3, warp_fn=tree_warp, name=f"Quadtree{tag}")
            angle = g.user(orb_cpu.compute_orientation, [img, x, y], warp_fn=_warp("angle"),
                           name=f"Angle{tag}")
            blurred = g.gaussian_blur(img, 7, 2.0, name=f"Blur{tag}")
            desc = g.user(orb_cpu.compute_descriptors, [blurred, x, y, angle],
                          warp_fn=_warp("describe"), name=f"Descriptor{tag}")
            back, back_warp = _scale_back(lvl, scale_factor, levels)
            back = g.user(back, [x, y, s, angle], 6, warp_fn=back_warp, name=f"ScaleBack{tag}")
            parts.append((*back, desc))
        joined = g.user(_handoff, [d for part in parts for d in part], len(KEYPOINT_FIELDS) + 1,
                        warp_fn=_warp("handoff", n_fields=len(KEYPOINT_FIELDS) + 1),
                        name=f"Handoff{cam}")
        for field, data in zip(KEYPOINT_FIELDS + ("descriptors",), joined):
            g.output(f"cam{cam}.{field}", data)
    return g


# ------------------------------------------------------------------------ stage callables
# Each factory returns the node's (fn, warp_fn): plain functions of the node's inputs (user
# nodes take positional arrays), parameters bound by closure so one graph can hold levels with
# different settings. The qualified names carry the parameters: calibration caches a node's
# costs under its callables' names and input sizes.


def _named(fn, label: str):
    fn.__qualname__ = label
    return fn


def _warp(stage: str, *args, **kwargs):
    """``kernels_warp.orb_stages.<stage>(*inputs, *args, **kwargs)``, imported at the first
    call (building the graph loads no Warp)."""
    def run(*inputs):
        from ..kernels_warp import orb_stages

        return getattr(orb_stages, stage)(*inputs, *args, **kwargs)
    params = ",".join(map(str, args + tuple(kwargs.values())))
    return _named(run, f"orb_stages.{stage}[{params}]")


def _fast(th):
    def fast(level):
        return orb_cpu.detect_cells(level, th)
    return _named(fast, f"fast[{th}]"), _warp("fast", th)


def _grid(ths):
    def grid(level, x, y, s):
        keep = orb_cpu.select_cells(x, y, s, cell_grid(level.shape[1], level.shape[0]), *ths)
        return x[keep], y[keep], s[keep]
    return _named(grid, f"grid[{ths}]"), _warp("grid", *ths)


def _quadtree(n_wanted, scale_factor, on_gpu):
    def quadtree(level, x, y, s):
        kept = orb_cpu.distribute_octtree(x, y, s, cell_grid(level.shape[1], level.shape[0]),
                                          n_wanted)
        return x[kept], y[kept], s[kept]
    return (_named(quadtree, f"quadtree[{n_wanted}]"),
            _warp("quadtree", n_wanted, scale_factor) if on_gpu else None)


def _scale_back(lvl, scale_factor, levels):
    size = keypoint_sizes(scale_factor, levels)[lvl]

    def scale_back(x, y, s, angle):
        octave = np.full(x.size, lvl, np.int32)
        sx, sy = orb_cpu.scale_back(x, y, octave, scale_factor, levels)
        return (sx, sy, s.astype(np.float32), np.full(x.size, size, np.float32),
                np.asarray(angle, np.float32), octave)
    return (_named(scale_back, f"scale_back[{lvl},{scale_factor},{levels}]"),
            _warp("scale_back", lvl, scale_factor, levels))


def _handoff(*parts):
    """Concatenate per-level (x, y, response, size, angle, octave, descriptors) tuples."""
    n = len(KEYPOINT_FIELDS) + 1
    return tuple(np.concatenate(parts[i::n], axis=0) for i in range(n))


# ------------------------------------------------------------------------ the DL node

_DL_THREADS = 4096
_DL_OUT = 256


@functools.lru_cache(maxsize=None)
def _dl_kernel():
    import warp as wp

    @wp.kernel
    def multiply_accumulate(iters: int, out: wp.array(dtype=wp.float32)):
        # A dependent chain of 4x4 matrix products per thread: arithmetic the compiler cannot
        # drop (the result is written), memory traffic negligible, so time ~ iters.
        i = wp.tid()
        a = wp.mat44(1.0) * (1.0 + float(i % 7) * 1.0e-3)
        b = wp.mat44(0.5)
        for _ in range(iters):
            a = a * b * 0.5 + wp.mat44(1.0e-3)
        wp.atomic_add(out, i % out.shape[0], a[0, 0])

    return multiply_accumulate


def _run_dl(iters: int, device):
    import warp as wp

    out = wp.zeros(_DL_OUT, dtype=wp.float32, device=device)
    wp.launch(_dl_kernel(), dim=_DL_THREADS, inputs=[int(iters)], outputs=[out], device=device)
    return out


def busy_clock(device: str):
    """The clock a DL node's duration is measured with on ``device``: the calling thread's CPU
    time on Warp's CPU device (its kernels run on the calling thread, so other processes' load
    on a shared host does not count as work), wall time on a GPU."""
    return time.thread_time if str(device) == "cpu" else time.perf_counter


def _seconds(iters: int, device) -> float:
    import warp as wp

    clock = busy_clock(device)
    wp.synchronize_device(device)
    t0 = clock()
    _run_dl(iters, device)
    wp.synchronize_device(device)
    return clock() - t0


@functools.lru_cache(maxsize=None)
def dl_iterations(ms: float, device: str) -> int:
    """Iterations of the DL kernel that take ``ms`` milliseconds on ``device`` (calibrated).

    Times a short run, scales linearly, then refines on runs near the target until within 2%
    (the launch's fixed cost is measured in, not guessed).
    """
    _seconds(1, device)  # compile and load the module outside the timing
    iters = 16
    while _seconds(iters, device) < 2e-3 and iters < 1 << 30:
        iters *= 4
    # Median of three per step (a busy host inflates single runs); stop once within 2%.
    for _ in range(5):
        took = sorted(_seconds(iters, device) for _ in range(3))[1]
        ratio = (ms * 1e-3) / max(took, 1e-9)
        iters = max(1, int(round(iters * ratio)))
        if abs(ratio - 1.0) < 0.02:
            break
    return iters


def dl_workload(ms: float):
    """The ``warp_fn`` of a GPU-only node doing ``ms`` milliseconds of real GPU work.

    The returned callable takes the node's input (any ``wp.array``, used only for its device)
    and returns a float32 [256] ``wp.array``: a grid of threads each running a calibrated chain
    of 4x4 matrix multiply-adds (:func:`dl_iterations`, calibrated once per device and time).
    Not a sleep: the GPU is busy for that long, so it competes with the other GPU nodes.
    """
    ms = check_float(ms, "ms", min_value=0.0, strict_min=True)

    def dl(src):
        device = str(src.device)
        return _run_dl(dl_iterations(ms, device), device)

    # Calibration caches costs by callable name and input sizes: one name per duration.
    return _named(dl, f"dl_workload[{ms:g}ms]")
