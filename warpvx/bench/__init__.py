"""The benchmark harness behind ``warpvx bench``: warpvx against OpenCV (and GPU peers).

For every registered primitive with benchmark cases (``warpvx.registry.Primitive.bench``) and
every size, the harness builds the cases from a real photo (scikit-image's astronaut, or the
bundled ``warpvx/data/astronaut_448.png``) resized to that size, then times each case on every
requested backend, on OpenCV (all cores) and on the peers that import (CV-CUDA, Kornia):

- warm-up calls first, so Warp's JIT compilation and first-touch allocations are excluded;
- a batch of N calls between two device synchronisations; the per-call time is the batch time
  over N, and the reported figure is the median over ``--repeat`` batches (N is chosen so a
  batch lasts a few milliseconds; on CUDA at least 100 calls, the way per-call GPU figures are
  usually quoted);
- with ``--graph``, cases that declare ``bytes_moved`` are also captured into a CUDA graph
  (``wp.ScopedCapture``) and replayed with ``wp.capture_launch``, and compared with the
  memory-bandwidth floor ``bytes_moved / bandwidth``, the bandwidth being a device-to-device
  copy measured in the same run.

Results are printed as a table with a legend (what each implementation is, which way the
ratio reads), written as JSON (with machine information and the input photo) and, when
matplotlib is installed, drawn as a bar chart (log time per case and implementation). Without
``--out`` they go to a new ``./warpvx-results/bench-<YYYYmmdd-HHMMSS>/``; committed results
(``benchmarks/results/...``) are only written when named.

Layout: :mod:`~warpvx.bench.timing` (how a call is timed), :mod:`~warpvx.bench.inputs` (the
photo and inputs made from it), :mod:`~warpvx.bench.report` (results, table, JSON, chart),
:mod:`~warpvx.bench.harness` (the run and the command line) and
:mod:`warpvx.bench.cases` (one module of :class:`~warpvx.bench.cases.BenchCase` per primitive,
named by the registry's ``bench=`` entries).
"""

from __future__ import annotations

from .harness import DEFAULT_SIZES, add_arguments, collect_cases, main, main_from_args, run
from .inputs import load_photo, load_photo_with_source, photo_at
from .report import (Report, Result, describe_impl, format_table, machine_info, plot_figure,
                     write_json, write_plot)
from .timing import Settings, copy_bandwidth, time_graph, time_per_call_s

__all__ = [
    "DEFAULT_SIZES",
    "Report",
    "Result",
    "Settings",
    "add_arguments",
    "collect_cases",
    "copy_bandwidth",
    "describe_impl",
    "format_table",
    "load_photo",
    "load_photo_with_source",
    "machine_info",
    "main",
    "main_from_args",
    "photo_at",
    "plot_figure",
    "run",
    "time_graph",
    "time_per_call_s",
    "write_json",
    "write_plot",
]
