"""The procedural scene generator: seeded, valid rooms (objects inside, spots in view and lit)."""

from __future__ import annotations

import numpy as np
import pytest

from torch_recon.contract.errors import SettingsError
from torch_recon.contract.frames import focal_length_px
from torch_recon.contract.procedural import (GAP_M, ProceduralSettings, bins_needed, procedural_scene, procedural_scenes,
                                             scene_caster, settings_from_dict)

N_SCENES = 12


@pytest.fixture(scope="module")
def scenes():
    return list(procedural_scenes(N_SCENES, first_seed=100))


def _room_box(ex):
    """Interior of the room: between the inner faces of the side walls, floor, ceiling, back wall."""
    parts = {p.name: p for p in ex.parts}
    sides = [parts["wall_left"].vertices[:, 0], parts["wall_right"].vertices[:, 0]]   # mirrored in some
    x0, x1 = min(v.max() for v in sides), max(v.min() for v in sides)
    z0 = parts["floor"].vertices[:, 2].max()
    z1 = parts["ceiling"].vertices[:, 2].min()
    y1 = parts["floor"].vertices[:, 1].max()
    return np.array([x0, 0.0, z0]), np.array([x1, y1, z1])


def test_same_seed_same_scene():
    a, b = procedural_scene(7), procedural_scene(7)
    assert [p.name for p in a.parts] == [p.name for p in b.parts]
    for p, q in zip(a.parts, b.parts):
        assert np.array_equal(p.vertices, q.vertices) and np.array_equal(p.faces, q.faces) and p.albedo == q.albedo
    assert np.array_equal(a.spot_targets, b.spot_targets)
    assert a.config_overrides == b.config_overrides and a.description == b.description
    c = procedural_scene(8)
    assert c.description != a.description or not np.array_equal(c.spot_targets, a.spot_targets)


def test_scenes_differ_and_vary(scenes):
    sizes = {round(float(_room_box(ex)[1][0] - _room_box(ex)[0][0]), 3) for ex in scenes}
    assert len(sizes) == N_SCENES                   # room sizes are drawn
    styles = {ex.description.split("(")[1].split(" back")[0] for ex in scenes}
    assert len(styles) >= 2                          # box, curved, L backs appear
    kinds = {name.split("_", 1)[1] for ex in scenes for name in ex.objects}
    assert len(kinds) >= 4


def test_object_count_is_drawn_over_the_whole_range(scenes):
    counts = {len(ex.objects) for ex in scenes}
    s = ProceduralSettings()
    assert counts == set(range(s.min_objects, s.max_objects + 1)), counts


def test_objects_inside_room_and_in_view(scenes):
    for ex in scenes:
        lo, hi = _room_box(ex)
        assert len(ex.objects) >= 1, f"{ex.name}: placement dropped every object"
        assert f"{len(ex.objects)} object(s)" in ex.description, ex.name
        by_name = {p.name: p for p in ex.parts}
        boxes = [np.concatenate([by_name[n].vertices for n in names]) for names in ex.objects.values()]
        for i in range(len(boxes)):            # footprints are disjoint discs GAP_M apart: so are any two points
            for j in range(i):
                gap = np.linalg.norm(boxes[i][:, None, :2] - boxes[j][None, :, :2], axis=-1).min()
                assert gap >= GAP_M - 1e-6, f"{ex.name}: objects {i} and {j} are {gap:.3f} m apart"
        for label, names in ex.objects.items():
            v = np.concatenate([by_name[n].vertices for n in names])
            assert np.all(v >= lo - 1e-6) and np.all(v <= hi + 1e-6), f"{ex.name}: {label} leaves the room"
            assert abs(v[:, 2].min() - lo[2]) < 1e-6, f"{ex.name}: {label} does not stand on the floor"
            # inside the sensor's 90 degree horizontal view (camera at the origin looking along +Y)
            assert np.all(np.abs(v[:, 0]) <= v[:, 1] + 1e-6), f"{ex.name}: {label} outside the view"
            if "wall_notch" in by_name:       # the L's block is room, not free floor
                nv = by_name["wall_notch"].vertices
                apart = np.any(v.max(0) <= nv.min(0) + 1e-6) or np.any(v.min(0) >= nv.max(0) - 1e-6)
                assert apart, f"{ex.name}: {label} overlaps the L-shaped back"


def test_spots_in_view_and_lit(scenes):
    for ex in scenes:
        t = np.asarray(ex.spot_targets)
        assert len(t) == ProceduralSettings().spots and all(ex.spot_enabled), ex.name
        # project into a 512 px image: every spot lands inside it
        f = focal_length_px(512, 512, ex.fov_rad, ex.fov_axis)
        c2w = np.asarray(ex.camera_to_world)
        cam = (t - c2w[:3, 3]) @ c2w[:3, :3]          # OpenGL camera frame: looks down -Z
        assert np.all(cam[:, 2] < 0), ex.name
        col = 256 + f * cam[:, 0] / -cam[:, 2]
        row = 256 - f * cam[:, 1] / -cam[:, 2]
        assert np.all((col >= 0) & (col < 512) & (row >= 0) & (row < 512)), ex.name
        # the co-located laser reaches each spot first (nothing in between)
        cast = scene_caster(ex)
        for p in t:
            d = p / np.linalg.norm(p)
            hit = cast(np.zeros(3), d)
            assert hit is not None and np.linalg.norm(hit[0] - p) < 1e-3, ex.name
        assert ex.config_overrides["bins"] == bins_needed(ex, t)


def test_settings_checked():
    with pytest.raises(SettingsError, match="procedural.kinds"):
        settings_from_dict({"kinds": ["teapot"]})
    with pytest.raises(SettingsError, match="procedural.max_objects"):
        settings_from_dict({"min_objects": 3, "max_objects": 2})
    with pytest.raises(SettingsError, match="procedural.colour"):
        settings_from_dict({"colour": 1})
    s = settings_from_dict({"max_objects": 1, "kinds": ["box"]})
    ex = procedural_scene(1, s)
    assert list(ex.objects) == ["obj0_box"]


def test_meshes_from_a_folder(tmp_path):
    import trimesh

    trimesh.creation.annulus(0.2, 0.5, 0.3).export(tmp_path / "ring.ply")
    s = ProceduralSettings(kinds=(), mesh_folder=str(tmp_path), min_objects=2, max_objects=2)
    ex = procedural_scene(3, s)
    assert ex.objects and all(name.endswith("_mesh") for name in ex.objects)
    with pytest.raises(SettingsError, match="mesh_folder"):
        ProceduralSettings(mesh_folder=str(tmp_path / "none")).validate()
