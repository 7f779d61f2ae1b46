"""The run behind ``warpvx bench``: collect the registered primitives' cases, time each on
every backend, OpenCV and the peers, and the command line that drives it."""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import sys
from dataclasses import asdict
from pathlib import Path

from .inputs import load_photo, photo_at
from .report import Report, Result, format_table, machine_info, write_json, write_plot
from .timing import (Settings, copy_bandwidth, device_of, sync_for, sync_peers, time_graph,
                     time_per_call_s)

DEFAULT_SIZES = ((1920, 1080), (1241, 376))
DEFAULT_OUT = Path("benchmarks") / "results"
PEERS = ("cvcuda", "kornia")


# --- the run --------------------------------------------------------------------------------


def collect_cases(primitives, sizes, photo, notes):
    """``[(size, BenchCase)]`` for the selected primitives; a missing module or bench function
    is skipped with a note."""
    from ..registry import REGISTRY, _load

    cases = []
    for name in primitives:
        prim = REGISTRY[name]
        if prim.bench is None:
            continue
        try:
            bench_fn = _load(prim.bench)
        except (ImportError, AttributeError) as exc:
            notes.append(f"{name}: skipped, no bench cases yet ({prim.bench}: {exc})")
            continue
        except Exception as exc:  # noqa: BLE001 - a module that fails to import is skipped too
            notes.append(f"{name}: skipped, {prim.bench} failed to load: {exc!r}")
            continue
        for size in sizes:
            try:
                made = bench_fn(photo_at(photo, size))
            except Exception as exc:  # noqa: BLE001 - one broken case must not stop the run
                notes.append(f"{name} {size[0]}x{size[1]}: bench cases failed: {exc!r}")
                continue
            cases.extend((size, c) for c in made)
    return cases


def run(*, primitives=None, sizes=DEFAULT_SIZES, backends=None, settings: Settings | None = None,
        graph=False, peers=True, progress=True) -> Report:
    """Time every case; see :mod:`warpvx.bench`. Returns the :class:`Report`."""
    import cv2

    from ..backend import available_backends, cuda_available
    from ..registry import REGISTRY

    settings = settings or Settings()
    cv2.setNumThreads(os.cpu_count() or 1)
    if primitives is None:
        primitives = [n for n, p in REGISTRY.items() if p.bench is not None]
    if backends is None:
        backends = ["cpu"] + (["cuda"] if cuda_available() else [])
    notes: list[str] = []
    usable = []
    available = available_backends()
    for b in backends:
        if b in available or (b == "cuda" and any(a.startswith("cuda") for a in available)):
            usable.append(b)
        else:
            notes.append(f"backend {b!r} is not available here; skipped")
    report = Report(machine=machine_info(), settings=asdict(settings),
                    sizes=[f"{w}x{h}" for w, h in sizes], backends=usable, notes=notes)
    cuda_backends = [b for b in usable if b.startswith("cuda")]
    warp_backends = [b for b in usable if b != "cpu"]
    if graph and warp_backends:
        for b in warp_backends:
            dev = device_of(b)
            report.copy_bandwidth_gbps[dev] = copy_bandwidth(
                dev, nbytes=(256 << 20) if dev != "cpu" else (64 << 20), settings=settings) / 1e9
    elif graph:
        notes.append("--graph: no Warp backend (cuda, warp-cpu), graph timings skipped")

    photo = load_photo()
    cases = collect_cases(primitives, sizes, photo, notes)
    peer_names = [p for p in PEERS if peers and cuda_backends]
    tasks = [(size, case, impl) for size, case in cases
             for impl in ["opencv"] + usable + peer_names]
    bar = _progress(len(tasks), progress)
    missing_peers = set()
    for size, case in cases:
        rows = {}
        for impl in ["opencv"] + usable + peer_names:
            bar.set_description(f"{case.primitive} {case.label} {impl}"[:60])
            res = Result(case.primitive, case.label, f"{size[0]}x{size[1]}", impl,
                         bytes_moved=case.bytes_moved)
            try:
                if impl == "opencv":
                    if case.opencv is None:
                        bar.update()
                        continue
                    res.per_call_s, res.calls_per_batch = time_per_call_s(case.opencv(), settings=settings)
                elif impl in PEERS:
                    if impl not in case.peers or impl in missing_peers:
                        bar.update()
                        continue
                    try:
                        fn = case.peers[impl]()
                    except ImportError as exc:
                        missing_peers.add(impl)
                        notes.append(f"peer {impl}: not importable ({exc}); skipped")
                        bar.update()
                        continue
                    res.per_call_s, res.calls_per_batch = time_per_call_s(
                        fn, sync_peers, settings=settings, min_calls=settings.gpu_min_calls)
                else:
                    fn = case.prepare(impl)
                    is_gpu = impl.startswith("cuda")
                    res.impl = impl if impl != "cuda" else device_of(impl)
                    res.per_call_s, res.calls_per_batch = time_per_call_s(
                        fn, sync_for(impl), settings=settings,
                        min_calls=settings.gpu_min_calls if is_gpu else 1)
                    if graph and impl != "cpu" and case.bytes_moved:
                        dev = device_of(impl)
                        try:
                            res.graph_per_call_s = time_graph(fn, dev, settings=settings)
                            bw = report.copy_bandwidth_gbps.get(dev)
                            if bw:
                                res.floor_s = case.bytes_moved / (bw * 1e9)
                                res.graph_over_floor = res.graph_per_call_s / res.floor_s
                        except Exception as exc:  # noqa: BLE001 - e.g. a call that cannot be captured
                            res.note = f"graph capture failed: {exc!r}"
            except Exception as exc:  # noqa: BLE001 - report and go on with the next case
                res.note = f"failed: {exc!r}"
            rows[impl] = res
            report.results.append(res)
            bar.update()
        ref = rows.get("opencv")
        if ref is not None and ref.per_call_s:
            for r in rows.values():
                if r.per_call_s:
                    r.speedup_vs_opencv = ref.per_call_s / r.per_call_s
    bar.close()
    for extra in ("torch", "cvcuda", "kornia"):
        mod = sys.modules.get(extra)
        if mod is not None:
            report.machine["versions"][extra] = getattr(mod, "__version__", "?")
    return report


