"""What every reconstructor offers the trainer (`ReconstructionModel`), the loss of (spot, pixel) pairs both
models share (`pair_loss`), and the depth of a render (`rendered_depth`); split from models.py."""

from __future__ import annotations

import torch

from .config import FitConfig
from .data import RayData
from .losses import distance_loss, in_warmup, predicted_path, shadow_loss, total_loss
from .renderer import secondary_rays


class ReconstructionModel:
    """What the trainer asks of every model beyond its methods; the defaults of the interface."""

    skip_warmup = False     # True: the distance-only warm-up would move nothing (start with both losses)
    plateau_stop = True     # False: run every step of the schedule (no early stop on a loss plateau)

    def after_step(self, step: int) -> bool:
        """Called after each optimiser step (`step` steps done); True when the model replaced its parameters."""
        return False

    def training_data(self, data: RayData) -> RayData:
        """The pairs the losses fit (all of `data` unless a model leaves some out)."""
        return data


def pair_loss(model: ReconstructionModel, data: RayData, idx, step: int, total: int, cfg: FitConfig, offset: float):
    """Distance (+ shadow after the warm-up) loss of the (spot, pixel) pairs `idx`."""
    px, sp = data.pair_pixel[idx], data.pair_spot[idx]
    dirs = data.pixel_dirs[px]
    c = data.sensor_origin.expand_as(dirs)
    l = data.spot_points[sp]
    warm = in_warmup(step, total, cfg.loss) and not model.skip_warmup
    loss = dirs.new_zeros(())
    stats = {"dist": 0.0, "shadow": 0.0}
    for depth in model.camera_depths(c, dirs, px):
        x = c + dirs * depth[:, None]
        o, u, near, far, _, length = secondary_rays(x, l, offset)
        dist = distance_loss(predicted_path(depth, length, data.laser_to_spot[sp]), data.path[idx],
                             data.lit[idx], cfg.loss)
        shadow = None
        if not warm:
            shadow = sum(shadow_loss(t, data.lit[idx], data.shadowed[idx], cfg.loss)
                         for t in model.segment_transmittances(o, u, near, far))
            stats["shadow"] += float(shadow.detach())
        stats["dist"] += float(dist.detach())
        loss = loss + total_loss(dist, shadow, cfg.loss)
    return loss, stats


def rendered_depth(r, far, min_opacity):
    """Per-ray depth of a render `r`: the expected depth with the missing opacity placed at `far`
    (`min_opacity` None), or the opacity-normalised depth, inf where the opacity stays below `min_opacity`."""
    if min_opacity is None:
        return r.depth + (1.0 - r.opacity) * far
    d = r.depth / r.opacity.clamp(min=1e-10)
    return torch.where(r.opacity >= min_opacity, d, torch.full_like(d, float("inf")))
