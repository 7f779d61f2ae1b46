"""GPU micro-benchmark of the pointwise primitives: colour conversion, remap, perspective warp.

Usage (on the GPU machine, from the repository root)::

    PYTHONPATH=. python3 benchmarks/perf/pointwise.py [--size 1920x1080] [--old DIR]

For each benchmark case of ``color_convert``, ``remap`` and ``warp_perspective`` (the cases
``warpvx bench`` runs: BGR2GRAY, BGR2RGB, NV12->BGR, lens-undistortion remap, mild homography;
all bilinear BGR, out= buffers on the device) it prints, per call:

- ``call``: the public function called 100 times back to back, then one device
  synchronisation (host overhead and kernel together, as a user sees them);
- ``host``: the same 100 calls without the synchronisation (the host side alone);
- ``graph``: the calls captured in a CUDA graph and replayed (the kernel alone);
- ``floor``: bytes read and written over the measured device-to-device copy bandwidth;
- ``cvcuda``: CV-CUDA's call, 100 back to back then one synchronisation, when it imports.

``--profile`` adds the recorded launch replayed alone and a cProfile of each public call.

``--old DIR`` names a directory holding ``warpvx_old``, an earlier copy of the package (its
registry strings pointing at itself), timed the same way for a before/after table.
"""

from __future__ import annotations

import argparse
import sys


def _timer(fn, sync, calls, repeat, *, warmup=0, issue_only=False):
    """Median seconds per call over ``repeat`` batches of ``calls`` calls, each between two
    ``sync()`` (``issue_only``: the clock stops before the closing one), after ``warmup``
    calls: :func:`warpvx.bench.time_per_call_s` with a fixed batch."""
    from warpvx.bench import Settings, time_per_call_s

    return time_per_call_s(fn, sync, settings=Settings(repeat=repeat, warmup=warmup), calls=calls,
                           issue_only=issue_only)[0]


def _graph_timer(fn, device, per_graph=20, replays=20, repeat=7):
    """Per-call seconds of ``fn`` replayed from a graph of ``per_graph`` calls (3 warm-up
    replays, ``repeat`` batches of ``replays``): :func:`warpvx.bench.time_graph`."""
    from warpvx.bench import Settings, time_graph

    return time_graph(fn, device, settings=Settings(repeat=repeat, warmup=3, graph_calls=per_graph),
                      calls=replays)


def _cases(lib, image):
    """``lib``'s bench cases: ``<lib>.bench.cases.<primitive>``, or in a copy older than that
    package, the ``bench_cases_*`` functions of its public modules."""
    if hasattr(lib.color, "bench_cases_color_convert"):
        return (lib.color.bench_cases_color_convert(image) + lib.geometry.bench_cases_remap(image)
                + lib.geometry.bench_cases_warp_perspective(image))
    import importlib

    return [case for name in ("color_convert", "remap", "warp_perspective")
            for case in importlib.import_module(f"{lib.__name__}.bench.cases.{name}").cases(image)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="1920x1080")
    parser.add_argument("--old", default=None, help="directory holding warpvx_old")
    parser.add_argument("--calls", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--backend", default="cuda", help="cuda (default); warp-cpu for a dry run")
    parser.add_argument("--profile", action="store_true", help="also show where the host time goes")
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.size.lower().split("x"))

    import warpvx
    import warpvx.color
    import warpvx.geometry
    from warpvx.backend import init_warp, resolve_backend
    from warpvx.bench import Settings, copy_bandwidth, load_photo, photo_at

    wp = init_warp()
    device = resolve_backend(args.backend).device
    graphs = device != "cpu"  # CUDA graphs need a CUDA device
    sync = lambda: wp.synchronize_device(device)  # noqa: E731
    image = photo_at(load_photo(), (w, h))

    bandwidth = copy_bandwidth(device, nbytes=256 << 20, settings=Settings(repeat=5, warmup=0))
    print(f"{wp.get_device(device).name}, {w}x{h}, copy bandwidth {bandwidth / 1e9:.0f} GB/s", flush=True)

    libs = [("new", warpvx)]
    if args.old:
        sys.path.insert(0, args.old)
        import warpvx_old
        import warpvx_old.color
        import warpvx_old.geometry

        libs.append(("old", warpvx_old))

    rows = {}
    new_cases = {}
    for tag, lib in libs:
        for case in _cases(lib, image):
            fn = case.prepare(args.backend)
            row = rows.setdefault(case.label, {"floor": case.bytes_moved / bandwidth})
            # warm-up first (JIT, recorded launches, clocks): three batches' worth of calls
            row[f"{tag} call"] = _timer(fn, sync, args.calls, args.repeat, warmup=3 * args.calls)
            row[f"{tag} host"] = _timer(fn, sync, args.calls, args.repeat, issue_only=True)
            row[f"{tag} graph"] = _graph_timer(fn, device) if graphs else float("nan")
            if tag == "new":
                new_cases[case.label] = (case, fn)
            print(f"{case.label} {tag}: done", flush=True)

    # Peers last, so that nothing they leave running (threads, streams) touches our timings.
    for label, (case, _) in new_cases.items():
        peer = case.peers.get("cvcuda")
        try:
            import torch

            pfn = peer()
            rows[label]["cvcuda"] = _timer(pfn, torch.cuda.synchronize, args.calls, args.repeat, warmup=5)
        except Exception as exc:  # noqa: BLE001 - a missing peer is reported, not fatal
            print(f"cvcuda {label}: {exc!r}", flush=True)

    cols = ["floor", "new call", "new host", "new graph", "cvcuda", "old call", "old host",
            "old graph"]
    cols = [c for c in cols if any(c in r for r in rows.values())]
    print(f"\n{'per call, us':<22}" + "".join(f"{c:>11}" for c in cols) + "   graph/floor")
    for label, row in rows.items():
        cells = "".join(f"{row.get(c, float('nan')) * 1e6:11.1f}" for c in cols)
        print(f"{label[:22]:<22}{cells}   {row['new graph'] / row['floor']:.1f}x")
    if args.profile:
        _diagnose(new_cases, sync, args.calls)
    return 0


def _diagnose(new_cases, sync, calls):
    """Where a plain call's host time goes: the recorded launch replayed alone, then the top
    of a cProfile of the public call."""
    import cProfile
    import io
    import pstats

    from warpvx.kernels_warp import _launch

    print("\nreplay alone, us per call (host: issue only; call: with the kernel)")
    for label, (_, fn) in new_cases.items():
        _launch.clear_recorded()
        fn()
        (plan,) = _launch._RECORDED.values()  # the launches of fn
        replay = lambda: [cmd.launch() for cmd in plan]  # noqa: E731
        host = _timer(replay, sync, calls, 5, issue_only=True) * 1e6
        call = _timer(replay, sync, calls, 5) * 1e6
        print(f"  {label[:22]:<22} host {host:6.1f}  call {call:6.1f}", flush=True)
    for label, (_, fn) in new_cases.items():
        prof = cProfile.Profile()
        sync()
        prof.enable()
        for _ in range(300):
            fn()
        prof.disable()
        sync()
        out = io.StringIO()
        pstats.Stats(prof, stream=out).sort_stats("tottime").print_stats(8)
        lines = [ln for ln in out.getvalue().splitlines() if ln.strip()][3:]
        print(f"\ncProfile, 300 calls of {label}:\n" + "\n".join(ln[:150] for ln in lines), flush=True)


if __name__ == "__main__":
    raise SystemExit(main())
