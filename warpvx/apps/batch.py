"""Many inputs through one application: one after another in this process, or on Ray (issue 16).

Usage (the applications' command lines call :func:`run_batch`)::

    warpvx stabilize clips/*.mp4 archive/ @more.txt --out OUT [--ray [ADDRESS]] [--resume]
    warpvx orbslam seq1 seq2 --out OUT --ray --num-gpus 0.25

Inputs (:func:`expand_inputs`): paths; a folder holding video files (each video one input,
otherwise the folder itself is one input: an image sequence); a glob (quote it); ``@list.txt``
(one input per line, relative to the list's folder, ``#`` comments).

Outputs: ``OUT/<name>/`` per input (``name``: the input's stem, ``-2``, ``-3``... when two
inputs share one), plus ``OUT/batch_summary.csv`` (:data:`SUMMARY_FIELDS`), also printed.
An input is written into ``OUT/.<name>.partial-XXXX/`` and renamed to ``OUT/<name>/`` once
complete, with its summary row in the marker file ``_COMPLETE``; so a folder ``OUT/<name>/``
with a marker is complete, and ``--resume`` skips exactly those.

Faults: an input whose application raises fails alone (status ``failed`` with the error); the
rest go on. On Ray, a worker process that dies (crash, out of memory, killed) is restarted
and its input retried ``--retries`` times; a dead worker leaves only a ``.partial`` folder,
removed when that input runs again.

Ray: ``--ray`` without an address starts (or joins) a local Ray instance; each worker is one
actor holding ``--num-gpus`` of a GPU (1 by default, a fraction to share one; 0 for the
``cpu`` and ``warp-cpu`` backends) and ``--cpus-per-input`` CPUs (the graph's CPU workers),
kept across inputs so Warp's loaded kernels stay warm. Without ``--ray`` nothing imports Ray.

Applications plug in through :func:`register_app`: ``fn(source, out_dir, options) -> dict``
runs one input into the existing folder ``out_dir`` and returns at least ``frames`` (int),
optionally ``quality`` (float, the app's figure of merit) and ``ate`` (float, m); ``options``
is the command line's other options as a dict (picklable).
"""

from __future__ import annotations

import argparse
import csv
import glob
import json
import os
import shutil
import time
import uuid

from ..errors import WarpvxValueError

#: Columns of the summary (CSV and printed table), one row per input.
SUMMARY_FIELDS = ("input", "output", "status", "frames", "seconds", "fps", "quality", "ate", "error")
#: Marker file inside a complete output folder: the input's summary row as JSON.
MARKER = "_COMPLETE"
SUMMARY_CSV = "batch_summary.csv"
VIDEO_EXTENSIONS = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".mpg", ".mpeg", ".webm", ".wmv")
#: Options :func:`add_batch_arguments` adds; never passed on to the applications.
BATCH_KEYS = ("out", "ray", "resume", "num_gpus", "cpus_per_input", "workers", "retries")
_GPU_FREE_BACKENDS = ("cpu", "warp-cpu")

_APPS: dict = {}


# --------------------------------------------------------------------------- applications


def register_app(name: str, fn) -> None:
    """Register ``fn(source, out_dir, options) -> dict`` as the batch adapter of app ``name``."""
    _APPS[name] = fn


def get_app(app):
    """The adapter of ``app``: a registered name, or a callable taken as is."""
    if callable(app):
        return app
    if app not in _APPS:
        raise WarpvxValueError(f"app: expected one of {', '.join(sorted(_APPS))}, got {app!r}")
    return _APPS[app]


def _frame_count(path) -> int:
    """Frames of the video file ``path`` (its container's count, else decoded)."""
    import cv2

    cap = cv2.VideoCapture(os.fspath(path))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    if n <= 0:
        n = 0
        while cap.grab():
            n += 1
    cap.release()
    return n


def run_stabilize(source, out_dir, options) -> dict:
    """Batch adapter of :mod:`warpvx.apps.stabilize`: ``out_dir/stabilized.mp4`` (and, when
    the options ask for them, the metrics JSON and trajectory plot under their base names).
    ``quality``: the output's ITF (dB, higher is steadier) when metrics are asked for."""
    from . import stabilize_cli

    args = argparse.Namespace(**options)
    args.input, args.output, args.quiet = source, os.path.join(out_dir, "stabilized.mp4"), True
    for key in ("metrics", "plot"):
        if getattr(args, key, None):
            setattr(args, key, os.path.join(out_dir, os.path.basename(getattr(args, key))))
    stabilize_cli.run(args)
    if args.metrics:
        with open(args.metrics) as f:
            report = json.load(f)
        return {"frames": report["frames"], "quality": report["output"]["itf"]}
    return {"frames": _frame_count(args.output)}


