"""Device time of pyramidal LK per call: one launch per level against one launch for all levels
(issue 11).

The graph bench's frames (``benchmarks/graph_bench.make_frames``: two cameras, 1280x720),
frame 0 to frame 1 of each camera, their pyramids built beforehand (as the graph's pyramid
nodes do), Shi-Tomasi corners of frame 0 (``--points``: 500 and 1000; quality 0.01, min
distance 5), 21x21 window, ``max_level`` 3 (4 levels), 30 iterations, eps 0.01. Each call of
the Warp implementation (``warpvx.kernels_warp.optical_flow_pyr_lk``, out= buffers) is
captured as a CUDA graph and replayed, timed with CUDA events (``harris_select.Timer``:
``--repeat`` trials of ``--replays`` replays, the median trial per replay), with a per-kernel
breakdown of eager calls.

Variants, in one process on the same data (``same``: outputs bit-identical to the first row's):

- ``before``: ``--before FILE``, another version of the Warp LK module (e.g. main's, written
  with ``git show main:warpvx/kernels_warp/optical_flow_pyr_lk.py > FILE``), loaded as a
  module of ``warpvx.kernels_warp``;
- ``per level``: this checkout with ``LEVELS_PER_LAUNCH = 1`` (a launch per level, the maths
  unchanged);
- ``fused``: this checkout as it is (all 4 levels in one launch, no grid-stride loop);
- with ``--sweep``, ``fused`` variants: ``grid-stride`` (the kernel with Warp's grid-stride
  loop: more registers), ``<=R regs`` (``launch_bounds=(BLOCK_DIM, B)``: B points per SM,
  the compiler spilling what does not fit), ``L lanes`` (``BLOCK_DIM``; the sums' order
  changes, so not bit-identical).

A checkout without ``LEVELS_PER_LAUNCH`` (the per-level kernel) gives one row, ``as is``.

Run on the GPU machine from the repository root (a minute or two on an H100)::

    PYTHONPATH=. python3 benchmarks/perf/lk_levels.py --sweep --out $OUT

``--device cpu`` runs it on Warp's CPU device (no capture; host wall time; a smoke test).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import os
import sys
import time

import cv2
import numpy as np
import warp as wp

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from harris_select import (SIZE, Timer, frames, kernel_breakdown, patched,  # noqa: E402
                           write_results)

LK = dict(win_size=(21, 21), max_level=3, max_iters=30, eps=0.01, min_eig_threshold=1e-4)
COMMAND = "PYTHONPATH=. python3 benchmarks/perf/lk_levels.py --out $OUT"


def load_module(path: str):
    """The LK module at ``path``, imported as ``warpvx.kernels_warp._lk_before`` (so its
    relative imports resolve; Warp compiles it as a module of its own)."""
    name = "warpvx.kernels_warp._lk_before"
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def variants(before: str | None, sweep: bool) -> list:
    """``(label, module, context)`` of each variant to time (kernels compiled once)."""
    from warpvx.kernels_warp import optical_flow_pyr_lk as lk

    out = [("before", load_module(before), contextlib.nullcontext)] if before else []
    if not hasattr(lk, "LEVELS_PER_LAUNCH"):
        return out + [("as is", lk, contextlib.nullcontext)]
    out += [("per level", lk, lambda: patched(lk, LEVELS_PER_LAUNCH=1)),
            ("fused", lk, contextlib.nullcontext)]
    if sweep:
        def kernel(**options):  # the same kernel function compiled with other options
            k = wp.kernel(lk.track_points.func, module="unique", enable_backward=False, **options)
            return lambda: patched(lk, track_points=k)

        out.append(("fused, grid-stride", lk, kernel(grid_stride=True)))
        for blocks in (5, 8):
            regs = 65536 // (blocks * lk.BLOCK_DIM) // 8 * 8
            out.append((f"fused, <={regs} regs", lk,
                        kernel(grid_stride=False, launch_bounds=(lk.BLOCK_DIM, blocks))))
        for lanes in (n for n in (64, 128, 256) if n != lk.BLOCK_DIM):
            out.append((f"fused, {lanes} lanes", lk, lambda n=lanes: patched(lk, BLOCK_DIM=n)))
    return out


def lk_rows(cams, device, timer, counts, kinds) -> list:
    """A row per camera, point count and variant (``kinds``: :func:`variants`)."""
    import warpvx

    rows = []
    for cam, (gray0, gray1) in cams.items():
        pyrs = [warpvx.build_optical_flow_pyramid(g, LK["win_size"], LK["max_level"])
                for g in (gray0, gray1)]
        host = gray0.numpy()
        for n in counts:
            pts_host = cv2.goodFeaturesToTrack(host, n, 0.01, 5).reshape(-1, 2).astype(np.float32)
            pts = wp.array(pts_host, dtype=wp.float32, device=device)
            m = len(pts_host)
            out = (wp.empty((m, 2), dtype=wp.float32, device=device),
                   wp.empty(m, dtype=wp.uint8, device=device),
                   wp.empty(m, dtype=wp.float32, device=device))
            first = None
            for label, mod, ctx in kinds:
                print(f"  LK {cam} {m} points: {label}", flush=True)
                with ctx():
                    def call(mod=mod):
                        mod.optical_flow_pyr_lk(pyrs[0], pyrs[1], pts, None, LK["win_size"],
                                                LK["max_level"], LK["max_iters"], LK["eps"],
                                                LK["min_eig_threshold"], out=out)
                    call()
                    wp.synchronize_device(device)
                    result = [a.numpy().copy() for a in out]
                    t = timer(call)
                    kernels = kernel_breakdown(call, device)
                if first is None:
                    first = result
                same = all(np.array_equal(a, b) for a, b in zip(result, first))
                rows.append(dict(camera=cam, points=m, variant=label, us=t * 1e6, same=same,
                                 tracked=int(result[1].sum()), kernels=kernels))
    return rows


def markdown(rows, device, args) -> str:
    how = "captured graph replays" if not device.is_cpu else "host wall time"
    command = COMMAND + "".join(f" --{k} {v}" for k, v in (("before", args.before),
                                                            ("points", args.points)) if v)
    command += " --sweep" if args.sweep else ""
    lines = [f"Regenerate: `{command}`", "",
             f"# LK device time per call, {SIZE[0]}x{SIZE[1]}, 21x21, 4 levels, {device.name}", "",
             f"{how}, median of {args.repeat} trials of {args.replays} replays; `x first`: the "
             "first variant's time / this one's; `same`: outputs bit-identical to the first "
             "variant's.", "",
             "| camera | points | variant | us/call | x first | same | tracked |",
             "|---|---|---|---|---|---|---|"]
    first = {}
    for r in rows:
        base = first.setdefault((r["camera"], r["points"]), r["us"])
        lines.append(f"| {r['camera']} | {r['points']} | {r['variant']} | {r['us']:.1f} | "
                     f"{base / r['us']:.2f} | {'yes' if r['same'] else 'NO'} | {r['tracked']} |")
    lines += ["", "## Kernels per eager call (us)", ""]
    for r in rows:
        if r["kernels"]:
            lines.append(f"- {r['camera']} {r['points']} {r['variant']}: " + ", ".join(
                f"{k} {v:.1f}" for k, v in list(r["kernels"].items())[:6]))
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda:0", help="cuda:N or cpu")
    ap.add_argument("--points", default="500,1000", help="corner counts, comma separated")
    ap.add_argument("--before", default=None, help="another LK module file to time first")
    ap.add_argument("--sweep", action="store_true", help="also the fused kernel's variants")
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--replays", type=int, default=50)
    ap.add_argument("--out", default=os.environ.get("OUT", "."))
    args = ap.parse_args(argv)
    wp.config.quiet = True
    wp.init()
    device = wp.get_device(args.device)
    t0 = time.time()
    with wp.ScopedDevice(device):
        rows = lk_rows(frames(device), device, Timer(device, args.repeat, args.replays),
                       [int(v) for v in args.points.split(",")], variants(args.before, args.sweep))
    write_results(args.out, "lk_levels", markdown(rows, device, args), rows, t0)


if __name__ == "__main__":
    main()
