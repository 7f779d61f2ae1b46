"""Camera sequences with exact ground truth: a room textured with real photos, ray-cast.

The scene is a box-shaped room (a corridor: floor, ceiling, two side walls, two end walls), each
face textured with a real photograph (mirrored tiling, ``texel`` metres per texture pixel). A
pinhole camera (optionally a rectified stereo pair, the right camera ``baseline`` metres along
the left camera's +x) moves along a smooth known path inside it. Every pixel's ray is cast
against the six faces (from inside a convex box the ray leaves through exactly one: the
smallest positive hit), the texture is sampled bilinearly (``cv2.remap``), and the image is
rendered at ``supersample`` times the size then area-averaged, so distant texture does not
alias. Poses, intrinsics and images are therefore exact: what a front end's ATE is measured
against.

Conventions: camera x right, y down, z forward (OpenCV); world = the first camera's frame;
poses are camera-to-world float64 4x4. :func:`write_kitti_sequence` writes KITTI odometry
layout (``image_0/``, ``image_1/``, ``calib.txt`` with P0/P1, ``times.txt``, ``poses.txt``).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..errors import WarpvxValueError

DATA = Path(__file__).resolve().parent.parent / "data"


def default_textures() -> list:
    """Six real gray textures from the package's bundled data (uint8 HxW): the astronaut
    photo and five frames of the bikes clip (see ``warpvx/data/LICENSE-*.md``)."""
    import cv2

    tex = [cv2.imread(str(DATA / "astronaut_448.png"), cv2.IMREAD_GRAYSCALE)]
    cap = cv2.VideoCapture(str(DATA / "bikes_shaky.mp4"))
    frames = []
    ok, f = cap.read()
    while ok:
        frames.append(f)
        ok, f = cap.read()
    cap.release()
    for i in np.linspace(0, len(frames) - 1, 5).astype(int):
        tex.append(cv2.cvtColor(frames[i], cv2.COLOR_BGR2GRAY))
    if any(t is None for t in tex) or len(tex) < 6:
        raise WarpvxValueError("textures: the bundled images could not be read")
    return tex


def camera_path(n_frames: int, step: float = 0.05, sway: float = 0.3, yaw_deg: float = 6.0,
                pitch_deg: float = 2.0, speed_var: float = 0.0, seed: int | None = None) -> np.ndarray:
    """A smooth path of ``n_frames`` camera-to-world poses (float64 [N, 4, 4]) in the room's
    frame: forward (+z) ``step`` m a frame on average, swaying sideways and up (amplitude
    ``sway`` m, ``sway`` / 3) and turning (yaw, pitch amplitudes in degrees) over one period.
    ``speed_var``: the forward speed varies by that fraction of ``step`` (0.5: from 0.5 to 1.5
    ``step`` a frame) over the period. ``seed``: random phases of the sway, the turns and the
    speed (so turn rates vary differently along the path); None starts them all at zero, the
    first pose then being the identity."""
    k = np.arange(n_frames, dtype=np.float64)
    phase = 2 * math.pi * k / max(n_frames, 8)
    ph = np.zeros(4) if seed is None else np.random.default_rng(seed).uniform(0, 2 * math.pi, 4)
    speed = step * (1 + speed_var * np.sin(phase + ph[3]))
    P = np.tile(np.eye(4), (n_frames, 1, 1))
    P[:, 0, 3] = sway * np.sin(phase + ph[0])
    P[:, 1, 3] = sway / 3 * (1 - np.cos(phase + ph[0]))
    P[:, 2, 3] = np.concatenate([[0.0], np.cumsum(speed[:-1])])
    yaws = np.radians(yaw_deg) * np.sin(phase + ph[1])
    pitches = np.radians(pitch_deg) * np.sin(2 * phase + ph[2])
    for T, a, b in zip(P, yaws, pitches):
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        yaw = np.array([[ca, 0, sa], [0, 1, 0], [-sa, 0, ca]])
        pitch = np.array([[1, 0, 0], [0, cb, -sb], [0, sb, cb]])
        T[:3, :3] = yaw @ pitch
    return P


class Room:
    """A textured box ``[-w/2, w/2] x [-h/2, h/2] x [z0, z1]`` (metres) rendered by ray casting.

    ``textures``: six gray uint8 images (faces -x, +x, -y, +y, -z, +z); ``texel``: metres per
    texture pixel.
    """

    def __init__(self, textures=None, width=4.0, height=3.0, z_range=(-2.0, 14.0), texel=0.004):
        textures = default_textures() if textures is None else list(textures)
        if len(textures) < 6:
            textures = (textures * 6)[:6]
        self.textures = [np.ascontiguousarray(t) for t in textures[:6]]
        self.low = np.array([-width / 2, -height / 2, z_range[0]])
        self.high = np.array([width / 2, height / 2, z_range[1]])
        self.texel = texel

    def render(self, K, size, pose, supersample: int = 2) -> np.ndarray:
        """The gray uint8 image (h, w = ``size`` reversed) seen by a camera of intrinsics ``K``
        (3x3) at camera-to-world ``pose`` (4x4)."""
        import cv2

        w, h = size
        ss = int(supersample)
        K = np.asarray(K, np.float32)
        # float32 rays: a texel error of 1e-7 relative is far below the texture's resolution
        u, v = np.meshgrid((np.arange(w * ss, dtype=np.float32) + 0.5) / ss - 0.5,
                           (np.arange(h * ss, dtype=np.float32) + 0.5) / ss - 0.5)
        rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
        R, c = pose[:3, :3].astype(np.float32), pose[:3, 3].astype(np.float32)
        if not ((c > self.low).all() and (c < self.high).all()):
            raise WarpvxValueError(f"pose: the camera at {c} is outside the room")
        d = rays_c @ R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = np.where(d > 0, self.high.astype(np.float32), self.low.astype(np.float32))
            t = (bound - c) / d
        t = np.where(np.isfinite(t) & (t > 0), t, np.inf)
        axis = np.argmin(t, axis=-1)
        hit = c + np.take_along_axis(t, axis[..., None], -1) * d
        img = np.zeros(axis.shape, np.float32)
        plane_axes = {0: (2, 1), 1: (0, 2), 2: (0, 1)}  # texture (u, v) world axes per face axis
        for a in range(3):
            for side in range(2):
                face = 2 * a + side
                mask = (axis == a) & ((d[..., a] > 0) == bool(side))
                if not mask.any():
                    continue
                tex = self.textures[face]
                ua, va = plane_axes[a]
                mx = (hit[..., ua] - np.float32(self.low[ua])) / np.float32(self.texel)
                my = (hit[..., va] - np.float32(self.low[va])) / np.float32(self.texel)
                sample = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT_101)
                img[mask] = sample[mask]
        if ss > 1:
            img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def intrinsics_for(size) -> np.ndarray:
    """A KITTI-like camera for ``size`` (w, h): focal length 0.57 w (KITTI: 718 px at 1241),
    principal point at the centre. float64 3x3."""
    w, h = size
    f = 0.57 * w
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])


def render_sequence(n_frames: int, size=(640, 480), *, baseline=None, textures=None, step=0.05,
                    supersample: int = 2, speed_var: float = 0.0, seed: int | None = None):
    """Render a sequence: returns (left images [N] uint8 HxW, right images or None, K 3x3,
    poses float64 [N, 4, 4], camera to world with world = the first camera). ``baseline`` (m)
    renders the right camera too; ``step``, ``speed_var``, ``seed``: the path
    (:func:`camera_path`)."""
    K = intrinsics_for(size)
    path = camera_path(n_frames, step=step, speed_var=speed_var, seed=seed)
    room = Room(textures, z_range=(-2.0, path[-1, 2, 3] + step + 12.0))
    left = [room.render(K, size, T, supersample) for T in path]
    right = None
    if baseline:
        offset = np.eye(4)
        offset[0, 3] = baseline
        right = [room.render(K, size, T @ offset, supersample) for T in path]
    return left, right, K, np.linalg.inv(path[0]) @ path


def write_kitti_sequence(folder, left, K, poses, *, right=None, baseline=None, fps=10.0) -> Path:
    """Write a sequence in KITTI odometry layout into ``folder`` (created): ``image_0/``
    (``image_1/`` with ``right``), ``calib.txt`` (P0, and P1 = K [I | -b e_x]), ``times.txt``,
    ``poses.txt`` (ground truth, KITTI format). Returns the folder."""
    import cv2

    from .trajectory_eval import write_kitti

    folder = Path(folder)
    (folder / "image_0").mkdir(parents=True, exist_ok=True)
    for i, img in enumerate(left):
        cv2.imwrite(str(folder / "image_0" / f"{i:06d}.png"), img)
    P0 = np.hstack([K, np.zeros((3, 1))])
    lines = ["P0: " + " ".join(f"{v:.12e}" for v in P0.reshape(-1))]
    if right is not None:
        (folder / "image_1").mkdir(exist_ok=True)
        for i, img in enumerate(right):
            cv2.imwrite(str(folder / "image_1" / f"{i:06d}.png"), img)
        P1 = P0.copy()
        P1[0, 3] = -K[0, 0] * baseline
        lines.append("P1: " + " ".join(f"{v:.12e}" for v in P1.reshape(-1)))
    (folder / "calib.txt").write_text("\n".join(lines) + "\n")
    (folder / "times.txt").write_text("".join(f"{i / fps:.6e}\n" for i in range(len(left))))
    write_kitti(folder / "poses.txt", poses)
    return folder


def main(argv=None) -> int:
    """``python -m warpvx.apps.orbslam_synth FOLDER [--frames N] [--size WxH] [--baseline B]``."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m warpvx.apps.orbslam_synth", description=__doc__.splitlines()[0])
    p.add_argument("folder")
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--size", default="640x480", help="WxH, e.g. 1241x376 (KITTI)")
    p.add_argument("--baseline", type=float, default=None, help="stereo baseline in metres (KITTI: 0.54)")
    p.add_argument("--step", type=float, default=0.05, help="mean forward step (m/frame)")
    p.add_argument("--speed-var", type=float, default=0.0, help="forward speed variation (fraction of --step)")
    p.add_argument("--seed", type=int, default=None, help="random phases of the path's sway, turns, speed")
    args = p.parse_args(argv)
    size = tuple(int(v) for v in args.size.lower().split("x"))
    left, right, K, poses = render_sequence(args.frames, size, baseline=args.baseline, step=args.step,
                                            speed_var=args.speed_var, seed=args.seed)
    print(write_kitti_sequence(args.folder, left, K, poses, right=right, baseline=args.baseline))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["Room", "camera_path", "default_textures", "intrinsics_for", "render_sequence",
           "write_kitti_sequence"]
