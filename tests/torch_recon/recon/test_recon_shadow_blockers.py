"""A shadowed segment's restored blocker next to what stayed occupied (recon/shadow_blockers.py,
`fast.explain_neighbour_power`): the lit inside of a hollow part touches nothing, the part's carved voxels do."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon.config import FitConfig  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.init import RESTORED, explain_shadows  # noqa: E402
from torch_recon.recon.shadow_blockers import blocker_weight, occupied_neighbours  # noqa: E402


def _segment_scene():
    """10^3 voxels of 10 cm, all lit-carved but one occupied voxel (5, 6, 5); one shadowed segment along x
    through the row (i, 5, 5): most shadowed crossings at (2, 5, 5) (open space), fewer at (5, 5, 5) (beside the
    occupied voxel)."""
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    label = torch.full(box.shape, 3, dtype=torch.int8)
    label[5, 6, 5] = 0
    shadow = torch.zeros(box.shape, dtype=torch.long)
    shadow[2, 5, 5], shadow[5, 5, 5] = 10, 6
    seg = (torch.tensor([[0.05, 0.55, 0.55]]), torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([0.0]), torch.tensor([0.9]))
    return box, label, shadow, seg


def test_occupied_neighbours_counts_the_26_neighbours_that_are_not_free():
    box, label, _, _ = _segment_scene()
    n = occupied_neighbours(label)
    assert n[5, 5, 5] == 1 and n[4, 5, 4] == 1 and n[2, 5, 5] == 0 and n[5, 6, 5] == 0
    assert n[0, 0, 0] == 0                       # outside the box counts as free
    assert blocker_weight(label, 0.0) is None
    assert float(blocker_weight(label, 2.0).reshape(box.shape)[5, 5, 5]) == 4.0


@pytest.mark.parametrize("power, expected", [(0.0, (2, 5, 5)), (1.0, (5, 5, 5))])
def test_the_blocker_goes_next_to_what_stayed_occupied(power, expected):
    box, label, shadow, seg = _segment_scene()
    flat = label.reshape(-1).clone()
    free = torch.zeros_like(shadow).reshape(-1)
    n = explain_shadows(box, flat, free, shadow.reshape(-1), *seg, 0.05,
                        weight=blocker_weight(label, power))
    assert n == 1
    assert torch.nonzero(flat.reshape(box.shape) == RESTORED).squeeze(0).tolist() == list(expected)


def test_a_negative_power_is_refused():
    with pytest.raises(SettingsError, match="fast.explain_neighbour_power"):
        FitConfig.from_dict({"mode": "fast", "fast": {"explain_neighbour_power": -1.0}})
