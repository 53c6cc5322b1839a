"""The hull prior (recon/hull_trim.py): convex closure of measured voxels, opening, shadows kept blocked."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.hull_trim import (keep_blocked, opening, outside_convex_closure,  # noqa: E402
                                         sole_blockers)


def _box(n=12):
    return GridBox([0.0, 0.0, 0.0], [1.0 * n / 10, 1.0 * n / 10, 1.0 * n / 10], n)     # voxel 0.1 m


def pair_segments(pairs):
    o = torch.tensor([a for a, _ in pairs], dtype=torch.float32)
    b = torch.tensor([b for _, b in pairs], dtype=torch.float32)
    v = b - o
    length = torch.linalg.vector_norm(v, dim=-1)
    return o, v / length[:, None], torch.zeros_like(length), length


def _block_with_flange():
    """A 4-voxel cube (2..5 on every axis) with a one-voxel-thick flange along +x at its bottom (x 6..9)."""
    solid = torch.zeros(12, 12, 12, dtype=torch.bool)
    solid[2:6, 2:6, 2:6] = True
    flange = torch.zeros_like(solid)
    flange[6:10, 2:6, 2] = True
    return solid | flange, flange


def test_convex_closure_removes_what_the_anchors_do_not_span():
    solid, flange = _block_with_flange()
    anchors = torch.zeros_like(solid)
    anchors[2:6, 2:6, 2:6] = True     # the cube: a measured surface and shadows' edges place it
    out = outside_convex_closure(solid, anchors)
    assert torch.equal(out, flange)
    # a margin keeps the first voxel outside the anchors' hull
    near = outside_convex_closure(solid, anchors, margin=1.0)
    assert not bool(near[6].any()) and bool(near[7:10, 2:6, 2].all())


def test_convex_closure_leaves_a_part_without_anchors_whole():
    solid, _ = _block_with_flange()
    assert not bool(outside_convex_closure(solid, torch.zeros_like(solid)).any())


def test_opening_removes_a_thin_flange_and_keeps_the_block():
    solid, flange = _block_with_flange()
    opened = opening(solid, 1)
    assert not bool((opened & flange).any())
    assert bool(opened[3:5, 3:5, 2:6].all()) and bool(opened[2:6, 3:5, 3:5].all())     # a ball fits there


def test_keep_blocked_keeps_the_only_blocker_of_a_shadow():
    box = _box()
    solid, flange = _block_with_flange()
    # one shadowed segment crosses the flange only (z = 0.25, above x 0.6..0.9), one crosses flange and cube
    segs = pair_segments([((0.75, 0.35, 0.0), (0.75, 0.35, 1.15)),      # through flange voxel (7, 3, 2)
                      ((1.15, 0.45, 0.25), (0.0, 0.45, 0.25))])     # along x through flange and cube
    kept = keep_blocked(box, solid, flange, segs, step=0.05)
    assert not bool(kept[7, 3, 2])                 # its only blocker stays
    assert bool(kept[8, 4, 2]) and bool(kept[6, 2, 2])    # the rest of the flange still goes
    # without that segment the whole flange may go
    assert torch.equal(keep_blocked(box, solid, flange, tuple(t[1:] for t in segs), step=0.05), flange)


def test_sole_blockers_are_where_a_shadow_grazes():
    box = _box()
    solid, _ = _block_with_flange()
    segs = pair_segments([((0.75, 0.35, 0.0), (0.75, 0.35, 1.15)),      # one flange voxel: 2 samples at step 0.05
                      ((1.15, 0.45, 0.35), (0.0, 0.45, 0.35))])     # 4 cube voxels: 8 samples
    sole = sole_blockers(box, solid.reshape(-1), segs, step=0.05, max_samples=3).reshape(solid.shape)
    assert bool(sole[7, 3, 2]) and int(sole.sum()) == 1
    assert int(sole_blockers(box, solid.reshape(-1), segs, 0.05, max_samples=8).sum()) == 5
    assert int(sole_blockers(box, solid.reshape(-1), segs, 0.05, max_samples=8, min_segments=2).sum()) == 0


def test_hull_prior_settings_refuse_bad_values():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match=r"fast\.hull_closure"):
        override(FitConfig(), ["fast.hull_closure=round"])
    with pytest.raises(SettingsError, match=r"fast\.hull_opening_voxels"):
        override(FitConfig(), ["fast.hull_opening_voxels=-1"])


@pytest.mark.parametrize("setting", [("hull_closure", "convex"), ("hull_opening_voxels", 1)])
def test_prior_keeps_the_box_a_shadow_measures(setting):
    """Tiny box on a floor (4 spots): with the prior on, the start still holds the box's hidden back face."""
    import numpy as np

    from tests.support.recon_fixtures import BOX_BACK_Y, box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import BACK_FACE_TOL_M, back_face_y, small_config
    from torch_recon.recon import fit

    cfg = small_config(steps=0)
    setattr(cfg.fast, *setting)
    r = fit(box_floor_measurements(32), config=cfg)
    assert np.isfinite(r.volume).all()
    assert abs(back_face_y(r) - BOX_BACK_Y) < BACK_FACE_TOL_M