def run_orbslam(source, out_dir, options) -> dict:
    """Batch adapter of :mod:`warpvx.apps.orbslam` (imported when called): its ``run`` writes
    the trajectories, ``frames.csv`` and, with ground truth, ``metrics.json`` into ``out_dir``.

    Ground truth per input: ``gt`` a folder -> ``gt/<input stem>.txt`` (KITTI's ``poses/``),
    a file -> that file for every input, none -> ``groundtruth.txt`` (TUM RGB-D) or
    ``poses.txt`` in the source folder when there is one. ``ate``: the ATE RMSE (m, up to
    scale when monocular).
    """
    try:
        from . import orbslam_cli
    except ImportError as exc:
        raise WarpvxValueError(f"app: warpvx.apps.orbslam is not available in this build ({exc})") from None
    args = argparse.Namespace(**options)
    args.source, args.out, args.quiet = source, out_dir, True
    stem = os.path.splitext(os.path.basename(os.path.normpath(source)))[0]
    if args.gt and os.path.isdir(args.gt):
        args.gt = os.path.join(args.gt, f"{stem}.txt")
    elif args.gt is None:
        found = [p for p in (os.path.join(source, n) for n in ("groundtruth.txt", "poses.txt")) if os.path.isfile(p)]
        args.gt = found[0] if found else None
    orbslam_cli.run(args)
    with open(os.path.join(out_dir, "frames.csv")) as f:
        frames = sum(1 for _ in f) - 1
    metrics = os.path.join(out_dir, "metrics.json")
    if not os.path.isfile(metrics):
        return {"frames": frames}
    with open(metrics) as f:
        return {"frames": frames, "ate": json.load(f)["warpvx"]["ate"]["rmse"]}


register_app("stabilize", run_stabilize)
register_app("orbslam", run_orbslam)


# --------------------------------------------------------------------------- inputs and outputs


def _listed(path):
    """The entries of the list file ``path``, relative to its folder."""
    try:
        with open(path) as f:
            lines = [line.split("#", 1)[0].strip() for line in f]
    except OSError as exc:
        raise WarpvxValueError(f"inputs: cannot read the list {path!r} ({exc.strerror})") from None
    base = os.path.dirname(os.path.abspath(path))
    return [os.path.join(base, line) for line in lines if line]


def expand_inputs(items) -> list:
    """The batch's inputs (str paths, in order, without repeats) from command-line ``items``:
    paths, folders of videos, globs and ``@list.txt`` files (see the module docstring).

    A path that does not exist stays: it fails alone when it runs. Raises a warpvx error
    naming ``inputs`` for a glob matching nothing, an unreadable list or no input at all.
    """
    out = []
    for item in items:
        item = os.fspath(item)
        if item.startswith("@"):
            found = expand_inputs(_listed(item[1:]))
        elif glob.has_magic(item):
            found = sorted(glob.glob(item))
            if not found:
                raise WarpvxValueError(f"inputs: the pattern {item!r} matches nothing")
        elif os.path.isdir(item):
            videos = sorted(os.path.join(item, f) for f in os.listdir(item)
                            if f.lower().endswith(VIDEO_EXTENSIONS) and not f.startswith("."))
            found = videos or [item]
        else:
            found = [item]
        out.extend(p for p in found if p not in out)
    if not out:
        raise WarpvxValueError("inputs: expected at least one input, got none")
    return out


def output_names(inputs) -> list:
    """One folder name per input: its stem, made unique with ``-2``, ``-3``... in order."""
    names, seen = [], set()
    for path in inputs:
        stem = os.path.splitext(os.path.basename(os.path.normpath(path)))[0] or "input"
        name, n = stem, 1
        while name in seen:
            n += 1
            name = f"{stem}-{n}"
        seen.add(name)
        names.append(name)
    return names


def read_complete(out_dir):
    """The summary row of a complete output folder (its marker), or None if incomplete."""
    try:
        with open(os.path.join(out_dir, MARKER)) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def summary_row(source, output, status, **fields) -> dict:
    row = dict.fromkeys(SUMMARY_FIELDS)
    row.update(input=source, output=output, status=status, **fields)
    return row


