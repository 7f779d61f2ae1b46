"""Applications built from warpvx graphs (SPEC §8): :mod:`warpvx.apps.stabilize`, the video
stabilizer of thesis §3.2, and its quality metrics :mod:`warpvx.apps.stabilize_metrics`."""
