"""The video stabilizer's command line (``warpvx stabilize``, ``apps/stabilize.py``): read a video,
run :mod:`warpvx.apps.stabilize`, write the stabilized video, metrics and trajectory plot."""

from __future__ import annotations

import dataclasses
import math
from collections import deque

import numpy as np

from ..errors import WarpvxError, WarpvxValueError
from . import stabilize as app
from .video_io import VideoSource, open_writer


def trajectory_params(T):
    """(x, y, angle in degrees) of a 3x3 motion: translation and rotation of its affine part."""
    return float(T[0, 2]), float(T[1, 2]), math.degrees(math.atan2(T[1, 0], T[0, 0]))


def save_plot(path, before, after):
    """Plot the trajectory (x, y, angle over frames) before and after smoothing as a PNG.

    ``before``, ``after``: lists of 3x3 matrices (T_k and the smoothed path S_k T_k).
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise WarpvxValueError("plot: matplotlib is not installed (pip install 'warpvx[plot]')") from None
    a = np.array([trajectory_params(T) for T in before])
    b = np.array([trajectory_params(T) for T in after])
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for i, label in enumerate(("x (px)", "y (px)", "angle (deg)")):
        axes[i].plot(a[:, i], label="input")
        axes[i].plot(b[:, i], label="stabilized")
        axes[i].set_ylabel(label)
    axes[0].legend()
    axes[-1].set_xlabel("frame")
    fig.suptitle("camera trajectory (first frame of the shot -> frame k)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def scene_cuts(segments):
    """The frames that start a new shot (a scene cut between frame k-1 and k), from the
    per-frame segment indices (:attr:`StabilizedFrame.segment`), ascending."""
    return [k for k in range(1, len(segments)) if segments[k] != segments[k - 1]]

# --------------------------------------------------------------------------- command line


def add_arguments(parser):
    """The stabilizer's command-line options (shared by ``warpvx stabilize`` and
    ``apps/stabilize.py``)."""
    d = app.StabilizerConfig()
    parser.add_argument("input", nargs="*", metavar="PATH",
                        help="IN OUT: a video file (anything OpenCV opens) or image folder, and the "
                             "stabilized video (.mp4: mp4v, .avi: MJPG); IN... --out DIR: a batch of "
                             "inputs, folders of videos, globs or @list.txt (see warpvx.apps.batch)")
    parser.add_argument("--demo", action="store_true",
                        help="stabilize the bundled real shaky clip into a folder (the one positional "
                             "argument, default a new ./warpvx-results/stabilize-<date>-<time>/): "
                             "stabilized.mp4 (input | output side by side), metrics.json and "
                             "trajectory.png (with matplotlib)")
    parser.add_argument("--backend", choices=app.BACKENDS, default="cpu")
    parser.add_argument("--engine", choices=app.ENGINES, default="auto",
                        help="graph (warpvx graph), device (every step on the Warp device, "
                             "replayed per frame), auto (device where it applies)")
    parser.add_argument("--window", type=int, default=d.window, help="smoothing window N in frames")
    parser.add_argument("--mode", choices=app.MODES, default=d.mode,
                        help="centered: lags N//2 frames (thesis); causal: no look-ahead")
    parser.add_argument("--crop", type=float, default=d.crop, help="fraction cut from each side, [0, 0.5)")
    parser.add_argument("--motion", choices=app.MOTIONS, default=d.motion)
    parser.add_argument("--detector", choices=app.DETECTORS, default=d.detector)
    parser.add_argument("--cut-threshold", type=float, default=d.cut_threshold, metavar="FRACTION",
                        help="scene cut: an inter-frame motion moving a frame corner by more than "
                             "this fraction of the diagonal restarts the smoothing (default "
                             "%(default)s)")
    parser.add_argument("--no-cuts", action="store_true",
                        help="no scene cut detection: smooth the clip as one shot")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--model", action="store_true", help="run the imperative OpenCV model instead of the graph")
    parser.add_argument("--compare", action="store_true", help="write input and output side by side")
    parser.add_argument("--plot", metavar="PNG", help="save the trajectory before/after smoothing")
    parser.add_argument("--metrics", metavar="JSON", help="write the quality metrics (keeps the frames in memory)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    from .batch import add_batch_arguments

    add_batch_arguments(parser)


def run(args) -> int:
    """Run the stabilizer for parsed ``args`` (see :func:`add_arguments`); returns 0.

    Raises a warpvx error on bad input (the callers print it as one line, exit status 2).
    """
    import json

    from tqdm import tqdm

    config = app.StabilizerConfig(window=args.window, mode=args.mode, crop=args.crop,
                                  motion=args.motion, detector=args.detector,
                                  cut_threshold=None if args.no_cuts else args.cut_threshold)
    if getattr(args, "demo", False):
        args = _demo_args(args)
    elif args.input is None or args.output is None:
        raise WarpvxValueError("input, output: give both (or --demo for the bundled clip)")
    if args.max_frames is not None and args.max_frames < 1:
        raise WarpvxValueError(f"max_frames: expected an int >= 1, got {args.max_frames}")
    if args.plot:  # fail before the work, not after it
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise WarpvxValueError("plot: matplotlib is not installed (pip install 'warpvx[plot]')") from None
    source = VideoSource(args.input, args.max_frames)
    w, h = source.size
    writer = open_writer(args.output, (2 * w if args.compare else w, h), source.fps)
    keep_in, keep_out = [], []
    before, after, warps, segments = [], [], [], []
    inputs = deque()

    def tee():
        for f in source:
            inputs.append(f)
            yield f

    frames = (app.stabilize_model(tee(), config) if args.model
              else app.stabilize(tee(), config, backend=args.backend,
                                 engine=getattr(args, "engine", "auto")))
    try:
        with tqdm(total=source.count, unit="frame", disable=args.quiet, desc="stabilize") as bar:
            for sf in frames:
                src = inputs.popleft()
                writer.write(np.hstack([src, sf.image]) if args.compare else sf.image)
                before.append(sf.trajectory)
                after.append(sf.transform @ sf.trajectory)
                warps.append(sf.warp)
                segments.append(sf.segment)
                if args.metrics:
                    keep_in.append(src)
                    keep_out.append(sf.image)
                bar.update()
    finally:
        writer.release()
    cuts = scene_cuts(segments)
    if cuts and not args.quiet:
        print(f"stabilize: scene cuts before frames {', '.join(map(str, cuts))}: "
              f"{len(cuts) + 1} shots smoothed apart")
    if args.plot:
        save_plot(args.plot, before, after)
    if args.metrics:
        from .stabilize_metrics import evaluate, evaluate_shots

        report = {"source": args.input, "frames": len(keep_in), "config": {
            k: v for k, v in dataclasses.asdict(config).items() if k not in ("camera_matrix", "dist_coeffs")},
            "backend": "model" if args.model else args.backend, "scene_cuts": cuts}
        report.update(evaluate(keep_in, keep_out, warps, cuts))
        if cuts:
            report["shots"] = evaluate_shots(keep_in, keep_out, cuts)
        with open(args.metrics, "w") as f:
            json.dump(report, f, indent=2)
    return 0


def _demo_args(args):
    """``args`` for ``--demo``: the bundled clip into a folder (created; the one positional
    argument, else a fresh ``./warpvx-results/stabilize-<date>-<time>/``)."""
    import copy
    import importlib.util
    from pathlib import Path

    if args.output is not None:
        raise WarpvxValueError(f"output: --demo takes one folder, got {args.input!r} and {args.output!r}")
    if args.input is None:
        from ..cli import fresh_results_dir

        folder = fresh_results_dir("stabilize")
    else:
        folder = Path(args.input)
        if folder.exists() and not folder.is_dir():
            raise WarpvxValueError(f"output: --demo writes into a folder; {str(folder)!r} is a file")
        folder.mkdir(parents=True, exist_ok=True)
    args = copy.copy(args)
    args.input, args.output, args.compare = app.demo_clip(), str(folder / "stabilized.mp4"), True
    args.metrics = args.metrics or str(folder / "metrics.json")
    if args.plot is None and importlib.util.find_spec("matplotlib") is not None:
        args.plot = str(folder / "trajectory.png")
    if not args.quiet:
        print(f"stabilize --demo: {args.input} -> {folder}/")
    return args


def main(argv=None, prog="stabilize") -> int:
    """Parse ``argv`` and run; bad input prints one line to stderr and returns 2."""
    import argparse

    parser = argparse.ArgumentParser(prog=prog, description=app.__doc__.splitlines()[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    return run_cli(args, prog)


def run_cli(args, prog="stabilize") -> int:
    """:func:`run` with warpvx errors reported as one line on stderr (exit status 2)."""
    import sys

    from .batch import run_batch, single_run

    try:
        single = single_run(args, output="output", alone=args.demo)
        return run(single) if single is not None else run_batch(args, "stabilize")
    except WarpvxError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2


__all__ = ["trajectory_params", "save_plot", "scene_cuts", "add_arguments", "run", "main", "run_cli"]
