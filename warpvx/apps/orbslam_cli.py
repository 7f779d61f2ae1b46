"""The ORB-SLAM2 front end's command line (``warpvx orbslam``, ``apps/orbslam_frontend.py``): open a
sequence, track it with :mod:`warpvx.apps.orbslam`, write the trajectories (TUM and KITTI),
``frames.csv`` and, with ground truth, ``metrics.json`` and the trajectory plot."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..check import check_float, check_int
from ..errors import WarpvxError, WarpvxValueError
from . import orbslam as app
from .orbslam_sources import Sequence, open_source


def add_arguments(parser):
    """The front end's command-line options (``warpvx orbslam`` and ``apps/orbslam_frontend.py``)."""
    parser.add_argument("source", nargs="+", help="KITTI odometry folder, TUM RGB-D folder (rgb.txt), image folder "
                        "or video; several, a glob or @list.txt: a batch under --out (see warpvx.apps.batch)")
    parser.add_argument("--intrinsics", help="fx,fy,cx,cy or a file (OpenCV yml, KITTI calib.txt, 'fx fy cx cy' text); "
                                             "needed unless SOURCE is a KITTI folder")
    parser.add_argument("--gt", metavar="FILE", help="ground truth (KITTI poses or TUM file): writes metrics.json")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: a new folder under ./warpvx-results/)")
    parser.add_argument("--backend", choices=app.BACKENDS, default="cpu")
    parser.add_argument("--max-frames", type=int, default=None)
    parser.add_argument("--mono", action="store_true", help="ignore image_1/ (monocular even on a stereo folder)")
    parser.add_argument("--depth", type=int, default=2, help="frames (batches with --batch) in flight")
    parser.add_argument("--batch", type=int, default=1, metavar="B",
                        help="frames per batch: B > 1 extracts and matches B frames per launch set and spreads "
                             "the pose work over --pose-workers processes (warpvx.apps.orbslam_batch; same "
                             "poses, faster on long sequences; try 16 on a GPU); 1: frame by frame")
    parser.add_argument("--pose-workers", type=int, default=None, metavar="N",
                        help="with --batch: processes for the pose work (default: all cores but three; 0: none)")
    parser.add_argument("--chain-in-process", action="store_true",
                        help="with --batch: track in this process (the default: a process of its own, with "
                             "the pose workers, warpvx.apps.orbslam_chain; same poses)")
    parser.add_argument("--gil-switch-ms", type=float, default=None, metavar="MS",
                        help="with --batch: the GIL switch interval during the run, ms (default 0.2, "
                             "warpvx.apps.orbslam_batch.SWITCH_INTERVAL; 0: Python's own, 5 ms)")
    parser.add_argument("--no-keyframe-motion", action="store_true",
                        help="monocular: motion from the previous frame only, never from the last keyframe "
                             "(faster with --batch, whose pose processes then do all essential matrices; "
                             "less accurate on slow motion)")
    parser.add_argument("--baseline", action="store_true",
                        help="also run the OpenCV-only monocular baseline and score it (with --gt)")
    parser.add_argument("--no-plot", action="store_true", help="skip trajectory.png")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    from .batch import add_batch_arguments

    add_batch_arguments(parser, out=False)


def _ground_truth(path, seq, n):
    from .trajectory_eval import associate, read_trajectory

    times, gt = read_trajectory(path)
    if times is None:
        if len(gt) < n:
            raise WarpvxValueError(f"gt: {path!r} has {len(gt)} poses for {n} frames")
        return np.arange(n), gt[:n]
    idx, gt = associate(seq.times[:n], times, gt)
    if len(idx) < 3:
        raise WarpvxValueError(f"gt: fewer than 3 ground-truth poses match the frames' timestamps in {path!r}")
    return idx, gt


def _anchor(poses):
    """Poses re-expressed relative to the first one (so frame 0 is the world)."""
    return np.linalg.inv(poses[0]) @ poses


