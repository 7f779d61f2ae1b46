"""Benchmark cases of :func:`warpvx.color_convert`."""

from __future__ import annotations

import numpy as np

from ...backend import resolve_backend
from ...color import color_convert, output_shape
from ..inputs import bgr_to_nv12
from . import BenchCase, place


def cases(image_bgr: np.ndarray) -> list[BenchCase]:
    """BGR2GRAY, BGR2RGB and NV12->BGR on a real photo (NV12 made from it)."""
    import cv2

    nv12 = bgr_to_nv12(image_bgr)
    return [_case(label, src_host, code) for label, src_host, code in (
        ("BGR2GRAY", image_bgr, cv2.COLOR_BGR2GRAY),
        ("BGR2RGB", image_bgr, cv2.COLOR_BGR2RGB),
        ("YUV2BGR_NV12", nv12, cv2.COLOR_YUV2BGR_NV12),
    )]


def _case(label, src_host, code) -> BenchCase:
    import cv2

    out_shape = output_shape(code, src_host.shape)
    h, w = out_shape[0], out_shape[1]

    def prepare(backend_name):
        be = resolve_backend(backend_name)
        src = place(src_host, be)
        out = place(np.empty(out_shape, np.uint8), be)
        return lambda: color_convert(src, code, out=out, backend=be)

    def opencv():
        dst = np.empty(out_shape, np.uint8)
        return lambda: cv2.cvtColor(src_host, code, dst=dst)

    def cvcuda_peer():
        import cvcuda
        import torch

        t = torch.from_numpy(src_host).cuda()
        t = t[None] if t.ndim == 3 else t[None, :, :, None]
        src = cvcuda.as_tensor(t.contiguous(), "NHWC")
        c = 1 if len(out_shape) == 2 else out_shape[2]
        dst = cvcuda.as_tensor(torch.empty((1, h, w, c), dtype=torch.uint8, device="cuda"), "NHWC")
        cv_code = getattr(cvcuda.ColorConversion, label)
        return lambda: cvcuda.cvtcolor_into(dst, src, cv_code)

    def kornia_peer():
        import kornia
        import torch

        if label == "YUV2BGR_NV12":
            y = torch.from_numpy(src_host[:h]).cuda().float().div(255)[None, None]
            uv = torch.from_numpy(src_host[h:].reshape(h // 2, w // 2, 2)).cuda().float()
            uv = uv.permute(2, 0, 1)[None].div(255).sub(0.5).contiguous()
            return lambda: kornia.color.yuv420_to_rgb(y, uv).flip(1)
        img = torch.from_numpy(src_host).cuda().permute(2, 0, 1)[None].float().div(255).contiguous()
        if label == "BGR2GRAY":
            return lambda: kornia.color.bgr_to_grayscale(img)
        return lambda: kornia.color.bgr_to_rgb(img)

    nbytes = src_host.nbytes + int(np.prod(out_shape))
    peers = {"cvcuda": cvcuda_peer, "kornia": kornia_peer}
    return BenchCase("color_convert", label, (w, h), prepare, opencv, peers, nbytes)
