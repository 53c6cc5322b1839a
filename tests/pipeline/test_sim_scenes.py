"""The example scenes' bpy-free geometry (torch_recon/contract/scenes.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from torch_recon.contract import scenes
from torch_recon.contract.frames import paper_to_blender_points

from torch_recon.contract.reference import REFERENCE_FILE as REFERENCE  # noqa: E402


def test_paper_targets_match_the_reference():
    targets, enabled = scenes.paper_spots()
    assert len(targets) == 24 and sum(enabled) == 16
    if REFERENCE.is_file():
        ref = json.loads(REFERENCE.read_text())
        assert np.allclose(targets, paper_to_blender_points(ref["laser_targets_24"]))
        assert [i for i, e in enumerate(enabled) if e] == ref["laser_targets_used_16_indices"]


def test_boxes_are_closed_with_outward_normals():
    b = scenes.box("b", (0, 0, 0), (1, 2, 3), 0.5)
    import trimesh

    m = trimesh.Trimesh(b.vertices, b.faces, process=False)
    assert m.is_watertight and m.volume == pytest.approx(6.0)    # positive volume: normals point out


def test_cave_room_and_chair_in_the_papers_place():
    ex = scenes.cave_chair()
    mesh, albedo = ex.trimesh()
    assert len(albedo) == len(mesh.faces)
    lo, hi = mesh.bounds
    assert np.allclose(lo, [-2.02, 0.0, -2.02]) and np.allclose(hi, [2.02, 4.02, 2.02])
    chair = [p for p in ex.parts if p.name.startswith("chair")]
    pts = np.concatenate([p.vertices for p in chair])
    assert pts[:, 2].min() == pytest.approx(-2.0)                 # stands on the floor
    assert np.allclose(pts[:, :2].mean(0), [0.0, 3.0], atol=0.05)  # paper (0, -2, 3) -> Blender (0, 3, -2)
    assert 0.9 < np.ptp(pts[:, 2]) < 1.1 and len([p for p in chair if "leg" in p.name]) == 4
    # the sensor: origin, looking along +Y, up +Z
    c2w = ex.camera_to_world
    assert np.allclose(c2w[:3, 3], 0) and np.allclose(-c2w[:3, 2], [0, 1, 0]) and np.allclose(c2w[:3, 1], [0, 0, 1])


def test_curved_wall_faces_the_room():
    w = scenes.curved_wall()
    import trimesh

    m = trimesh.Trimesh(w.vertices, w.faces, process=False)
    assert np.all(m.face_normals[:, 1] < 0)                       # towards the sensor side (-Y)
    assert m.bounds[1, 1] == pytest.approx(4.0)


def test_every_example_and_unknown_name():
    for name in scenes.EXAMPLES:
        ex = scenes.example(name)
        extra = len(scenes.OUTSIDE_FOV_TARGETS) if name == "outside-fov" else 0   # its out-of-view spots
        assert ex.parts and len(ex.spot_targets) == 24 + extra
        assert len(ex.spot_enabled) == len(ex.spot_targets) and sum(ex.spot_enabled) == 16
        if ex.has_exact_mesh:
            assert len(ex.trimesh()[0].faces) > 0
        else:
            with pytest.raises(ValueError):
                ex.triangles()
    assert scenes.ambient().lights and scenes.ambient().config_overrides["ambient_per_bin"] > 0
    with pytest.raises(KeyError):
        scenes.example("nope")


@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("size", [(64, 32), (32, 64)])
def test_camera_fov_matches_blenders_view_frame(fit, size):
    """The field of view we record is the one Cycles renders (checked against view_frame)."""
    import math

    import bpy
    from pipeline.blender_scene import camera_fov

    bpy.ops.wm.read_factory_settings(use_empty=True)
    data = bpy.data.cameras.new("lidar")
    cam = bpy.data.objects.new("lidar", data)
    scene = bpy.context.scene
    scene.collection.objects.link(cam)
    data.sensor_fit = fit
    scene.render.resolution_x, scene.render.resolution_y = size
    corners = [tuple(v) for v in data.view_frame(scene=scene)]
    fov, axis = camera_fov(cam, *size)
    k = 0 if axis == "x" else 1
    expected = 2.0 * math.atan(max(c[k] for c in corners) / -corners[0][2])
    assert fov == pytest.approx(expected, rel=1e-6)
