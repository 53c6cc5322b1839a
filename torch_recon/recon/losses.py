"""PlatoNeRF's two losses, shared by both modes.

distance: the rendered camera-ray depth d, the secondary segment |x - l| (x = c + d u) and |l - o|
    predict the two-bounce optical path; MSE against the measured path, both divided by
    `path_scale_m` (paper: 15), on pixels with signal only.
shadow: the transmittance of the secondary ray x -> l should be 1 where the pixel is lit and 0
    where it is in shadow; MSE, averaged separately over shadowed and lit rays, then weighted.
Distance alone during the warm-up (the first 12.5 % of the steps); the total is scaled by 100.
"""

from __future__ import annotations

import torch

from .config import LossConfig


def predicted_path(depth: torch.Tensor, secondary_length: torch.Tensor, laser_to_spot: torch.Tensor):
    """Two-bounce optical path: camera -> x (depth) + x -> l + l -> laser origin."""
    return depth + secondary_length + laser_to_spot


def _masked_mean(v: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    n = mask.sum()
    return torch.where(n > 0, (v * mask).sum() / n.clamp(min=1), v.new_zeros(()))


def distance_loss(pred_path, measured_path, signal, cfg: LossConfig) -> torch.Tensor:
    """MSE on path / scale over the rays with signal (0 when there are none); NaN targets are ignored."""
    m = signal & torch.isfinite(measured_path)
    target = torch.where(m, measured_path, torch.zeros_like(measured_path))
    err = (pred_path - target) / cfg.path_scale_m
    return _masked_mean(err * err, m.float())


def shadow_loss(transmittance, lit, shadowed, cfg: LossConfig) -> torch.Tensor:
    """shadow_weight * mean(T^2 | shadowed) + lit_weight * mean((1 - T)^2 | lit)."""
    return (cfg.shadow_weight * _masked_mean(transmittance ** 2, shadowed.float())
            + cfg.lit_weight * _masked_mean((1.0 - transmittance) ** 2, lit.float()))


def in_warmup(step: int, total_steps: int, cfg: LossConfig) -> bool:
    return step < int(round(cfg.warmup_fraction * total_steps))


def total_loss(dist: torch.Tensor, shadow: torch.Tensor | None, cfg: LossConfig) -> torch.Tensor:
    """loss_scale * (distance_weight * distance + shadow); shadow None during the warm-up."""
    loss = cfg.distance_weight * dist
    if shadow is not None:
        loss = loss + shadow
    return cfg.loss_scale * loss


def all_finite(t: torch.Tensor) -> bool:
    """True when every value of `t` is finite. A finite sum proves it in one pass without a mask (a NaN makes the
    sum NaN, an inf makes it inf or NaN); only a non-finite sum (a NaN, an inf, or an overflow of large finite
    values) is looked at value by value."""
    return bool(torch.isfinite(t.sum())) or bool(torch.isfinite(t).all())
