"""The spot advisor (recon/spot_advice.py, `platolidar advise-spots`): spots whose light reaches the shadow hull
that no lit segment of the capture crosses."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from support.recon_fixtures import BOX_HI, BOX_LO, CAMERA, SPOTS, box_floor_mesh  # noqa: E402
from torch_recon.contract.errors import PlatolidarError  # noqa: E402
from torch_recon.recon import FitConfig, fit  # noqa: E402
from torch_recon.recon.spot_advice import AdviceSettings, advise_spots  # noqa: E402
from torch_recon.recon.synthetic_measurements import ideal_measurements  # noqa: E402

#: only the two spots on the left wall: the box's shadow hull to its right no lit segment crosses
LEFT = SPOTS[SPOTS[:, 0] < 0]


def _config():
    cfg = FitConfig(progress=False, steps=0, threads=1, plateau_patience=0)
    cfg.fast.resolution = 40
    cfg.fast.coarse_resolution = 20
    cfg.fast.coarse_fraction = 0.0
    return cfg


def _measure(targets):
    return ideal_measurements(box_floor_mesh(), CAMERA, 32, 32, targets, fov_rad=np.deg2rad(70.0))


def _excess_hull_right(out_dir) -> int:
    """Occupied voxels of a fit right of the box and above the floor, outside the box: truly empty space."""
    with np.load(out_dir / "volume.npz") as z:
        vol, lo, hi = z["opacity"], z["bbox_min"], z["bbox_max"]
    v = (hi - lo) / np.array(vol.shape)
    x, y, zc = np.meshgrid(*[lo[a] + (np.arange(vol.shape[a]) + 0.5) * v[a] for a in range(3)], indexing="ij")
    region = (x > BOX_HI[0] + 2 * v[0]) & (x < 1.2) & (y > BOX_LO[1]) & (y < 3.1) & (zc > 2 * v[2]) & (zc < 0.45)
    return int((region & (vol >= 0.5)).sum())


@pytest.fixture(scope="module")
def left_fit(tmp_path_factory):
    meas = _measure(LEFT)
    out = tmp_path_factory.mktemp("fit-left")
    fit(meas, out=out, config=_config(), uv=False)
    return meas, out


def test_the_advised_spot_carves_the_hull_the_capture_left(left_fit, tmp_path):
    meas, out = left_fit
    advice = advise_spots(None, out, AdviceSettings(add=1, candidates=120, threads=1), measurements=meas)
    assert advice.hull_voxels > 0 and len(advice.spots) == 1
    spot = advice.spots[0]
    assert spot.voxels > 0 and spot.gain > 0 and spot.pixel is not None
    # the capture lights the scene from the left: the light that reaches the right of the box comes from the right
    assert spot.point[0] > 0.0, spot.point
    before = _excess_hull_right(out)
    assert before >= 8          # the setting: the shadow hull does fill that space (10 voxels)
    again = _measure(np.concatenate([LEFT, spot.point[None]]))
    fit(again, out=tmp_path / "fit", config=_config(), uv=False)
    assert _excess_hull_right(tmp_path / "fit") < 0.5 * before
    # the --spot-list texts
    assert advice.spot_list().count(";") == 0 and advice.spot_list(True).count(";") == len(LEFT)
    json.dumps(advice.to_json())


def test_a_fit_saved_with_settings_since_removed_is_still_advised(left_fit, tmp_path):
    """A fit folder written before session 15 holds fast settings removed since (measured no better: FastConfig.
    REMOVED_SETTINGS): the advisor reads the fit's labelling settings it knows and advises as for the fit itself."""
    import shutil

    from torch_recon.recon.fast_config import FastConfig

    meas, out = left_fit
    old = tmp_path / "old-fit"
    shutil.copytree(out, old)
    report = json.loads((old / "fit.json").read_text())
    report["settings"]["fast"].update({"explain_pick": "segment", "explain_cover_lit_power": 0.5,
                                       "explain_min_plane_neighbours": 0, "mesh_lone_inset_voxels": 0.0,
                                       "mesh_hull_taubin_iterations": 0, "mesh_hull_flat_centre_voxels": 0.0})
    assert set(report["settings"]["fast"]) >= set(FastConfig.REMOVED_SETTINGS) - {"tv_weight", "footprint_voxels",
                                                                                   "footprint_views"}
    (old / "fit.json").write_text(json.dumps(report))
    settings = AdviceSettings(add=1, candidates=40, threads=1)
    now, then = advise_spots(None, out, settings, measurements=meas), advise_spots(None, old, settings, measurements=meas)
    assert then.hull_voxels == now.hull_voxels > 0 and then.spot_list() == now.spot_list()


