"""FAST corners and pyramidal LK on a Warp device: before / after / OpenCV in one run.

The cases are the registry's own bench cases (``warpvx.bench.cases.fast_corners``,
``warpvx.bench.cases.optical_flow_pyr_lk``) on the benchmark photo at each size, timed
through the public functions with :func:`warpvx.bench.time_per_call_s` (warm-up and JIT excluded,
batches between two device synchronisations, median). OpenCV runs on all cores beside them.

``--before DIR``: DIR holds ``old_fast_corners.py`` and ``old_optical_flow_pyr_lk.py``,
copies of the previous Warp modules with absolute imports; the registry's Warp
implementations (and, for the video-loop row, the previous pyramid path of
:func:`warpvx.flow.build_optical_flow_pyramid`) are pointed at them for the "before" column,
and their results are compared with the current ones (``same``).

Run on the GPU machine from the repository root::

    PYTHONPATH=. python3 benchmarks/perf/fast_lk.py --before build/fast_lk_before
"""

from __future__ import annotations

import argparse
import importlib.util
import sys

import numpy as np

import warpvx
from warpvx import flow
from warpvx.bench import Settings, load_photo, photo_at, time_per_call_s
from warpvx.bench.cases import fast_corners, optical_flow_pyr_lk
from warpvx.registry import REGISTRY

PRIMS = {"fast_corners": "old_fast_corners", "optical_flow_pyr_lk": "old_optical_flow_pyr_lk"}


def _load(path, name):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def _old_pyramid(img, max_level, be, stream):
    """The previous ``warpvx.flow._pyramid``: the public gaussian_pyramid every frame."""
    from warpvx.pyramid import gaussian_pyramid

    return gaussian_pyramid(img, max_level + 1, backend=be, stream=stream)


class Variant:
    """Points the registry (and flow's pyramid helper) at the old or the current code."""

    def __init__(self, before_dir):
        self.new = {p: REGISTRY[p].implementation("warp") for p in PRIMS}
        self.new_pyramid = flow._pyramid
        self.old = None
        if before_dir:
            self.old = {p: getattr(_load(f"{before_dir}/{m}.py", m), p) for p, m in PRIMS.items()}

    def use(self, which):
        impls = self.old if which == "before" else self.new
        for p, f in impls.items():
            REGISTRY[p]._loaded["warp"] = f
        flow._pyramid = _old_pyramid if which == "before" else self.new_pyramid


def _host(result):
    """A comparable host copy of a call's result."""
    if isinstance(result, warpvx.Keypoints):
        h = result.to("host")
        return [np.asarray(getattr(h, f)) for f in ("x", "y", "response", "size", "angle", "octave")]
    return [a.numpy() for a in result]


def _same(a, b) -> bool:
    return len(a) == len(b) and all(x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", default=None, help="directory of the old_*.py baselines")
    ap.add_argument("--device", default="cuda:0", help="a Warp backend: cuda:N or warp-cpu")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--sizes", default="1920x1080,1241x376")
    args = ap.parse_args(argv)

    import cv2
    import warp as wp

    wp.config.quiet = True
    wp.init()
    settings = Settings(repeat=args.repeat)
    device = args.device

    wp_device = "cpu" if device == "warp-cpu" else device

    def sync():
        wp.synchronize_device(wp_device)

    variant = Variant(args.before)
    photo = load_photo()
    print(f"{'case':52s} {'size':>10s} {'before us':>10s} {'after us':>9s} {'opencv us':>10s} "
          f"{'x before':>8s} {'x after':>8s} same")
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.split("x"))
        img = photo_at(photo, (w, h))
        cases = fast_corners.cases(img) + optical_flow_pyr_lk.cases(img)
        for case in cases:
            cv_fn = case.opencv()
            t_cv, _ = time_per_call_s(cv_fn, settings=settings)
            times, results = {}, {}
            for which in (("before", "after") if variant.old else ("after",)):
                variant.use(which)
                fn = case.prepare(device)
                results[which] = _host(fn())
                times[which], _ = time_per_call_s(fn, sync, settings=settings,
                                                  min_calls=settings.gpu_min_calls)
                sync()
            variant.use("after")
            tb = times.get("before")
            ta = times["after"]
            same = "-" if tb is None else ("yes" if _same(results["before"], results["after"]) else "NO")
            print(f"{(case.primitive + ' ' + case.label)[:52]:52s} {w}x{h:<5d} "
                  f"{(tb or 0) * 1e6:10.1f} {ta * 1e6:9.1f} {t_cv * 1e6:10.1f} "
                  f"{(t_cv / tb if tb else 0):8.2f} {t_cv / ta:8.2f} {same}", flush=True)
    print(f"cv2 threads {cv2.getNumThreads()}, device {wp.get_device(wp_device).name}")


if __name__ == "__main__":
    main()
