"""Applications built from warpvx graphs (SPEC §8): :mod:`warpvx.apps.stabilize`, the video
stabilizer of thesis §3.2 (command line :mod:`warpvx.apps.stabilize_cli`, quality metrics
:mod:`warpvx.apps.stabilize_metrics`), and :mod:`warpvx.apps.orbslam`, the ORB-SLAM2 front end
(sequences :mod:`warpvx.apps.orbslam_sources`, command line :mod:`warpvx.apps.orbslam_cli`);
video input/output shared by both in :mod:`warpvx.apps.video_io`."""