def test_bad_input_one_clear_error(left_fit, tmp_path):
    meas, out = left_fit
    with pytest.raises(PlatolidarError, match="volume.npz: no such file"):
        advise_spots(None, tmp_path, AdviceSettings(), measurements=meas)
    with pytest.raises(PlatolidarError, match="occupied_prior"):
        advise_spots(None, out, AdviceSettings(occupied_prior=1.0), measurements=meas)
    with pytest.raises(PlatolidarError, match="fitted to other data"):
        advise_spots(None, out, AdviceSettings(), measurements=_measure(SPOTS))


def test_cli_refuses_bad_input_with_one_line(left_fit, tmp_path, capsys):
    from torch_recon.cli import main

    _, out = left_fit
    assert main(["advise-spots", str(tmp_path), str(out), "--add", "0"]) == 2
    # the inputs are checked in argument order: a missing dataset is named before the missing fit
    assert main(["advise-spots", str(tmp_path / "none"), str(tmp_path / "nofit")]) == 2
    assert main(["advise-spots", str(tmp_path), str(tmp_path / "nofit")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "add" in err[0]
    assert "none: no such dataset" in err[1] and "volume.npz" not in err[1]
    assert "nofit" in err[2] and "volume.npz" in err[2]


def test_a_coarse_sensor_hull_leaves_out_what_the_sensor_saw_through():
    """The advisor labels voxels as the fit's start field does: with pixel rays farther apart than
    fast.carve_seen_free_beyond_voxels the space between them that the sensor saw through is free, not hull."""
    import dataclasses

    from torch_recon.recon.config import FastConfig
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.fields import GridBox
    from torch_recon.recon.init import grid_bbox
    from torch_recon.recon.spot_voxels import HULL, voxel_classes
    from torch_recon.recon.visible_surface_init import coarse_sensor_seen_free

    meas = ideal_measurements(box_floor_mesh(), CAMERA, 16, 16, LEFT, fov_rad=np.deg2rad(70.0))
    data = build_ray_data(meas)
    fc = FastConfig(resolution=40)
    box = GridBox(*grid_bbox(data, fc.resolution, fc.bbox_margin_voxels), fc.resolution)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    seen = coarse_sensor_seen_free(data, box, fc, meta)
    assert seen is not None and int(seen.sum()) > 0         # the setting: 16 px is a coarse sensor on 40 voxels
    opacity = np.ones(tuple(box.shape), np.float32)         # every voxel occupied: the labels alone decide
    cls = voxel_classes(data, box, opacity, 0.5, dataclasses.asdict(fc), meta, fc.secondary_offset_voxels * box.voxel)
    hull = (cls == HULL).reshape(tuple(box.shape))
    assert int(hull.sum()) > 0 and int((hull & seen).sum()) == 0


def test_beyond_view_none_aims_as_far_beyond_the_view_as_the_capture_s_spots():
    """`beyond_view_deg` none: candidates beyond the image reach as far as the capture's farthest spot (a laser
    known to scan there), measured along the image axes; none when every spot is in view. Default: in view."""
    from types import SimpleNamespace

    from torch_recon.contract.frames import look_at_c2w
    from torch_recon.recon.spot_geometry import degrees_beyond_view

    assert AdviceSettings().beyond_view_deg == 0.0
    # looking along +y with a 90 deg view: the image edge is 45 deg off-axis
    sensor = SimpleNamespace(width=64, height=48, fov_rad=np.pi / 2, fov_axis="x",
                             camera_to_world=look_at_c2w([0.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    at = lambda deg_x, deg_z: [np.tan(np.radians(deg_x)), 1.0, np.tan(np.radians(deg_z))]  # noqa: E731
    assert degrees_beyond_view(sensor, [at(10, 5), at(-40, 0)]) == 0.0
    assert degrees_beyond_view(sensor, [at(10, 5), at(-60, 0)]) == pytest.approx(15.0, abs=1e-6)
    half_y = np.degrees(np.arctan(24 / 32))          # the image's half height, at the same focal length
    assert degrees_beyond_view(sensor, [at(0, half_y + 7)]) == pytest.approx(7.0, abs=1e-6)
    assert degrees_beyond_view(sensor, [[0.0, -1.0, 0.0]]) == 0.0      # behind the sensor


def _slab_grid():
    """A 10^3 grid of 0.1 m voxels from (0, 1, 0), a slab occupying x 2..7, y 3..7, z 4..5 (indices), and a
    sensor in front of it, above and right of it (0.9, 0, 2)."""
    from torch_recon.contract.frames import look_at_c2w
    from torch_recon.recon.fields import GridBox

    box = GridBox.exact([0.0, 1.0, 0.0], 0.1, (10, 10, 10))
    occupied = torch.zeros(10, 10, 10, dtype=torch.bool)
    occupied[2:8, 3:8, 4:6] = True
    return box, occupied, look_at_c2w([0.9, 0.0, 2.0], [0.5, 1.5, 0.45])


def test_back_faces_are_the_sides_of_a_part_facing_away_from_the_sensor():
    """A slab seen from above and in front: its underside, its far side and its left side (the sensor is
    right of it) bound free space away from the sensor; its top and front do not (the sensor sees them)."""
    from torch_recon.recon.spot_geometry import back_facing_free

    box, occupied, c2w = _slab_grid()
    back = back_facing_free(occupied, box, c2w)
    assert bool(back[2:8, 3:8, 4].all())                # the underside: every voxel of the lower layer
    assert not bool(back[3:7, 3:7, 5].any())            # the top's inner voxels (the front row included)
    assert bool(back[3:7, 7, 5].all())                  # the far side's upper row
    assert bool(back[2, 3:7, 5].all()) and not bool(back[7, 3:7, 5].any())   # left side yes, right side no
    assert not bool((back & ~occupied).any())


def test_light_grazing_a_back_face_places_it():
    """A FACE voxel (a hidden back face next to a measured surface) is a target the light passes, not a
    blocker and not unbounded hull: a segment along the slab's underside values each of its voxels 1; as HULL
    the same voxels are worth (1 - prior)^n; one SOLID voxel on the way stops the segment."""
    from torch_recon.recon.spot_voxels import FACE, HULL, SOLID, segment_values

    box, occupied, _ = _slab_grid()
    layer = torch.zeros(10, 10, 10, dtype=torch.bool)
    layer[2:8, 5, 4] = True                             # one row of the underside, along x
    index = torch.full((1000,), -1, dtype=torch.long)
    flat = torch.nonzero(layer.reshape(-1)).squeeze(1)
    index[flat] = torch.arange(len(flat))
    start, end = torch.tensor([[0.05, 1.55, 0.45]]), torch.tensor([[0.95, 1.55, 0.45]])

    def values(kind):
        cls = torch.zeros(1000, dtype=torch.int8)
        cls[flat] = kind
        return segment_values(box, cls, index, len(flat), start, end, 0.0, 0.05, 0.25, "cpu")

    assert torch.allclose(values(FACE), torch.ones(6))
    hull = values(HULL)
    assert bool((hull > 0).all()) and float(hull.max()) < 0.5      # six voxels of prior 0.25: 0.75^6 = 0.18
    assert float(values(SOLID).sum()) == 0.0


def test_refinement_moves_a_coarse_spot_to_a_better_point_near_it(left_fit, capsys):
    """With few, coarse candidates the greedy spot is rarely the best point near it: `refine_voxels` moves it
    to a better sensor-visible point within the radius (the same expected-coverage objective), never to a
    worse one, the same way every run (seeded)."""
    from torch_recon.cli import main

    meas, out = left_fit
    coarse = AdviceSettings(add=1, candidates=8, threads=1)
    refined = AdviceSettings(add=1, candidates=8, threads=1, refine_voxels=4.0)
    before = advise_spots(None, out, coarse, measurements=meas)
    after = advise_spots(None, out, refined, measurements=meas)
    assert after.details["covered_greedy"] == pytest.approx(before.covered)
    assert after.covered > before.covered * 1.02, (before.covered, after.covered)
    moved = np.linalg.norm(after.spots[0].point - before.spots[0].point)
    assert 0.0 < moved <= 3 * 4.0 * after.voxel_m + 1e-6          # at most SWEEPS radii away
    assert after.spots[0].pixel is not None and after.spots[0].gain > before.spots[0].gain
    # it comes within 2 % of what 15 times as many candidates find (session 14: the same point and coverage; since
    # session 21's start field, `fast.surface_seen_through_voxels`, a neighbouring local best: 7.36 against 7.44)
    dense = advise_spots(None, out, AdviceSettings(add=1, candidates=120, threads=1), measurements=meas)
    assert after.covered >= 0.98 * dense.covered, (after.covered, dense.covered)
    again = advise_spots(None, out, refined, measurements=meas)
    assert np.array_equal(again.spots[0].point, after.spots[0].point)
    assert main(["advise-spots", "x", str(out), "--refine-voxels", "-1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refine_voxels" in err[0]


def test_the_advisor_labels_voxels_as_the_fit_s_start_field_does(monkeypatch):
    """The advisor's labels are the start field's, restored blockers included: the blockers rank by the same
    objects' measured points (the room's planes left out, `init.objects_measured_points`)."""
    import dataclasses

    from torch_recon.recon import spot_voxels
    from torch_recon.recon.config import FastConfig
    from torch_recon.recon.data import build_ray_data
    from torch_recon.recon.fields import GridBox
    from torch_recon.recon.init import grid_bbox, in_view, initial_grid
    from torch_recon.recon.visible_surface_init import coarse_sensor_seen_free
    from torch_recon.recon.voxel_evidence import RESTORED

    meas = _measure(LEFT)
    data = build_ray_data(meas)
    fc = FastConfig(resolution=40)
    assert fc.explain_measured_scale_voxels > 0      # the default this test is about
    box = GridBox(*grid_bbox(data, fc.resolution, fc.bbox_margin_voxels), fc.resolution)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    view = in_view(data, box, meta["camera_to_world"], meta["fov_rad"], meta["fov_axis"])
    offset = fc.secondary_offset_voxels * box.voxel
    start = initial_grid(data, box, fc, offset, view, seen_free=coarse_sensor_seen_free(data, box, fc, meta))[2]
    labels, wrapped = [], spot_voxels.configured_evidence_grid

    def recorded(*args, **kwargs):
        out = wrapped(*args, **kwargs)
        labels.append(out[0].label)
        return out
    monkeypatch.setattr(spot_voxels, "configured_evidence_grid", recorded)
    spot_voxels.voxel_classes(data, box, np.ones(tuple(box.shape), np.float32), 0.5, dataclasses.asdict(fc), meta,
                              offset)
    assert int((start.label == RESTORED).sum()) > 0
    assert torch.equal(labels[0], start.label)
