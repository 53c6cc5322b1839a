"""The fast mode's closed-form start: shadow-consistent carving and visible-surface normals."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.voxel_evidence import RESTORED, explain_shadows  # noqa: E402
from torch_recon.recon.visible_surface_init import _depth_normals  # noqa: E402


def _segment(a, b):
    a, b = torch.tensor([a], dtype=torch.float32), torch.tensor([b], dtype=torch.float32)
    v = b - a
    length = torch.linalg.vector_norm(v, dim=-1)
    return a, v / length[:, None], torch.zeros(1), length


def test_a_shadowed_segment_through_carved_space_gets_its_blocker_back():
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    n = int(np.prod(box.shape))
    label = torch.full((n,), 3, dtype=torch.int8)          # everything carved by lit rays
    lit = torch.full((n,), 50)
    shadow = torch.zeros(n, dtype=torch.long)
    pole = (5 * 10 + 5) * 10 + 5                           # voxel (5, 5, 5): a thin pole's voxel
    lit[pole], shadow[pole] = 3, 40                        # grazed by few lit rays, crossed by many shadows
    shadow[(5 * 10 + 2) * 10 + 5] = 40                     # as shadowed elsewhere but well lit: stays free
    restored = explain_shadows(box, label, lit, shadow, *_segment([0.05, 0.55, 0.55], [0.95, 0.55, 0.55]),
                               step=0.05)
    assert restored == 1 and int(label[pole]) == RESTORED
    assert int((label == RESTORED).sum()) == 1
    # a second shadowed segment through the restored voxel is already explained: nothing more changes
    assert explain_shadows(box, label, lit, shadow, *_segment([0.55, 0.05, 0.55], [0.55, 0.95, 0.55]),
                           step=0.05) == 0


def test_a_shadowed_segment_blocked_by_unknown_space_changes_nothing():
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    n = int(np.prod(box.shape))
    label = torch.full((n,), 3, dtype=torch.int8)
    label[(7 * 10 + 5) * 10 + 5] = 0                       # hidden, never carved: already a blocker
    before = label.clone()
    assert explain_shadows(box, label, torch.ones(n), torch.ones(n), *_segment([0.05, 0.55, 0.55],
                                                                               [0.95, 0.55, 0.55]), step=0.05) == 0
    assert torch.equal(label, before)


def test_normals_of_a_surface_seen_at_a_grazing_angle_next_to_another_surface():
    """A seat seen at 15 degrees with a wall rising right behind it (the nearer neighbour two rows up is on
    the wall): the seat's normals are vertical, the wall's horizontal."""
    h, w = 12, 8
    x = np.zeros((h, w, 3))
    for i in range(h):                                     # rows 0-3: wall (y = 3.2), rows 4-11: seat (z = -1)
        for j in range(w):
            x[i, j] = [0.05 * j, 3.2, -0.6 - 0.1 * i] if i < 4 else [0.05 * j, 3.2 - 0.1 * (i - 3), -1.0]
    valid = np.ones((h, w), bool)
    n = _depth_normals(x, valid, np.array([0.0, 0.0, 0.0]), np.full((h, w), 0.2), tol=0.01)
    assert np.all(np.abs(n[5:, 2:-2, 2]) > 0.99), n[5:, 2:-2]
    assert np.all(np.abs(n[:3, 2:-2, 1]) > 0.99), n[:3, 2:-2]


def test_space_the_sensor_saw_through_beside_an_objects_edge_starts_empty():
    """The visible-surface ramp must not fill voxels the camera rays crossed beyond an object's silhouette.
    The box's front face (normal -y) extended sideways puts the voxels beside the box, behind that plane,
    at a positive signed distance, though the sensor saw the floor through them; at 512 px the same ramp
    grew cave-chair's resolved legs and chair back into lumps several voxels wide (depth L1 0.073 m)."""
    from tests.support.recon_fixtures import BOX_HI, BOX_LO, box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.init import grid_bbox, in_view, initial_grid
    from torch_recon.recon.voxel_evidence import evidence_grid
    from torch_recon.recon.visible_surface_init import surface_offset

    meas = box_floor_measurements(32)
    data = build_ray_data(meas)
    cfg = small_config(steps=0).fast
    box = GridBox(*grid_bbox(data, cfg.resolution, cfg.bbox_margin_voxels), cfg.resolution)
    view = in_view(data, box, np.asarray(meas.camera_to_world), meas.fov_rad, meas.fov_axis)
    label = evidence_grid(data, box, cfg.surface_margin_voxels, cfg.carve_min_lit, 0.0, cfg.step_voxels,
                          cfg.carve_core, carve_spacing_voxels=cfg.carve_spacing_voxels,
                          explain_shadow_rays=cfg.explain_shadows, explain_camera_free=cfg.explain_camera_free,
                          nearest_free=cfg.nearest_free, nearest_surface=cfg.nearest_surface)[0].label
    raw = initial_grid(data, box, cfg, 0.0, view)[0].raw_xyz().detach()
    centres = box.centres()
    beside = ((centres[..., 0].abs() > BOX_HI[0]) & (centres[..., 1] > BOX_LO[1]) & (centres[..., 1] < BOX_HI[1])
              & (centres[..., 2] < BOX_HI[2]))
    seen_through = label == 2
    assert int((seen_through & beside).sum()) > 20
    # never behind a measured surface: at most the ramp's value at the surface (before: 4.0, fully occupied)
    at_surface = surface_offset(cfg.density_scale, box.voxel, cfg.surface_slope)
    assert float(raw[seen_through].max()) <= at_surface + 1e-4


