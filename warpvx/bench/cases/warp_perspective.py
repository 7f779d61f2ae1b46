"""Benchmark cases of :func:`warpvx.warp_perspective`."""

from __future__ import annotations

import numpy as np

from ...backend import resolve_backend
from ...geometry import warp_perspective
from ..inputs import mild_homography
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """Bilinear perspective warp of a BGR photo through a mild homography, same size."""
    import cv2

    h, w = image_bgr.shape[:2]
    m = mild_homography(w, h)

    def prepare(backend_name):
        be = resolve_backend(backend_name)
        src = place(image_bgr, be)
        out = place(np.empty_like(image_bgr), be)
        return lambda: warp_perspective(src, m, (w, h), "linear", out=out, backend=be)

    def opencv():
        dst = np.empty_like(image_bgr)
        return lambda: cv2.warpPerspective(image_bgr, m, (w, h), dst=dst, flags=cv2.INTER_LINEAR)

    def cvcuda_peer():
        import cvcuda
        import torch

        src = cvcuda.as_tensor(torch.from_numpy(image_bgr).cuda()[None], "NHWC")
        dst = cvcuda.as_tensor(torch.empty((1, h, w, 3), dtype=torch.uint8, device="cuda"), "NHWC")
        xform = m.astype(np.float32)
        zero = np.zeros(4, np.float32)
        flags = int(cvcuda.Interp.LINEAR)
        return lambda: cvcuda.warp_perspective_into(dst, src, xform, flags,
                                                    border_mode=cvcuda.Border.CONSTANT,
                                                    border_value=zero)

    def kornia_peer():
        import kornia
        import torch

        img = torch.from_numpy(image_bgr).cuda().permute(2, 0, 1)[None].float().contiguous()
        mt = torch.from_numpy(m).float().cuda()[None]
        return lambda: kornia.geometry.transform.warp_perspective(img, mt, (h, w), mode="bilinear",
                                                                  padding_mode="zeros",
                                                                  align_corners=True)

    return [BenchCase("warp_perspective", "mild homography linear", (w, h), prepare, opencv,
                      {"cvcuda": cvcuda_peer, "kornia": kornia_peer}, image_bgr.nbytes * 2)]
