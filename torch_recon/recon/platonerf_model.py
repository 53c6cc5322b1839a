"""PlatoNeRF's reconstructor: two NeRF MLPs trained like the authors' code (see docs/reconstruction.md)."""

from __future__ import annotations

import torch

from .config import FitConfig
from .data import RayData
from .fields import GridBox, NeRFField
from .init import scene_bbox
from .models import _depth, pair_loss
from .renderer import render_field
from .sampler import importance_positions, merged_intervals, ray_box, uniform_intervals


class PlatoNeRFModel:
    """Two NeRF MLPs (coarse, fine), 64 stratified + 128 importance samples, as published."""

    def __init__(self, data: RayData, cfg: FitConfig, meas_meta: dict, generator: torch.Generator):
        self.data, self.cfg, self.pc = data, cfg, cfg.platonerf
        self.device = data.pixel_dirs.device
        lo, hi = scene_bbox(data, 0.05)
        self.bbox = (torch.as_tensor(lo, device=self.device), torch.as_tensor(hi, device=self.device))
        centre = 0.5 * (lo + hi)
        kw = dict(depth=self.pc.depth, width=self.pc.width, skip=self.pc.skip, pe_frequencies=self.pc.pe_frequencies,
                  centre=centre)
        self.coarse = NeRFField(**kw).to(self.device)
        self.fine = NeRFField(**kw).to(self.device)
        self.gen = generator
        self.make_optimizer()

    def make_optimizer(self):
        self.optimizer = torch.optim.Adam(list(self.coarse.parameters()) + list(self.fine.parameters()),
                                          lr=self.pc.lr, betas=(0.9, 0.999))

    def before_step(self, step: int, total: int) -> bool:
        lr = self.pc.lr * 0.1 ** (step / self.pc.lr_decay_steps)
        for g in self.optimizer.param_groups:
            g["lr"] = lr
        return False

    def _bounds(self, o, d):
        near = torch.full_like(o[:, 0], self.pc.near_m)
        if self.pc.far_m is None:
            _, far = ray_box(o, d, *self.bbox)
            far = torch.maximum(far, near + 1e-3)
        else:
            far = torch.full_like(near, self.pc.far_m)
        return near, far

    def _render(self, o, d, near, far, train=True):
        """(fine RenderOut, coarse RenderOut) with the paper's hierarchical sampling."""
        t0, t1 = uniform_intervals(near, far, self.pc.coarse_samples, stratified=train, generator=self.gen)
        coarse = render_field(self.coarse, o, d, t0, t1)
        extra = importance_positions(t0, t1, coarse.weights, self.pc.fine_samples, deterministic=not train,
                                     generator=self.gen)
        f0, f1 = merged_intervals(t0, t1, extra, near, far)
        return render_field(self.fine, o, d, f0, f1), coarse

    def camera_depths(self, c, dirs):
        near, far = self._bounds(c, dirs)
        fine, coarse = self._render(c, dirs, near, far)
        return [fine.depth, coarse.depth]

    def segment_transmittances(self, o, u, near, far):
        fine, coarse = self._render(o, u, near, torch.maximum(far, near))
        return [fine.transmittance, coarse.transmittance]

    def loss(self, idx, step, total, gen):
        return pair_loss(self, self.data, idx, step, total, self.cfg, self.cfg.loss.secondary_offset_m)

    @torch.no_grad()
    def render_depth(self, origins, dirs, chunk=2048, min_opacity=None):
        """The method's own test rendering (64 + 128 samples, fine network); conventions as FastModel."""
        out = []
        for i in range(0, origins.shape[0], chunk):
            o, d = origins[i:i + chunk], dirs[i:i + chunk]
            near, far = self._bounds(o, d)
            fine, _ = self._render(o, d, near, far, train=False)
            out.append(_depth(fine, far, min_opacity))
        return torch.cat(out) if out else origins.new_zeros(0)

    def density(self, pts):
        return torch.cat([self.fine(pts[i:i + 65536]) for i in range(0, pts.shape[0], 65536)]) \
            if pts.shape[0] else pts.new_zeros(0)

    @torch.no_grad()
    def density_volume(self):
        box = GridBox(self.bbox[0].cpu(), self.bbox[1].cpu(), self.pc.volume_resolution).to(self.device)
        pts = box.centres().reshape(-1, 3)
        sigma = torch.cat([self.fine(pts[i:i + 65536]) for i in range(0, pts.shape[0], 65536)])
        op = 1.0 - torch.exp(-sigma * box.voxel)
        return op.reshape(box.shape).cpu().numpy(), box.bbox_min.cpu().numpy(), box.bbox_max.cpu().numpy()

    def params_finite(self) -> bool:
        return all(bool(torch.isfinite(p).all()) for p in list(self.coarse.parameters()) + list(self.fine.parameters()))

    def state_dict(self):
        return {"coarse": {k: v.clone() for k, v in self.coarse.state_dict().items()},
                "fine": {k: v.clone() for k, v in self.fine.state_dict().items()},
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, st):
        self.coarse.load_state_dict(st["coarse"])
        self.fine.load_state_dict(st["fine"])
        self.make_optimizer()
        self.optimizer.load_state_dict(st["optimizer"])
