"""Shadowed segments' blockers chosen together (recon/shadow_cover.py, `fast.explain_pick` 'cover'): a wall voxel
both shadows cross beats the less-lit voxels each segment alone ranks first (the lamp shade's interior)."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon.config import FitConfig  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.voxel_evidence import RESTORED, explain_shadows  # noqa: E402
from torch_recon.recon.shadow_cover import greedy_cover  # noqa: E402


def _two_shadows():
    """10^3 voxels of 10 cm, all lit-carved; segment A along x through row (i, 5, 5), segment B along y through
    column (7, j, 5); they cross at the wall voxel (7, 5, 5), lit once, 8 shadowed crossings. Each has an unlit
    voxel of 10 shadowed crossings of its own, (2, 5, 5) and (7, 2, 5): the per-segment ratio picks those."""
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    label = torch.full(box.shape, 3, dtype=torch.int8)
    shadow = torch.zeros(box.shape, dtype=torch.long)
    lit = torch.zeros(box.shape, dtype=torch.long)
    shadow[2, 5, 5] = shadow[7, 2, 5] = 10
    shadow[7, 5, 5], lit[7, 5, 5] = 8, 1
    seg = (torch.tensor([[0.05, 0.55, 0.55], [0.75, 0.05, 0.55]]), torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
           torch.tensor([0.0, 0.0]), torch.tensor([0.9, 0.9]))
    return box, label, shadow, lit, seg


@pytest.mark.parametrize("cover, expected", [(None, [[2, 5, 5], [7, 2, 5]]), (0.5, [[7, 5, 5]])])
def test_one_shared_blocker_explains_both_shadows(cover, expected):
    box, label, shadow, lit, seg = _two_shadows()
    flat = label.reshape(-1).clone()
    n = explain_shadows(box, flat, lit.reshape(-1), shadow.reshape(-1), *seg, 0.05, cover_lit_power=cover)
    assert n == len(expected)
    assert torch.nonzero(flat.reshape(box.shape) == RESTORED).tolist() == expected


def test_greedy_cover_blocks_every_segment_and_is_deterministic():
    seg = torch.tensor([0, 0, 1, 1, 2, 2, 2, 3])
    vox = torch.tensor([5, 9, 9, 4, 4, 9, 7, 1])
    lit = torch.zeros(10, dtype=torch.long)
    picked = greedy_cover(seg, vox, lit, 0.5)
    assert picked.tolist() == [1, 9]         # 9 blocks segments 0-2, 1 is segment 3's only voxel
    assert greedy_cover(seg[:0], vox[:0], lit, 0.5).numel() == 0


def test_bad_settings_are_refused():
    with pytest.raises(SettingsError, match="fast.explain_pick"):
        FitConfig.from_dict({"mode": "fast", "fast": {"explain_pick": "best"}})
    with pytest.raises(SettingsError, match="fast.explain_cover_lit_power"):
        FitConfig.from_dict({"mode": "fast", "fast": {"explain_cover_lit_power": float("nan")}})
