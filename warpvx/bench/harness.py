"""The run behind ``warpvx bench``: collect the registered primitives' cases, time each on
every backend, OpenCV and the peers, and the command line that drives it."""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import re
import sys
from dataclasses import asdict
from pathlib import Path

from .inputs import load_photo_with_source, photo_at
from .report import Report, Result, describe_impl, format_table, machine_info, write_json, write_plot
from .timing import (Settings, copy_bandwidth, device_of, sync_for, sync_peers, time_graph,
                     time_per_call_s)

DEFAULT_SIZES = ((1920, 1080), (1241, 376))
PEERS = ("cvcuda", "kornia")
BACKEND_NAMES = ("cpu", "warp-cpu", "cuda", "cuda:N")


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
    """Time every case; see :mod:`warpvx.bench`. Returns the :class:`Report`.

    ``backends`` are warpvx backend names (:data:`BACKEND_NAMES`; an unknown one raises
    :class:`~warpvx.errors.BackendError`); one this machine lacks is skipped with a note, and
    so is the absence of any Warp backend (``cpu`` alone compares OpenCV with the
    NumPy/OpenCV implementation)."""
    import cv2

    from ..backend import cuda_available, resolve_backend
    from ..errors import BackendError
    from ..registry import REGISTRY

    settings = settings or Settings()
    cv2.setNumThreads(os.cpu_count() or 1)
    if primitives is None:
        primitives = [n for n, p in REGISTRY.items() if p.bench is not None]
    if backends is None:
        backends = ["cpu"] + (["cuda"] if cuda_available() else [])
    unknown = [b for b in backends if not is_backend_name(b)]
    if unknown:
        raise BackendError(f"backends: unknown {', '.join(map(repr, unknown))}; "
                           f"valid: {', '.join(BACKEND_NAMES)}")
    notes: list[str] = []
    usable = []
    for b in backends:
        try:
            resolve_backend(b)
            usable.append(b)
        except (BackendError, ImportError) as exc:
            notes.append(f"{b!r} is not available on this machine ({exc}); skipped")
    if all(b == "cpu" for b in usable):
        notes.append("no Warp backend ran: 'cpu' is warpvx's NumPy/OpenCV implementation, so "
                     "this run compares OpenCV with (mostly) OpenCV; add --backends cpu warp-cpu "
                     "to time the Warp kernels on the CPU (single-threaded, slow), or run where "
                     "CUDA is present")
    photo, photo_info = load_photo_with_source()
    report = Report(machine=machine_info(), settings=asdict(settings),
                    sizes=[f"{w}x{h}" for w, h in sizes], backends=usable, notes=notes,
                    photo=photo_info)
    cuda_backends = [b for b in usable if b.startswith("cuda")]
    warp_backends = [b for b in usable if b != "cpu"]
    if graph and warp_backends:
        for b in warp_backends:
            dev = device_of(b)
            report.copy_bandwidth_gbps[dev] = copy_bandwidth(
                dev, nbytes=(256 << 20) if dev != "cpu" else (64 << 20), settings=settings) / 1e9
    elif graph:
        notes.append("--graph: no Warp backend (cuda, warp-cpu), graph timings skipped")

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
    report.impls = {impl: describe_impl(impl, report.machine)
                    for impl in dict.fromkeys(r.impl for r in report.results)}
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


def is_backend_name(name: str) -> bool:
    """Whether ``name`` is a backend name warpvx knows (:data:`BACKEND_NAMES`), available here
    or not."""
    return name in ("cpu", "warp-cpu", "cuda") or re.fullmatch(r"cuda:\d+", name) is not None


def parse_backend(text: str) -> str:
    """``type=`` for one ``--backends`` name."""
    if not is_backend_name(text):
        raise argparse.ArgumentTypeError(f"unknown backend {text!r}; valid: {', '.join(BACKEND_NAMES)}")
    return text