def _write_tracked(out, seq, poses, rows):
    """Write the trajectories (TUM, KITTI) and ``frames.csv`` of the tracked frames into ``out``."""
    import csv

    from . import trajectory_eval as te

    te.write_tum(out / "trajectory.tum.txt", seq.times[:len(poses)], poses)
    te.write_kitti(out / "trajectory.kitti.txt", poses)
    with open(out / "frames.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["frame", "time", *app.STATS[:5], "lost", "track_ms", "ms"])
        w.writerows(rows)


def run(args) -> int:
    """Run the front end for parsed ``args`` (see :func:`add_arguments`); returns 0. Raises a
    warpvx error on bad input (the callers print it as one line, exit status 2). The
    trajectories and ``frames.csv`` are written for the frames tracked even when reading or
    tracking stops part way (an error, which then says so, or Ctrl-C). Frames where tracking
    was lost (their poses the motion model's, see :func:`warpvx.apps.orbslam.track`) are
    flagged in the ``lost`` column, counted in ``metrics.json`` (``lost_frames``) and the
    summary line, and listed in a warning on stderr."""
    import json
    import sys

    from tqdm import tqdm

    from . import trajectory_eval as te

    if args.max_frames is not None and args.max_frames < 1:
        raise WarpvxValueError(f"max_frames: expected an int >= 1, got {args.max_frames}")
    batch = check_int(getattr(args, "batch", 1), "batch", min_value=1)
    switch_ms = getattr(args, "gil_switch_ms", None)
    if switch_ms is not None:
        check_float(switch_ms, "gil_switch_ms", min_value=0.0)
    if not args.no_plot:
        try:
            import matplotlib  # noqa: F401
        except ImportError:
            raise WarpvxValueError("plot: matplotlib is not installed (pip install 'warpvx[plot]'; "
                                   "or pass --no-plot)") from None
    if args.gt is not None and not os.path.isfile(args.gt):
        raise WarpvxValueError(f"gt: no such file {args.gt!r}")
    seq = open_source(args.source, args.intrinsics, args.max_frames)
    if args.mono and seq.camera.stereo:
        seq = Sequence(seq.kind, app.Camera(seq.camera.K, seq.camera.size), seq.times, seq._left)
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
    else:
        from ..cli import fresh_results_dir

        out = fresh_results_dir("orbslam")
    mode = "stereo" if seq.camera.stereo else "monocular"
    config = app.TrackerConfig(keyframe_motion=not getattr(args, "no_keyframe_motion", False))
    poses, rows = [], []
    images = [] if args.baseline else None

    def feed():
        for item in seq:
            if images is not None:
                images.append(item["image"])
            yield item

    with tqdm(total=seq.count, unit="frame", disable=args.quiet, desc=f"orbslam ({mode})") as bar:
        if batch > 1:
            from .orbslam_batch import SWITCH_INTERVAL, track_frames_batched

            tracked = track_frames_batched(feed(), seq.camera, config, batch=batch, backend=args.backend,
                                           workers=getattr(args, "pose_workers", None), depth=args.depth,
                                           chain_process=not getattr(args, "chain_in_process", False),
                                           # (0 ms: Python's own interval)
                                           gil_switch_s=SWITCH_INTERVAL if switch_ms is None else 1e-3 * switch_ms or None)
        else:
            tracked = app.track_frames(feed(), seq.camera, config, backend=args.backend, depth=args.depth)
        try:
            for f in tracked:
                poses.append(f.pose)
                lost = int(f.stats["reference"] == app.REF_LOST)
                rows.append([f.index, f"{seq.times[f.index]:.6f}"]
                            + [int(f.stats[k]) for k in app.STATS[:5]]
                            + [lost, f"{f.stats['track_ms']:.3f}", f"{f.ms:.3f}"])
                bar.update()
        except BaseException as exc:
            if not poses:
                raise
            _write_tracked(out, seq, np.asarray(poses), rows)
            if isinstance(exc, WarpvxError):  # (still one line: the callers print it)
                raise type(exc)(f"{exc} (the {len(poses)} frames before it are tracked in {out})") from exc
            raise
    poses = np.asarray(poses)
    n = len(poses)
    _write_tracked(out, seq, poses, rows)
    lost = [r[0] for r in rows if r[7]]
    if lost:
        shown = ", ".join(map(str, lost[:10])) + (", ..." if len(lost) > 10 else "")
        print(f"warning: tracking lost on {len(lost)} of {n} frames ({shown}): their poses are the "
              "constant-velocity model's (frames.csv: lost)", file=sys.stderr)
    note = ("monocular: scale is unobservable, the trajectory is right up to one global scale "
            "(ATE after Sim(3) alignment)" if mode == "monocular"
            else "stereo: metric scale from the stereo baseline (ATE after SE(3) alignment)")
    report = {"source": os.fspath(args.source), "kind": seq.kind, "mode": mode, "note": note,
              "frames": n, "backend": args.backend, "batch": batch, "keyframe_motion": config.keyframe_motion,
              "read_ms_per_frame": seq.read_ms / max(n, 1), "lost_frames": len(lost)}
    gt = None
    if args.gt:
        idx, gt = _ground_truth(args.gt, seq, n)
        gt = _anchor(gt)
        report["warpvx"] = te.evaluate(_anchor(poses[idx]), gt, with_scale=mode == "monocular")
        if images is not None:
            base = app.opencv_baseline(images, seq.camera.K)
            report["opencv_baseline"] = te.evaluate(_anchor(base[idx]), gt, with_scale=True)
        with open(out / "metrics.json", "w") as f:
            json.dump(report, f, indent=2)
    if not args.no_plot:
        if gt is not None:
            aligned, _ = te.align(_anchor(poses[idx]), gt, mode == "monocular")
            te.save_plot(out / "trajectory.png", aligned, gt, f"{mode}, aligned to ground truth")
        else:
            te.save_plot(out / "trajectory.png", poses, None, f"{mode} (top view)")
    msg = f"{n} frames ({mode}; {note}; {len(lost)} lost) -> {out}"
    if gt is not None:
        msg += f"; ATE {report['warpvx']['ate']['rmse']:.4g}"
    print(msg)
    return 0


def main(argv=None, prog="orbslam_frontend.py") -> int:
    """Parse ``argv`` and run; bad input prints one line to stderr and returns 2."""
    from ..cli import ArgumentParser

    parser = ArgumentParser(prog=prog, description=app.__doc__.splitlines()[0])
    add_arguments(parser)
    return run_cli(parser.parse_args(argv), prog)


def run_cli(args, prog="orbslam") -> int:
    """:func:`run` with warpvx errors reported as one line on stderr (exit status 2)."""
    import sys

    from .batch import run_batch, single_run

    try:
        single = single_run(args, paths="source")
        return run(single) if single is not None else run_batch(args, "orbslam", paths="source")
    except WarpvxError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2


__all__ = ["add_arguments", "run", "main", "run_cli"]
