"""One-voxel sheets placed inside their voxel (recon/thin_sheets.py, `fast.mesh_sheet_inset_voxels`): a wall's two
faces move in, a column (a leg or the lamp's pole) keeps its faces."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from torch_recon.contract.errors import SettingsError  # noqa: E402
from torch_recon.recon.config import FitConfig  # noqa: E402
from torch_recon.recon.thin_sheets import one_voxel_sheets, sheet_inset  # noqa: E402

LEVEL, HALF = 0.0, 1.0


def _field():
    """12^3 voxels, free (level - half) but a wall x = 3 (y, z 2..9) and a column x = y = 8 (z 2..9), saturated."""
    raw = torch.full((12, 12, 12), LEVEL - HALF)
    raw[3, 2:10, 2:10] = LEVEL + HALF
    raw[8, 8, 2:10] = LEVEL + HALF
    return raw


def test_a_wall_is_a_sheet_a_column_is_not():
    raw = _field()
    sheet = one_voxel_sheets(raw >= LEVEL + HALF, raw <= LEVEL - HALF, 4)
    assert bool(sheet[3, 3:9, 3:9].all())        # its corners have 3 in-plane neighbours
    assert not bool(sheet[8, 8].any())


def test_the_sheets_faces_move_inside_by_the_inset():
    raw = _field()
    out = sheet_inset(raw, LEVEL, HALF, 0.25)
    v = float(out[3, 5, 5])
    # the crossing from the free neighbour (x = 2) lies 0.5 + 0.25 voxel from its centre
    t = (LEVEL - (LEVEL - HALF)) / (v - (LEVEL - HALF))
    assert t == pytest.approx(0.75)
    assert float(out[8, 8, 5]) == LEVEL + HALF          # the column keeps its faces
    keep = torch.zeros_like(raw, dtype=torch.bool)
    keep[3, 5, 5] = True
    assert float(sheet_inset(raw, LEVEL, HALF, 0.25, keep=keep)[3, 5, 5]) == LEVEL + HALF


def test_a_sheet_beside_a_measured_ramp_stays():
    raw = _field()
    raw[2, 5, 5] = LEVEL - 0.5 * HALF        # a measured surface's outer ramp beside the wall
    assert float(sheet_inset(raw, LEVEL, HALF, 0.25)[3, 5, 5]) == LEVEL + HALF


def test_bad_settings_are_refused():
    with pytest.raises(SettingsError, match="fast.mesh_sheet_inset_voxels"):
        FitConfig.from_dict({"mode": "fast", "fast": {"mesh_sheet_inset_voxels": 0.6}})
    with pytest.raises(SettingsError, match="fast.mesh_sheet_min_in_plane"):
        FitConfig.from_dict({"mode": "fast", "fast": {"mesh_sheet_min_in_plane": 0}})


def test_a_trained_unsaturated_wall_and_a_two_voxel_slab_are_placed_too():
    """Training lowers a hull voxel's raw (its opacity stays 1): such a wall is lowered as well; with max_run 2 the
    two-voxel slab a wall straddling a voxel face leaves too, not with 1."""
    raw = _field()
    raw[3, 2:10, 2:10] = LEVEL + 0.6 * HALF                   # trained, still above the lowered value
    raw[6:8, 2:10, 2:10] = LEVEL + HALF                        # a two-voxel slab x = 6, 7
    target = LEVEL - HALF + HALF / 0.75
    one = sheet_inset(raw, LEVEL, HALF, 0.25)
    assert float(one[3, 5, 5]) == pytest.approx(target)
    assert float(one[6, 5, 5]) == LEVEL + HALF
    two = sheet_inset(raw, LEVEL, HALF, 0.25, max_run=2)
    assert float(two[6, 5, 5]) == pytest.approx(target) and float(two[7, 5, 5]) == pytest.approx(target)


def test_space_the_sensor_saw_through_does_not_end_a_sheet():
    """`fast.mesh_sheet_unseen_sides`: a slab with camera-free space on one side is a part's thickness behind its
    seen face (a chair's seat), not a wall somewhere inside the voxel."""
    raw = _field()
    seen = torch.zeros_like(raw, dtype=torch.bool)
    seen[2] = True                                              # the sensor saw the space at x = 2, before the wall
    assert float(sheet_inset(raw, LEVEL, HALF, 0.25, seen=seen)[3, 5, 5]) == LEVEL + HALF
    assert float(sheet_inset(raw, LEVEL, HALF, 0.25)[3, 5, 5]) < LEVEL + HALF
