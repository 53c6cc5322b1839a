"""A shadowed segment's restored blocker next to what stayed occupied (recon/shadow_blockers.py,
`fast.explain_neighbour_power`): the lit inside of a hollow part touches nothing, the part's carved voxels do."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon.config import FitConfig  # noqa: E402
from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.voxel_evidence import RESTORED, explain_shadows  # noqa: E402
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


def test_mesh_islands_touching_a_restored_blocker_survive_the_cleanup():
    """`fast.mesh_keep_restored_voxels`: a leg's restored one-voxel column, broken where one voxel moved, falls apart
    into pieces below the island size; the pieces of the restored run are kept, a lone restored voxel (a speck)
    still goes."""
    from types import SimpleNamespace

    import numpy as np

    from torch_recon.mesh_export import mesh_from_volume
    from torch_recon.recon.api import _kept_island_centres, voxel_centre_box

    n = 40
    box = GridBox([0.0, 0.0, 0.0], [float(n)] * 3, n)     # 1 m voxels
    v = np.zeros(box.shape, np.float32)
    v[2:38, 2:38, 2:6] = 1.0                              # the floor
    v[20, 20, 8:14] = 1.0                                 # a leg's restored column above the floor, broken at z = 14
    v[20, 20, 15:30] = 1.0
    v[5, 30, 20] = 1.0                                    # a speck: a lone restored voxel
    restored = torch.zeros(box.shape, dtype=torch.bool)
    restored[20, 20, 8:14] = restored[20, 20, 15:30] = restored[5, 30, 20] = True
    model = SimpleNamespace(thin_parts=None, grid=SimpleNamespace(box=box),
                            start_evidence=lambda: SimpleNamespace(restored=restored),
                            fc=SimpleNamespace(mesh_keep_restored_voxels=3))
    lo, hi = voxel_centre_box(v, box.bbox_min.numpy(), box.bbox_max.numpy())
    leg = lambda m: int(((np.abs(m.vertices[:, :2] - 20.5) < 1.0).all(1) & (m.vertices[:, 2] > 7)).sum())  # noqa: E731
    speck = lambda m: bool((np.abs(m.vertices - [5.5, 30.5, 20.5]).max(1) < 1.5).any())  # noqa: E731
    kept, _ = mesh_from_volume(v, lo, hi, 0.5, min_island_fraction=0.2, keep_near=_kept_island_centres(model))
    assert leg(kept) > 0 and not speck(kept)
    model.fc.mesh_keep_restored_voxels = 0                # off: no thin parts, nothing kept near anything
    assert _kept_island_centres(model) is None
    plain, _ = mesh_from_volume(v, lo, hi, 0.5, min_island_fraction=0.2, keep_near=None)
    assert leg(plain) == 0 and not speck(plain)


def test_the_model_keeps_the_start_fields_restored_blockers_without_labelling_again(monkeypatch):
    """`FastModel.start_evidence().restored` is the start field's label 4, from the one evidence labelling it was
    built with (not a second `evidence_grid` run at export)."""
    import torch_recon.recon.init as init
    from tests.torch_recon.recon.test_recon_thin_training import _meta, _wall_post_data
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon.models import FastModel

    labels = []
    original = init.configured_evidence_grid

    def counted(*args, **kwargs):
        out = original(*args, **kwargs)
        labels.append(out[0].label.clone())
        return out

    monkeypatch.setattr(init, "configured_evidence_grid", counted)
    for seen_through in (0.0, 0.5):     # also where the labelling drops the blockers the pixels saw through (session 18)
        labels.clear()
        cfg = small_config(steps=10)
        cfg.fast.resolution = 32
        cfg.fast.seen_through_voxels = seen_through
        model = FastModel(_wall_post_data(), cfg, _meta())
        assert len(labels) == 1
        restored = model.start_evidence().restored
        assert len(labels) == 1
        assert torch.equal(restored, labels[0] == RESTORED)


def test_a_negative_restored_run_length_is_refused():
    with pytest.raises(SettingsError, match="fast.mesh_keep_restored_voxels"):
        FitConfig.from_dict({"mode": "fast", "fast": {"mesh_keep_restored_voxels": -1}})


def test_a_segment_in_a_large_restored_cluster_takes_the_blocker_most_segments_picked():
    """`fast.explain_shared_cluster_voxels` (shadow_blockers.shared_blockers): a segment whose own best voxel lies in a
    cluster of restored voxels at least that large moves to the first pass's pick on its path that most segments
    picked (the lamp shade's wall rather than a lid voxel); in a smaller cluster it keeps its own."""
    from torch_recon.recon.shadow_blockers import shared_blockers

    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    flat_of = lambda i, j, k: (i * 10 + j) * 10 + k  # noqa: E731
    wall, lid, lone, other = flat_of(5, 5, 5), flat_of(5, 5, 6), flat_of(1, 1, 1), flat_of(1, 1, 3)
    score = torch.zeros(1000)
    score[[wall, lid, lone, other]] = torch.tensor([5.0, 9.0, 9.0, 5.0])
    # four segments: three pick the wall, one (crossing the wall too) picks the lid beside it; one lone pick elsewhere
    paths = torch.tensor([[wall, wall], [wall, wall], [wall, wall], [lid, wall], [lone, other]])
    cand = torch.ones_like(paths, dtype=torch.bool)
    picked = torch.tensor([wall, wall, wall, lid, lone])
    out = shared_blockers(box, picked, [(paths, cand)], score, min_cluster=2)
    assert out.tolist() == [wall, wall, wall, wall, lone]
    assert shared_blockers(box, picked, [(paths, cand)], score, min_cluster=3).tolist() == picked.tolist()


def test_a_negative_shared_cluster_size_is_refused():
    with pytest.raises(SettingsError, match="fast.explain_shared_cluster_voxels"):
        FitConfig.from_dict({"mode": "fast", "fast": {"explain_shared_cluster_voxels": -1}})


@pytest.mark.parametrize("scale, expected", [(0.0, (6, 5, 5)), (0.05, (5, 5, 5))])
def test_the_blocker_goes_where_the_leg_was_measured_not_beside_it(scale, expected):
    """`fast.explain_measured_scale_voxels` (shadow_blockers.MeasuredSurfacePoints): a segment along x crosses a leg's
    carved voxel (5, 5, 5), grazed by a lit ray (shadowed 8, lit 1), and the voxel beside it in the leg's own shadow
    (shadowed 6, lit 0): the ratio alone puts the blocker beside the leg; the leg's measured point (0.58, 0.55, 0.55)
    inside its voxel puts it on the leg."""
    from torch_recon.recon.shadow_blockers import MeasuredSurfacePoints

    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    flat = torch.full(box.shape, 3, dtype=torch.int8).reshape(-1)
    shadow = torch.zeros(box.shape, dtype=torch.long)
    lit = torch.zeros(box.shape, dtype=torch.long)
    shadow[5, 5, 5], lit[5, 5, 5], shadow[6, 5, 5] = 8, 1, 6
    seg = (torch.tensor([[0.05, 0.55, 0.55]]), torch.tensor([[1.0, 0.0, 0.0]]), torch.tensor([0.0]),
           torch.tensor([0.9]))
    measured = (MeasuredSurfacePoints(torch.tensor([[0.58, 0.55, 0.55], [0.1, 0.1, 0.9], [float("nan")] * 3]), scale)
                if scale > 0 else None)
    n = explain_shadows(box, flat, lit.reshape(-1), shadow.reshape(-1), *seg, 0.05, measured=measured)
    assert n == 1
    assert torch.nonzero(flat.reshape(box.shape) == RESTORED).squeeze(0).tolist() == list(expected)


def test_a_negative_measured_scale_is_refused():
    with pytest.raises(SettingsError, match="fast.explain_measured_scale_voxels"):
        FitConfig.from_dict({"mode": "fast", "fast": {"explain_measured_scale_voxels": -0.5}})