def run_item(app, source, out_root, name, options) -> dict:
    """Run one input of the batch into ``out_root/name``; returns its summary row.

    The app writes into a fresh ``out_root/.name.partial-XXXX`` folder, renamed to
    ``out_root/name`` with the ``_COMPLETE`` marker once it returns (replacing an older
    complete output; a folder of that name without the marker is left alone, and the input
    fails). An exception of the app is this input's failure, recorded in the row (status
    ``failed``).
    """
    final = os.path.join(out_root, name)
    if os.path.lexists(final) and read_complete(final) is None:
        return summary_row(source, None, "failed", error=f"output: {final!r} exists and is no batch output "
                                                        f"(no {MARKER} marker); move it away")
    for stale in glob.glob(os.path.join(glob.escape(out_root), f".{glob.escape(name)}.partial-*")):
        shutil.rmtree(stale, ignore_errors=True)  # left by a worker that died on this input
    tmp = os.path.join(out_root, f".{name}.partial-{uuid.uuid4().hex[:12]}")
    os.mkdir(tmp)
    start = time.perf_counter()
    try:
        result = get_app(app)(source, tmp, dict(options))
    except Exception as exc:  # noqa: BLE001 -- one input's fault must not stop the batch
        shutil.rmtree(tmp, ignore_errors=True)
        return summary_row(source, None, "failed", error=f"{type(exc).__name__}: {exc}")
    seconds = time.perf_counter() - start
    frames = int(result["frames"])
    row = summary_row(source, final, "done", frames=frames, seconds=round(seconds, 4),
               fps=round(frames / seconds, 2) if seconds > 0 else None,
               quality=result.get("quality"), ate=result.get("ate"))
    with open(os.path.join(tmp, MARKER), "w") as f:
        json.dump(row, f, indent=2)
    if os.path.lexists(final):
        shutil.rmtree(final)
    os.rename(tmp, final)
    return row


# --------------------------------------------------------------------------- running a batch


def run_items(app, inputs, out, options=None, *, ray=None, resume=False, num_gpus=None,
              cpus_per_input=None, workers=None, retries=2, progress=True) -> list:
    """Run every input of ``inputs`` (paths) through ``app`` into ``out/<name>/``; returns
    the summary rows (dicts of :data:`SUMMARY_FIELDS`) in input order.

    Parameters
    ----------
    app : str or callable
        A registered application (``"stabilize"``, ``"orbslam"``) or an adapter.
    options : dict
        The application's options (``backend`` decides the default ``num_gpus``).
    ray : str or None
        None: in this process, one input after another. ``""``: a local Ray instance (or
        the one ``ray.init`` already joined); else the address of a Ray cluster.
    resume : bool
        Skip inputs whose output folder is complete (status ``skipped``, its recorded row).
    num_gpus : float
        GPUs per Ray worker: default 1, a fraction shares one; 0 for ``cpu``/``warp-cpu``.
    cpus_per_input : float
        CPUs per Ray worker; default the graph's CPU workers (1 to 4).
    workers : int
        Ray workers (actors); default as many as the cluster's resources hold, at most one
        per input.
    retries : int
        Times an input is retried on Ray when its worker process dies.
    """
    from tqdm import tqdm

    options = dict(options or {})
    os.makedirs(out, exist_ok=True)
    rows = [None] * len(inputs)
    todo = []
    for i, (source, name) in enumerate(zip(inputs, output_names(inputs))):
        done = read_complete(os.path.join(out, name)) if resume else None
        if done is not None:
            rows[i] = dict(done, status="skipped")
        else:
            todo.append((i, source, name))
    with tqdm(total=len(inputs), initial=len(inputs) - len(todo), unit="input", desc="batch",
              disable=not progress) as bar:
        def report(i, row):
            rows[i] = row
            fps = f"{row['fps']:.1f} FPS" if row["fps"] else row["status"]
            bar.set_postfix_str(f"{os.path.basename(row['input'])}: {fps}")
            bar.update()

        if ray is None:
            for i, source, name in todo:
                report(i, run_item(app, source, out, name, options))
        elif todo:
            from .batch_ray import run_on_ray

            gpus = num_gpus if num_gpus is not None else 1.0
            if options.get("backend") in _GPU_FREE_BACKENDS:
                gpus = 0.0
            if cpus_per_input is None:
                from ..graph.costs import default_n_cpus

                cpus_per_input = default_n_cpus()
            run_on_ray(app, todo, out, options, report, address=ray, num_gpus=gpus,
                       num_cpus=cpus_per_input, workers=workers, retries=retries)
    return rows


def format_summary(rows) -> str:
    """The summary rows as an aligned text table (:data:`SUMMARY_FIELDS` less ``output``)."""
    fields = [f for f in SUMMARY_FIELDS if f != "output"]

    def cell(row, f):
        v = row.get(f)
        if f == "input":
            v = os.path.basename(os.path.normpath(v))
        return "" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v)

    table = [fields] + [[cell(r, f) for f in fields] for r in rows]
    widths = [max(len(line[k]) for line in table) for k in range(len(fields))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(line, widths)).rstrip() for line in table)


