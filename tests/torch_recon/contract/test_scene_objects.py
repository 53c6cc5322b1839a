"""Which parts are objects (torch_recon.contract.scene_objects) and the examples' labels."""

from __future__ import annotations

import copy

import numpy as np

from torch_recon.contract import scenes
from torch_recon.contract.ground_truth import object_meshes, room_mesh
from torch_recon.contract.scene_objects import label_parts, split_mesh_objects

from tests.support.example_triangles import example_triangles


def _bounds(ex):
    return {p.name: (p.vertices.min(axis=0), p.vertices.max(axis=0)) for p in ex.parts}


def test_unlabelled_parts_split_room_shell_from_touching_objects():
    # a user's .blend without an 'Objects' collection: walls (also a curved one) are the shell, the chair's
    # seat, back and legs touch: one object
    for ex in (scenes.cave_chair(), scenes.curved_wall_scene()):
        labels = label_parts(_bounds(ex))
        assert len(labels) == 1
        (parts,) = labels.values()
        assert sorted(parts) == sorted(p.name for p in ex.parts if p.name.startswith("chair_"))
    labels = label_parts(_bounds(scenes.organic_occluded()))
    assert sorted(sum(labels.values(), [])) == ["blob", "occluder"] and len(labels) == 2


def test_labels_win_and_every_labelled_example_names_real_parts():
    for name in scenes.OBJECT_SCENES:
        ex = scenes.example(name)
        names = {p.name for p in ex.parts}
        assert ex.objects and all(set(v) <= names for v in ex.objects.values()), name
        assert label_parts(_bounds(ex), ex.objects) == ex.objects


def test_object_meshes_and_room_from_triangles():
    ex = scenes.thin_structures()
    tri = example_triangles(ex)
    objs = object_meshes(*tri, labelled=ex.objects)
    assert sorted(objs) == ["lamp", "table"]
    lamp, parts = objs["lamp"]
    assert parts == sorted(ex.objects["lamp"]) and len(lamp.faces) == 12 * len(parts)
    room = room_mesh(tri, objs)
    assert len(room.faces) + sum(len(m.faces) for m, _ in objs.values()) == len(tri[1])
    whole, _ = ex.trimesh()
    assert len(split_mesh_objects(whole)) == 2          # the same two objects, found without labels


def test_outside_fov_column_is_out_of_view_and_shadows_visible_pixels():
    """outside-fov: the column lies outside the sensor's view, the out-of-view spots' light passes it, and its
    shadows land on pixels the sensor sees (analytic renders with and without the column)."""
    from torch_recon.contract.analytic import render_two_bounce
    from torch_recon.contract.frames import project_points
    from torch_recon.contract.scenes import OUTSIDE_FOV_TARGETS, chair, outside_fov, room_walls
    from torch_recon.contract.synthetic import concat, default_sensor

    sc = outside_fov()
    assert sum(sc.spot_enabled) == 16 and all(sc.spot_enabled[-len(OUTSIDE_FOV_TARGETS):])
    column = next(p for p in sc.parts if p.name == "column")
    sensor = default_sensor(24, 24, bins=391)
    col, row, depth = project_points(sensor.camera_to_world, 24, 24, sensor.fov_rad, column.vertices)
    assert not np.any((depth > 0) & (col >= 0) & (col < 24) & (row >= 0) & (row < 24))
    lds = np.asarray(OUTSIDE_FOV_TARGETS) / np.linalg.norm(OUTSIDE_FOV_TARGETS, axis=1, keepdims=True)
    with_column = render_two_bounce(sc.trimesh()[0], sensor, lds).sum(-1) > 0
    without = render_two_bounce(concat(room_walls() + chair()), sensor, lds).sum(-1) > 0
    shadowed_by_column = (without & ~with_column).sum(axis=(1, 2))
    assert np.all(shadowed_by_column > 0.05 * 24 * 24), shadowed_by_column


def test_scene_fingerprint_is_stable_and_sees_every_edit():
    """The benchmark cache keys datasets by it: an edited scene must not reuse an old simulation."""
    import dataclasses

    from torch_recon.contract.scenes import EXAMPLES
    base = EXAMPLES["outside-fov"]()
    assert base.fingerprint() == EXAMPLES["outside-fov"]().fingerprint()
    assert len({EXAMPLES[n]().fingerprint() for n in EXAMPLES}) == len(EXAMPLES)
    moved = copy.deepcopy(base)
    moved.parts[-1].vertices[0, 0] += 1e-6                       # one vertex of the column, a micrometre
    spots = dataclasses.replace(base, spot_targets=[*base.spot_targets[:-1], (0.0, 3.9, -1.0)])
    dark = dataclasses.replace(base, config_overrides={"ambient_per_bin": 0.01})
    assert len({base.fingerprint(), moved.fingerprint(), spots.fingerprint(), dark.fingerprint()}) == 4