def _progress(total, enabled):
    if enabled:
        try:
            from tqdm import tqdm

            return tqdm(total=total, unit="run", leave=False, file=sys.stderr)
        except ImportError:
            pass

    class _Silent:
        def update(self, n=1):
            pass

        def set_description(self, s):
            pass

        def close(self):
            pass

    return _Silent()

# --- command line ---------------------------------------------------------------------------


def _split_list(values):
    out = []
    for v in values or []:
        out += [p for p in v.split(",") if p.strip()]
    return [p.strip() for p in out]


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        w, h = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--sizes: expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"--sizes: expected positive sizes, got {text!r}")
    return w, h


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``warpvx bench``'s options to ``parser``."""
    parser.add_argument("--sizes", nargs="+", metavar="WxH",
                        help="image sizes (default: 1920x1080 1241x376); comma or space separated")
    parser.add_argument("--primitives", nargs="+", metavar="NAME",
                        help="registered primitives to time (default: all with bench cases)")
    parser.add_argument("--backends", nargs="+", metavar="NAME",
                        help="warpvx backends: cpu, warp-cpu (slow), cuda, cuda:N "
                             "(default: cpu, plus cuda when present)")
    parser.add_argument("--repeat", type=int, default=None, help="timed batches per measurement (median)")
    parser.add_argument("--quick", action="store_true",
                        help="fewer, shorter batches (a smoke run; timings are noisier)")
    parser.add_argument("--graph", action="store_true",
                        help="also time cases inside a captured graph (CUDA; Warp's CPU graphs for "
                             "warp-cpu) against the memory-bandwidth floor")
    parser.add_argument("--no-peers", action="store_true", help="skip CV-CUDA and Kornia")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="directory for the JSON and PNG (default: benchmarks/results/)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw the PNG chart")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main_from_args(args) -> int:
    """Run ``warpvx bench`` from parsed arguments; prints the table and the output paths."""
    from ..registry import REGISTRY

    try:
        sizes = [parse_size(s) for s in _split_list(args.sizes)] or list(DEFAULT_SIZES)
    except argparse.ArgumentTypeError as exc:
        print(f"warpvx bench: {exc}", file=sys.stderr)
        return 2
    primitives = _split_list(args.primitives) or None
    if primitives:
        unknown = [p for p in primitives if p not in REGISTRY]
        if unknown:
            print(f"warpvx bench: unknown primitive(s) {unknown}; registered: {sorted(REGISTRY)}",
                  file=sys.stderr)
            return 2
    backends = _split_list(args.backends) or None
    if args.repeat is not None and args.repeat < 1:
        print("warpvx bench: --repeat must be >= 1", file=sys.stderr)
        return 2
    settings = Settings.quick(args.repeat) if args.quick else Settings(repeat=args.repeat or 7)
    report = run(primitives=primitives, sizes=sizes, backends=backends, settings=settings,
                 graph=args.graph, peers=not args.no_peers, progress=not args.no_progress)
    for note in report.notes:
        print(f"note: {note}")
    for r in report.results:
        if r.note:
            print(f"note: {r.primitive} {r.case} {r.size} {r.impl}: {r.note}")
    print(format_table(report))
    if report.copy_bandwidth_gbps:
        for dev, bw in report.copy_bandwidth_gbps.items():
            print(f"device-to-device copy bandwidth on {dev}: {bw:.0f} GB/s (read + write)")
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    json_path = write_json(report, Path(args.out) / f"bench-{stamp}.json")
    print(f"wrote {json_path}")
    if not args.no_plot:
        png = write_plot(report, Path(args.out) / f"bench-{stamp}.png")
        print(f"wrote {png}" if png else "matplotlib not installed: no plot")
    return 0


def main(argv=None) -> int:
    """``python -m warpvx.bench`` (same as ``warpvx bench``)."""
    parser = add_arguments(argparse.ArgumentParser(prog="warpvx bench", description=__doc__.split("\n\n")[0]))
    return main_from_args(parser.parse_args(argv))
