"""Brute-force equirect/pinhole compositor: every Gaussian at every pixel, sequential over depth.

An independent check of the tiled rasterizer (:mod:`.rasterize`): no binning, no fragment lists, no
log-space cumulative sums; a plain loop over Gaussians in depth order applying the same rules
(support ellipse, alpha cap/threshold, early termination). Intended for tiny scenes in float64.
"""

from __future__ import annotations

import torch
from torch import Tensor

from .projection import ProjectedGaussians, RasterSettings

__all__ = ["composite_brute_force"]


def composite_brute_force(
    proj: ProjectedGaussians, settings: RasterSettings, background: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    h, w = proj.height, proj.width
    dtype = proj.uv.dtype
    jj, ii = torch.meshgrid(torch.arange(w, dtype=dtype), torch.arange(h, dtype=dtype), indexing="xy")
    px, py = jj.reshape(-1) + 0.5, ii.reshape(-1) + 0.5
    rgbs, depths, alphas = [], [], []
    for cam in range(proj.num_cameras):
        rgb = torch.zeros(h * w, 3, dtype=dtype)
        depth = torch.zeros(h * w, dtype=dtype)
        trans = torch.ones(h * w, dtype=dtype)
        done = torch.zeros(h * w, dtype=torch.bool)
        rows = torch.nonzero(proj.camera == cam).flatten()
        rows = rows[torch.argsort(proj.depth[rows].detach(), stable=True)]
        for g in rows.tolist():
            du = px - proj.uv[g, 0]
            if proj.wrap_u:
                du = torch.remainder(du + w / 2, w) - w / 2
            dv = py - proj.uv[g, 1]
            a, b, c = proj.conic[g]
            mahal = a * du * du + 2 * b * du * dv + c * dv * dv
            alpha = torch.clamp(proj.opacity[g] * torch.exp(-0.5 * mahal), max=settings.alpha_max)
            use = (mahal <= settings.sigma_extent**2) & (alpha >= settings.alpha_min) & ~done
            next_t = trans * (1 - alpha)
            stop = use & (next_t < settings.transmittance_min)
            done = done | stop
            use = use & ~stop
            weight = torch.where(use, alpha * trans, torch.zeros_like(alpha))
            rgb = rgb + weight[:, None] * proj.color[g]
            depth = depth + weight * proj.depth[g]
            trans = torch.where(use, next_t, trans)
        acc = 1 - trans
        if background is not None:
            rgb = rgb + trans[:, None] * background.to(dtype)
        rgbs.append(rgb.T.reshape(3, h, w))
        depths.append(depth.reshape(h, w))
        alphas.append(acc.reshape(h, w))
    return torch.stack(rgbs), torch.stack(depths), torch.stack(alphas)
