"""A minimal monocular front end behind ``warpvx ros-orbslam``: ORB extraction as a warpvx
graph, frame-to-frame tracking on the CPU.

Per frame: ORB-SLAM2 keypoints and descriptors (:func:`warpvx.orb`, in :func:`orb_graph`),
mutual-best Hamming matches to the previous frame (:func:`warpvx.match_hamming`), the
essential matrix by RANSAC and the relative pose with the cheirality check
(``cv2.findEssentialMat`` + ``cv2.recoverPose``), chained with unit translation steps (a
monocular camera has no scale). A frame with fewer than :data:`MIN_MATCHES` matches, or no
essential matrix, keeps the previous pose. Stand-in for the full ORB-SLAM front end app.
"""

from __future__ import annotations

import numpy as np

from ._env import msg as _msg

#: Fewest matches to estimate a relative pose (the five-point RANSAC needs 5; 8 steadies it).
MIN_MATCHES = 8


def orb_graph(shape, n_features: int = 2000, backend: str = "cpu"):
    """A graph: input ``image`` (uint8 gray of ``shape`` (h, w)) -> ORB -> outputs
    ``keypoints`` (:class:`~warpvx.Keypoints`) and ``descriptors`` (uint8 [N, 32]), scheduled
    on CPU workers (``"cpu"``) or with the Warp device (other backends)."""
    from ..apps.stabilize import schedule
    from ..graph import Graph

    g = Graph("orb")
    image = g.input("image", shape=tuple(shape), dtype=np.uint8)
    keypoints, descriptors = g.orb(image, n_features=n_features, name="orb",
                                   target=None if backend == "cpu" else "gpu")
    g.output("keypoints", keypoints)
    g.output("descriptors", descriptors)
    schedule(g, backend)
    return g


class MonoTracker:
    """Frame-to-frame monocular tracking; :meth:`update` returns each frame's pose.

    Poses are camera-to-world float64 4x4, the world being the first camera (x right, y down,
    z forward), translation in steps of unit length.
    """

    def __init__(self, backend: str | None = "cpu"):
        self.backend = backend
        self.pose = np.eye(4)
        self._prev = None

    def update(self, keypoints, descriptors, K) -> np.ndarray:
        """Track one frame: ``keypoints`` (Keypoints, level-0 pixels), ``descriptors``
        (uint8 [N, 32]), ``K`` (float64 3x3 intrinsics). Returns a copy of the pose."""
        import cv2

        from ..matching import match_hamming

        xy = keypoints.numpy().xy().astype(np.float64)
        descriptors = np.asarray(descriptors)
        if self._prev is not None and len(xy) and len(self._prev[0]):
            pairs, _ = match_hamming(self._prev[1], descriptors, cross_check=True, backend=self.backend)
            if len(pairs) >= MIN_MATCHES:
                p0, p1 = self._prev[0][pairs[:, 0]], xy[pairs[:, 1]]
                E, mask = cv2.findEssentialMat(p0, p1, K, cv2.RANSAC, 0.999, 1.0)
                if E is not None and E.shape == (3, 3):
                    _, R, t, _ = cv2.recoverPose(E, p0, p1, K, mask=mask)
                    step = np.eye(4)  # previous camera -> current camera
                    step[:3, :3], step[:3, 3] = R, t.ravel()
                    self.pose = self.pose @ np.linalg.inv(step)
        self._prev = (xy, descriptors)
        return self.pose.copy()


def track_frames(frames, K, *, n_features: int = 2000, backend: str = "cpu") -> list:
    """Offline: the poses (float64 4x4) of gray uint8 ``frames`` with intrinsics ``K``, the
    same work as the ``ros-orbslam`` node without ROS."""
    tracker, graph, poses = MonoTracker(backend), None, []
    for frame in frames:
        graph = graph or orb_graph(frame.shape, n_features, backend)
        out = graph.process({"image": frame})
        poses.append(tracker.update(out["keypoints"], out["descriptors"], K))
    return poses


def pose_message(pose, header, frame_id: str):
    """A geometry_msgs/PoseStamped of camera-to-world 4x4 ``pose`` (stamp from ``header``)."""
    import cv2

    out = _msg("geometry_msgs", "PoseStamped")()
    out.header.stamp, out.header.frame_id = header.stamp, frame_id
    rvec = cv2.Rodrigues(np.ascontiguousarray(pose[:3, :3]))[0].ravel()
    angle = float(np.linalg.norm(rvec))
    axis = rvec / angle if angle > 0 else np.zeros(3)
    q = out.pose.orientation
    q.x, q.y, q.z = (axis * np.sin(angle / 2)).tolist()
    q.w = float(np.cos(angle / 2))
    p = out.pose.position
    p.x, p.y, p.z = pose[:3, 3].tolist()
    return out


def pose_matrix(msg) -> np.ndarray:
    """The camera-to-world float64 4x4 of a geometry_msgs/Pose(Stamped)."""
    import cv2

    pose = getattr(msg, "pose", msg)
    q, p = pose.orientation, pose.position
    half = np.arccos(np.clip(q.w, -1.0, 1.0))
    s = np.sin(half)
    rvec = np.array([q.x, q.y, q.z]) / s * 2 * half if s > 1e-12 else np.zeros(3)
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(rvec)[0]
    out[:3, 3] = p.x, p.y, p.z
    return out


def path_message(poses: list, frame_id: str):
    """A nav_msgs/Path of PoseStamped messages ``poses`` (the header: the last pose's stamp)."""
    out = _msg("nav_msgs", "Path")()
    out.header.frame_id = frame_id
    if poses:
        out.header.stamp = poses[-1].header.stamp
    out.poses = list(poses)
    return out