def test_a_point_on_a_thin_part_is_shadowed_by_the_part_not_by_a_voxel_beside_it():
    """A leg a voxel wide, carved by grazing lit rays; a point x on its near side is shadowed from a spot on
    the far side: the leg itself blocks, within the offset the segment skips next to x. Without looking
    there (`lead`) the blocker lands on the first voxel past the offset, beside the leg (a lump outside it)."""
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 10)
    n = int(np.prod(box.shape))
    leg = (5 * 10 + 5) * 10 + 5                            # voxel (5, 5, 5)
    beside = (6 * 10 + 5) * 10 + 5                         # voxel (6, 5, 5), just outside the leg
    x0, spot = [0.52, 0.55, 0.55], [0.98, 0.55, 0.55]      # x on the leg's near side; the spot along +x
    off = 0.15                                             # 1.5 voxels skipped next to x (and the spot)
    o, d, _, length = _segment(x0, spot)
    seg = (o, d, torch.full((1,), off), length - off)
    for lead, want in ((0.0, beside), (off, leg)):
        label = torch.full((n,), 3, dtype=torch.int8)      # carved by lit rays, the leg's voxel (x's) too
        lit, shadow = torch.full((n,), 10), torch.full((n,), 5)
        lit[leg], shadow[leg] = 2, 30                      # the leg: grazed by few lit rays, crossed by many shadows
        assert explain_shadows(box, label, lit, shadow, *seg, step=0.05, lead=lead) == 1
        assert int(label[want]) == RESTORED, lead
        assert int((label == RESTORED).sum()) == 1


def test_explain_lead_refuses_a_negative_distance():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    with pytest.raises(SettingsError, match=r"fast\.explain_lead_voxels"):
        override(FitConfig(), ["fast.explain_lead_voxels=-1"])