def write_summary(rows, path) -> None:
    """Write the summary rows as CSV (:data:`SUMMARY_FIELDS`, empty cells for None)."""
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=SUMMARY_FIELDS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


# --------------------------------------------------------------------------- command line


def add_batch_arguments(parser, *, out=True) -> None:
    """The batch options of an application's command line (``out=False`` when the app
    already has its own ``--out DIR``, which then names the batch's root folder)."""
    if out:
        parser.add_argument("--out", metavar="DIR", default=None,
                            help="batch: one output folder per input under DIR (makes a batch)")
    parser.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                        help="batch on Ray: a cluster's ADDRESS, or none for a local instance "
                             "(put it after the inputs, or write --ray=ADDRESS)")
    parser.add_argument("--resume", action="store_true",
                        help="batch: skip inputs whose output folder is complete")
    parser.add_argument("--num-gpus", type=float, default=None,
                        help="Ray: GPUs per worker (fractions share one); default 1, 0 on cpu/warp-cpu")
    parser.add_argument("--cpus-per-input", type=float, default=None,
                        help="Ray: CPUs per worker; default the graph's CPU workers")
    parser.add_argument("--workers", type=int, default=None,
                        help="Ray: workers; default as many as the cluster holds")
    parser.add_argument("--retries", type=int, default=2,
                        help="Ray: retries of an input whose worker process died")


def _is_batch_path(path) -> bool:
    return path.startswith("@") or glob.has_magic(path) or (
        os.path.isdir(path) and expand_inputs([path]) != [path])


def single_run(args, *, paths="input", output=None, alone=False):
    """The parsed arguments of ONE run of the application, or None when they ask for a batch.

    ``paths``: the attribute holding the positional paths (a list). ``output``: the attribute
    of the single run's output path, taken from the last positional (``IN OUT``), or None
    when the app names its output with an option. Positionals a run lacks are None (the app
    reports them). A batch is asked for by ``--ray``, ``--resume``, more inputs than one run
    takes, a glob, a list or a folder of videos, and for apps with a positional output, by
    ``--out``; ``alone`` (e.g. ``--demo``) asks for one run whatever the paths are.
    """
    values = list(getattr(args, paths))
    n = 2 if output else 1
    batch_options = args.ray is not None or args.resume or (output and args.out is not None)
    if alone or not (batch_options or len(values) > n or any(_is_batch_path(v) for v in values[:1])):
        if len(values) > n or (alone and batch_options):
            raise WarpvxValueError(f"{paths}: one run takes at most {n} paths and no batch options, "
                                   f"got {' '.join(values)}")
        values += [None] * (n - len(values))
        single = dict(vars(args), **{paths: values[0]})
        if output:
            single[output] = values[1]
        return argparse.Namespace(**single)
    if args.out is None:
        raise WarpvxValueError("out: a batch (several inputs, a glob, a list, a folder of videos, "
                               "--ray or --resume) writes under --out DIR; one run is "
                               + ("IN OUT" if output else "SOURCE"))
    return None


def app_options(args, *, paths="input") -> dict:
    """The options of parsed ``args`` an application's adapter gets: all but the batch's own,
    the positional ``paths`` and the subcommand."""
    return {k: v for k, v in vars(args).items() if k not in BATCH_KEYS and k not in (paths, "command")}


def parse_options(add_arguments, argv, *, paths="input") -> dict:
    """An application's options as its command line parses ``argv`` (the positional paths
    included), for :func:`run_items`: ``add_arguments(parser)`` is the app's own."""
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    return app_options(parser.parse_args(list(argv)), paths=paths)


def run_batch(args, app, *, paths="input") -> int:
    """Run the batch the parsed command line ``args`` asks for (see :func:`add_batch_arguments`):
    print the summary table and write ``OUT/batch_summary.csv``. Returns 0 when every
    input is done or skipped, 1 when some failed."""
    inputs = expand_inputs(getattr(args, paths))
    options = app_options(args, paths=paths)
    rows = run_items(app, inputs, args.out, options, ray=args.ray, resume=args.resume,
                     num_gpus=args.num_gpus, cpus_per_input=args.cpus_per_input,
                     workers=args.workers, retries=args.retries,
                     progress=not options.get("quiet", False))
    write_summary(rows, os.path.join(args.out, SUMMARY_CSV))
    print(format_summary(rows))
    return 1 if any(r["status"] == "failed" for r in rows) else 0


__all__ = [
    "SUMMARY_FIELDS", "MARKER", "BATCH_KEYS", "register_app", "get_app", "run_stabilize",
    "run_orbslam", "expand_inputs", "output_names", "read_complete", "run_item", "run_items",
    "format_summary", "write_summary", "add_batch_arguments", "single_run", "app_options", "parse_options",
    "run_batch",
]