def parse_size(text: str) -> tuple[int, int]:
    """``type=`` for one ``--sizes`` entry, ``WIDTHxHEIGHT``."""
    try:
        w, h = text.lower().split("x")
        w, h = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"expected positive sizes, got {text!r}")
    return w, h


def parse_primitive(text: str) -> str:
    """``type=`` for one ``--primitives`` name: a registered primitive."""
    from ..registry import REGISTRY

    if text not in REGISTRY:
        raise argparse.ArgumentTypeError(f"unknown primitive {text!r}; registered: {', '.join(sorted(REGISTRY))}")
    return text


def add_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add ``warpvx bench``'s options to ``parser``. The list options take space- or
    comma-separated values (parsed to lists of lists, flattened by :func:`main_from_args`)."""
    from ..cli import comma_list, positive_int

    parser.add_argument("--sizes", nargs="+", metavar="WxH", type=comma_list(parse_size),
                        help="image sizes (default: 1920x1080 1241x376)")
    parser.add_argument("--primitives", nargs="+", metavar="NAME", type=comma_list(parse_primitive),
                        help="registered primitives to time (default: all with bench cases)")
    parser.add_argument("--backends", nargs="+", metavar="NAME", type=comma_list(parse_backend),
                        help="warpvx backends: cpu (the NumPy/OpenCV implementation), warp-cpu "
                             "(Warp kernels on the CPU; slow), cuda, cuda:N (Warp kernels on a GPU) "
                             "(default: cpu, plus cuda when present)")
    parser.add_argument("--repeat", type=positive_int, default=None,
                        help="timed batches per measurement, median taken (default: 7, 3 with --quick)")
    parser.add_argument("--quick", action="store_true",
                        help="fewer, shorter batches (a smoke run; timings are noisier)")
    parser.add_argument("--graph", action="store_true",
                        help="also time cases inside a captured graph (CUDA; Warp's CPU graphs for "
                             "warp-cpu) against the memory-bandwidth floor")
    parser.add_argument("--no-peers", action="store_true", help="skip CV-CUDA and Kornia")
    parser.add_argument("--out", type=Path, default=None,
                        help="directory for the JSON and PNG, e.g. benchmarks/results/NAME to record "
                             "a run (default: a new ./warpvx-results/bench-<YYYYmmdd-HHMMSS>/)")
    parser.add_argument("--no-plot", action="store_true", help="do not draw the PNG chart")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _flat(lists):
    return [v for part in lists or [] for v in part] or None


def main_from_args(args) -> int:
    """Run ``warpvx bench`` from parsed arguments; prints the table, notes and output paths."""
    from ..cli import fresh_results_dir

    settings = Settings.quick(args.repeat) if args.quick else Settings(repeat=args.repeat or 7)
    report = run(primitives=_flat(args.primitives), sizes=_flat(args.sizes) or DEFAULT_SIZES,
                 backends=_flat(args.backends), settings=settings, graph=args.graph,
                 peers=not args.no_peers, progress=not args.no_progress)
    print(format_table(report))
    for note in report.notes:
        print(f"note: {note}")
    for r in report.results:
        if r.note:
            print(f"note: {r.primitive} {r.case} {r.size} {r.impl}: {r.note}")
    if report.copy_bandwidth_gbps:
        for dev, bw in report.copy_bandwidth_gbps.items():
            print(f"device-to-device copy bandwidth on {dev}: {bw:.0f} GB/s (read + write)")
    out = Path(args.out) if args.out is not None else fresh_results_dir("bench")
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    json_path = write_json(report, out / f"bench-{stamp}.json")
    print(f"wrote {json_path}")
    if not args.no_plot:
        png = write_plot(report, out / f"bench-{stamp}.png")
        print(f"wrote {png}" if png else "matplotlib not installed: no plot")
    return 0


def main(argv=None) -> int:
    """``python -m warpvx.bench`` (same as ``warpvx bench``)."""
    from ..cli import ArgumentParser

    parser = add_arguments(ArgumentParser(prog="warpvx bench", description=__doc__.split("\n\n")[0]))
    return main_from_args(parser.parse_args(argv))