def test_a_blocker_restored_on_a_measured_room_plane_keeps_the_planes_ramp(monkeypatch):
    """Session 21: on cave-chair a grazing shadowed segment (a chair leg's shadow on a side wall; the leg, a metre
    away, carved) took a wall voxel as its blocker; occupied, it put the wall half a voxel into the room (+8 mm
    ridges). A restored voxel straddling the measured floor keeps the floor's ramp (the floor stays where it was
    measured); one a voxel above the floor (in the ramp, off the plane: a leg's foot) stays occupied."""
    from tests.support.recon_fixtures import box_floor_measurements
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon import init
    from torch_recon.recon.config import override
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.visible_surface_init import surface_offset

    meas = box_floor_measurements(32)
    data = build_ray_data(meas)
    cfg = small_config(steps=0)
    box = GridBox(*init.grid_bbox(data, cfg.fast.resolution, cfg.fast.bbox_margin_voxels), cfg.fast.resolution)
    view = init.in_view(data, box, np.asarray(meas.camera_to_world), meas.fov_rad, meas.fov_axis)
    c = box.centres()
    i, j = int(torch.argmin((c[:, 0, 0, 0] + 0.8).abs())), int(torch.argmin((c[0, :, 0, 1] - 1.2).abs()))
    k = int(torch.argmin(c[0, 0, :, 2].abs()))              # the voxel straddling the floor (z = 0), beside the box
    real = init.configured_evidence_grid

    def with_blockers(*args, **kw):                          # two carved voxels a shadowed segment took back
        evidence, shadow_count = real(*args, **kw)
        evidence.label[i, j, k] = evidence.label[i, j, k + 1] = RESTORED
        return evidence, shadow_count

    monkeypatch.setattr(init, "configured_evidence_grid", with_blockers)
    fc = cfg.fast
    floor_ramp = fc.surface_slope * float(-c[i, j, k, 2]) / box.voxel + surface_offset(fc.density_scale, box.voxel,
                                                                                         fc.surface_slope)
    raw = init.initial_grid(data, box, fc, 0.0, view)[0].raw_xyz().detach()
    assert abs(float(raw[i, j, k]) - floor_ramp) < 0.01 * fc.surface_slope     # to a hundredth of a voxel
    assert float(raw[i, j, k + 1]) == fc.raw_occupied
    old = override(cfg, ["fast.surface_plane_blocker_voxels=0"]).fast
    assert float(init.initial_grid(data, box, old, 0.0, view)[0].raw_xyz().detach()[i, j, k]) == old.raw_occupied


def test_surface_plane_blocker_band_refuses_a_bad_value():
    from torch_recon.contract.errors import SettingsError
    from torch_recon.recon.config import FitConfig, override

    for bad in ("-0.5", "3", "nan"):
        with pytest.raises(SettingsError, match=r"fast\.surface_plane_blocker_voxels"):
            override(FitConfig(), [f"fast.surface_plane_blocker_voxels={bad}"])


def test_a_shadowed_pair_whose_spot_lies_on_its_pixels_wall_is_in_plane():
    """The bay's spots lie on its side walls: a side-wall pixel and a spot on the same wall are in one plane (light at
    grazing incidence, no return, no occluder: `fast.explain_in_plane_voxels`); floor pixels and the other wall's
    spots are not."""
    from tests.support.recon_fixtures import SIDE_X, box_floor_measurements
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.init import grid_bbox
    from torch_recon.recon.visible_surface_init import visible_surface
    from torch_recon.recon.voxel_evidence import in_plane_pairs

    data = build_ray_data(box_floor_measurements(32))
    box = GridBox(*grid_bbox(data, 40, 1.5), 40)
    flagged = in_plane_pairs(data, visible_surface(data, box), 0.5 * box.voxel)
    x = data.sensor_origin + data.pixel_dirs * data.visible_depth[:, None]
    px, spot = x[data.pair_pixel].double(), data.spot_points[data.pair_spot].double()
    same_wall = ((px[:, 0].abs() - SIDE_X).abs() < 0.01) & (torch.sign(px[:, 0]) == torch.sign(spot[:, 0]))
    assert int(flagged.sum()) > 100 and bool(data.shadowed[flagged].float().mean() > 0.95)
    assert bool(((px[flagged, 0] - spot[flagged, 0]).abs() < box.voxel).all())     # (a corner pixel: the wall's normal)
    assert float(same_wall[~flagged].float().mean()) < 0.05
    # with the setting on, training leaves them out too (neither lit nor shadowed: the losses skip them)
    from tests.torch_recon.recon.test_recon_fit import small_config
    from torch_recon.recon.config import override
    from torch_recon.recon.models import FastModel

    meas = box_floor_measurements(32)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    model = FastModel(data, override(small_config(steps=0), ["fast.explain_in_plane_voxels=0.5"]), meta)
    train = model.training_data(data)
    assert not bool(train.shadowed[flagged].any()) and torch.equal(train.shadowed[~flagged], data.shadowed[~flagged])
