"""Benchmark cases of :func:`warpvx.remap`."""

from __future__ import annotations

import numpy as np

from ...backend import resolve_backend
from ...geometry import remap
from ..inputs import undistort_maps
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """Bilinear remap of a BGR photo through lens-undistortion maps, constant border."""
    import cv2

    h, w = image_bgr.shape[:2]
    map_x, map_y = undistort_maps(w, h)

    def prepare(backend_name):
        be = resolve_backend(backend_name)
        src, mx, my = (place(a, be) for a in (image_bgr, map_x, map_y))
        out = place(np.empty_like(image_bgr), be)
        return lambda: remap(src, mx, my, "linear", "constant", 0, out=out, backend=be)

    def opencv():
        dst = np.empty_like(image_bgr)
        return lambda: cv2.remap(image_bgr, map_x, map_y, cv2.INTER_LINEAR, dst=dst,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def cvcuda_peer():
        import cvcuda
        import torch

        src = cvcuda.as_tensor(torch.from_numpy(image_bgr).cuda()[None], "NHWC")
        grid = torch.from_numpy(np.stack([map_x, map_y], -1)).cuda()[None].contiguous()
        mp = cvcuda.as_tensor(grid, "NHWC")
        dst = cvcuda.as_tensor(torch.empty((1, h, w, 3), dtype=torch.uint8, device="cuda"), "NHWC")
        zero = np.zeros(4, np.float32)
        return lambda: cvcuda.remap_into(dst, src, mp, src_interp=cvcuda.Interp.LINEAR,
                                         map_interp=cvcuda.Interp.NEAREST,
                                         map_type=cvcuda.Remap.ABSOLUTE, align_corners=False,
                                         border=cvcuda.Border.CONSTANT, border_value=zero)

    def kornia_peer():
        import kornia
        import torch

        img = torch.from_numpy(image_bgr).cuda().permute(2, 0, 1)[None].float().contiguous()
        mx = torch.from_numpy(map_x).cuda()[None]
        my = torch.from_numpy(map_y).cuda()[None]
        return lambda: kornia.geometry.transform.remap(img, mx, my, mode="bilinear",
                                                       padding_mode="zeros", align_corners=True)

    nbytes = image_bgr.nbytes * 2 + map_x.nbytes + map_y.nbytes
    return [BenchCase("remap", "undistort linear", (w, h), prepare, opencv,
                      {"cvcuda": cvcuda_peer, "kornia": kornia_peer}, nbytes)]
