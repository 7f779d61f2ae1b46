"""Monocular accuracy of the ORB-SLAM front end on rendered sequences of varying speed (exact
poses) and on castle_simu: warpvx with and without keyframe motion
(``TrackerConfig.keyframe_motion``) against the OpenCV-only baseline (ATE after Sim(3)
alignment, RPE over one frame). CPU backend: the poses equal the GPU's and the batched mode's
(tests/apps/test_orbslam_batch.py), so accuracy needs no GPU.

Usage::

    python benchmarks/orbslam_accuracy.py --out DIR      # ~4 min on 2 cores
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from warpvx.apps import orbslam as o  # noqa: E402
from warpvx.apps import trajectory_eval as te  # noqa: E402
from warpvx.apps.orbslam_synth import render_sequence  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
# (the bench's castle_simu: next to the main checkout, else the dev machine's copy; a worktree has none beside it)
from orbslam_bench import CASTLE  # noqa: E402

#: (label, frames, size, mean step m/frame, speed variation, seed): the bench's sequence first.
SEQUENCES = (
    ("bench: 60 f 1241x376, 0.25 m/f", 60, (1241, 376), 0.25, 0.0, None),
    ("60 f 1241x376, 0.25 m/f +-50%, seed 1", 60, (1241, 376), 0.25, 0.5, 1),
    ("60 f 1241x376, 0.25 m/f +-50%, seed 4", 60, (1241, 376), 0.25, 0.5, 4),
    ("80 f 640x480, 0.04-0.16 m/f, seed 2", 80, (640, 480), 0.1, 0.6, 2),
    ("60 f 640x480, 0.05 m/f +-50%, seed 5", 60, (640, 480), 0.05, 0.5, 5),
    ("30 f 640x480, 0.05 m/f", 30, (640, 480), 0.05, 0.0, None),
)


def scores(est, gt):
    r = te.evaluate(est, gt, True)
    return r["ate"]["rmse"], r["rpe"]["delta_1"]["trans_rmse"], r["rpe"]["delta_1"]["rot_rmse_deg"]


def sequences(castle: Path):
    for label, n, size, step, var, seed in SEQUENCES:
        left, _, K, gt = render_sequence(n, size, step=step, speed_var=var, seed=seed, supersample=1)
        yield label, left, o.Camera(K, size), gt
    if castle.is_dir():
        from warpvx.apps.orbslam_sources import open_source

        seq = open_source(str(castle))
        left = [f["image"] for f in seq]
        yield "castle_simu, 40 f 640x480", left, seq.camera, te.read_kitti(castle / "poses.txt")[:len(left)]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="folder for orbslam_accuracy.md")
    p.add_argument("--castle", default=str(CASTLE))
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows = []
    n_seq = len(SEQUENCES) + Path(args.castle).is_dir()
    for label, left, camera, gt in tqdm(sequences(Path(args.castle)), total=n_seq, unit="sequence"):
        row = [label]
        for kfm in (True, False):
            frames = [{"image": im} for im in left]
            poses = np.array([f.pose for f in o.track_frames(frames, camera, o.TrackerConfig(keyframe_motion=kfm))])
            row.append(scores(poses, gt))
        row.append(scores(o.opencv_baseline(left, np.ascontiguousarray(camera.K)), gt))
        rows.append(row)
    fmt = "{:.4f} / {:.4f} / {:.3f}".format
    lines = [f"<!-- python benchmarks/orbslam_accuracy.py --out {args.out} -->",
             "# Monocular accuracy: ATE (m, Sim3) / RPE t (m, 1 frame) / RPE r (deg)", "",
             "| sequence | warpvx (keyframe motion, default) | warpvx, keyframe motion off | OpenCV baseline |"
             " default no worse than baseline | off no worse |", "| --- | --- | --- | --- | --- | --- |"]
    for label, on, off, base in rows:
        lines.append(f"| {label} | {fmt(*on)} | {fmt(*off)} | {fmt(*base)} | "
                     f"{'yes' if all(a <= b for a, b in zip(on, base)) else 'NO'} | "
                     f"{'yes' if all(a <= b for a, b in zip(off, base)) else 'NO'} |")
    lines += ["", f"CPU backend, {time.perf_counter() - t0:.0f} s."]
    (out / "orbslam_accuracy.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
