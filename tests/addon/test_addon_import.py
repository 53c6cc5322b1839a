"""Import: meshes land in place in the 'Reconstruction' collection; error colours; visible-depth points."""

import json

import bpy
import numpy as np
import pytest
import trimesh

from tests.support.addon_fixtures import blank, call, expect_error  # noqa: F401 (fixtures)

from addon import importing


def _bbox_world(obj):
    m = np.array(obj.matrix_world)
    co = np.array([tuple(v.co) for v in obj.data.vertices])
    co = co @ m[:3, :3].T + m[:3, 3]
    return co.min(0), co.max(0)


def _box(centre, extents):
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def test_ply_lands_in_place(blank, tmp_path):
    src = _box((1.5, -2.0, 0.75), (0.4, 0.6, 1.5))
    path = tmp_path / "recon.ply"
    src.export(path)
    blank.platolidar.import_path = str(path)
    res, err = call(bpy.ops.platolidar.import_reconstruction)
    assert err is None and res == {"FINISHED"}
    coll = bpy.data.collections[importing.COLLECTION_NAME]
    assert coll.name in blank.collection.children
    (obj,) = coll.objects
    assert len(obj.users_collection) == 1
    lo, hi = _bbox_world(obj)
    np.testing.assert_allclose(lo, src.bounds[0], atol=1e-5)
    np.testing.assert_allclose(hi, src.bounds[1], atol=1e-5)


@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_meshes_from_torch_recon_writer_land_in_place(blank, tmp_path, suffix):
    """The reconstructor's writer (torch_recon.mesh_export): .obj is a Y-up file, .ply world Z-up."""
    mesh_export = pytest.importorskip("torch_recon.mesh_export")
    src = _box((0.3, 2.0, 1.2), (0.5, 0.2, 0.8))
    path = mesh_export.write_mesh(src, tmp_path / f"m{suffix}")
    blank.platolidar.import_path = str(path)
    res, err = call(bpy.ops.platolidar.import_reconstruction)
    assert err is None
    (obj,) = bpy.data.collections[importing.COLLECTION_NAME].objects
    lo, hi = _bbox_world(obj)
    np.testing.assert_allclose(lo, src.bounds[0], atol=1e-5)
    np.testing.assert_allclose(hi, src.bounds[1], atol=1e-5)


def test_colour_by_error_against_ground_truth(blank, tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    gt = trimesh.Trimesh(vertices=[[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], faces=[[0, 1, 2], [0, 2, 3]])
    gt.export(ds / "gt.ply")
    (ds / "dataset.json").write_text(json.dumps({"ground_truth": {"mesh_file": "gt.ply"}}))
    _box((0.0, 0.0, 0.3), (1.0, 1.0, 0.2)).export(tmp_path / "recon.ply")  # vertices at z = 0.2 and 0.4
    s = blank.platolidar
    s.import_path, s.recon_dataset_dir, s.import_color_error = str(tmp_path / "recon.ply"), str(ds), True
    res, err = call(bpy.ops.platolidar.import_reconstruction)
    assert err is None
    (obj,) = bpy.data.collections[importing.COLLECTION_NAME].objects  # the GT was imported only temporarily
    me = obj.data
    err_m = np.array([d.value for d in me.attributes[importing.ERROR_ATTRIBUTE].data])
    z = np.array([v.co.z for v in me.vertices])
    np.testing.assert_allclose(err_m, z, atol=1e-5)
    assert me.color_attributes.active_color.name == importing.ERROR_COLOUR
    assert "gt" not in bpy.data.meshes


def test_import_bad_states(blank, tmp_path):
    s = blank.platolidar
    expect_error(bpy.ops.platolidar.import_reconstruction, "no mesh file")
    s.import_path = str(tmp_path / "missing.ply")
    expect_error(bpy.ops.platolidar.import_reconstruction, "does not exist")
    (tmp_path / "notes.txt").write_text("hello")
    s.import_path = str(tmp_path / "notes.txt")
    expect_error(bpy.ops.platolidar.import_reconstruction, "expected a .ply")
    (tmp_path / "broken.ply").write_text("not a ply at all")
    s.import_path = str(tmp_path / "broken.ply")
    expect_error(bpy.ops.platolidar.import_reconstruction, "broken.ply")
    _box((0, 0, 0), (1, 1, 1)).export(tmp_path / "ok.ply")
    s.import_path, s.import_color_error, s.recon_dataset_dir = str(tmp_path / "ok.ply"), True, str(tmp_path)
    expect_error(bpy.ops.platolidar.import_reconstruction, "ground-truth mesh")
    assert importing.COLLECTION_NAME not in bpy.data.collections or \
        not bpy.data.collections[importing.COLLECTION_NAME].objects  # nothing half-imported


def _measurements(path, with_depth=True):
    from torch_recon.contract.frames import look_at_c2w, pixel_rays
    from torch_recon.measurements import Measurements
    w, h, fov = 6, 4, np.radians(60.0)
    c2w = look_at_c2w([0.0, 0.0, 1.0], [0.0, 3.0, 1.0])
    _, dirs = pixel_rays(c2w, w, h, fov, "x")
    depth = (3.0 / dirs[..., 1]).astype(np.float32)  # range to the wall y = 3
    depth[0, 0] = np.nan  # one unknown pixel
    m = Measurements(width=w, height=h, fov_rad=float(fov), fov_axis="x", camera_to_world=c2w,
                     laser_origin=np.array([0.0, 0.0, 1.0]), bin_width_m=0.0384, shadow_threshold=0.15,
                     visible_depth=depth if with_depth else None,
                     visible_confidence=np.ones((h, w), np.float32) if with_depth else None)
    return m.save(path)


def test_visible_depth_points(blank, tmp_path):
    blank.platolidar.measurements_path = str(_measurements(tmp_path / "m.npz"))
    res, err = call(bpy.ops.platolidar.import_visible_depth)
    assert err is None
    obj = bpy.data.collections[importing.COLLECTION_NAME].objects[importing.POINTS_NAME]
    co = np.array([tuple(v.co) for v in obj.data.vertices])
    assert co.shape == (23, 3)
    np.testing.assert_allclose(co[:, 1], 3.0, atol=1e-5)
    assert obj.modifiers[0].type == "NODES"


def test_visible_depth_bad_states(blank, tmp_path):
    s = blank.platolidar
    s.measurements_path = str(tmp_path / "none.npz")
    expect_error(bpy.ops.platolidar.import_visible_depth, "does not exist")
    s.measurements_path = str(_measurements(tmp_path / "nodepth.npz", with_depth=False))
    expect_error(bpy.ops.platolidar.import_visible_depth, "no visible depth")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    s.measurements_path = str(tmp_path / "junk.npz")
    expect_error(bpy.ops.platolidar.import_visible_depth, "not a measurements file")
