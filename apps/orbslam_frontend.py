#!/usr/bin/env python
"""ORB-SLAM2 front end (thesis ch. 4): ORB extraction, matching and camera motion as a warpvx graph.

Usage:
    python apps/orbslam_frontend.py SOURCE [--intrinsics fx,fy,cx,cy|FILE] [--gt FILE]
                                    [--out DIR] [--backend cpu|warp-cpu|cuda] [--max-frames N]
                                    [--mono] [--baseline] [--no-plot]

    SOURCE  a KITTI odometry folder (image_0/, calib.txt, times.txt; image_1/ for stereo),
            a TUM RGB-D folder (rgb.txt), an image folder or a video (these need --intrinsics)

Writes trajectory.tum.txt, trajectory.kitti.txt, frames.csv, trajectory.png and, with --gt,
metrics.json (ATE after Sim(3) alignment for monocular, SE(3) for stereo; RPE; KITTI t_rel/r_rel).
Monocular scale is unobservable: the trajectory is right up to one global scale.

Example on a rendered stereo sequence with exact ground truth:
    python -m warpvx.apps.orbslam_synth seq --frames 40 --baseline 0.2
    python apps/orbslam_frontend.py seq --gt seq/poses.txt --out run --baseline

Same as `warpvx orbslam SOURCE ...`; the logic is warpvx.apps.orbslam.
"""

import sys

from warpvx.apps.orbslam_cli import main

if __name__ == "__main__":
    sys.exit(main(prog="orbslam_frontend.py"))
