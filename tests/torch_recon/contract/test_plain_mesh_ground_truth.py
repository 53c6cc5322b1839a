"""The ground truth's PlainMesh (no trimesh import) gives trimesh's numbers and files (bpy-free, ~1 s).

Each case builds the same mesh both ways (contract.plain_mesh.PlainMesh and trimesh.Trimesh, process=False)
and compares what ground_truth.py / test_views.py / analytic.py read of it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("embreex")
trimesh = pytest.importorskip("trimesh")

from torch_recon.contract import analytic, ground_truth, scenes  # noqa: E402
from torch_recon.contract.frames import look_at_c2w, paper_test_view_cameras  # noqa: E402
from torch_recon.contract.plain_mesh import PlainMesh  # noqa: E402
from torch_recon.contract.test_views import (SceneViewSettings, check_test_views, free_space,  # noqa: E402
                                             scene_test_view_cameras)
from tests.support.example_triangles import example_triangles  # noqa: E402


@pytest.fixture(scope="module")
def cave():
    v, f, owner, names = example_triangles(scenes.cave_chair())
    return PlainMesh(v, f), trimesh.Trimesh(v, f, process=False)


def _ply_body(path):
    data = path.read_bytes()
    head, body = data.split(b"end_header\n", 1)
    return [ln for ln in head.split(b"\n") if not ln.startswith(b"comment")], body


def test_ply_file_and_geometry_equal_trimesh(cave, tmp_path):
    plain, tm = cave
    plain.export(tmp_path / "a.ply", file_type="ply")
    tm.export(str(tmp_path / "b.ply"), file_type="ply")
    assert _ply_body(tmp_path / "a.ply") == _ply_body(tmp_path / "b.ply")
    back = trimesh.load(tmp_path / "a.ply", process=False)
    assert np.array_equal(back.faces, tm.faces) and np.allclose(back.vertices, tm.vertices, atol=1e-6)
    assert np.array_equal(plain.bounds, tm.bounds)
    assert np.allclose(plain.face_normals, tm.face_normals, atol=1e-12)


def test_compact_submesh_equals_remove_unreferenced_vertices():
    v, f, owner, names = example_triangles(scenes.thin_structures())
    sel = owner % 3 == 1                       # faces of every third part: most vertices unused
    ref = trimesh.Trimesh(v, f[sel], process=False).copy()
    ref.remove_unreferenced_vertices()
    got = PlainMesh.compact(v, f[sel])
    assert np.array_equal(got.vertices, ref.vertices) and np.array_equal(got.faces, ref.faces)
    assert np.array_equal(got.bounds, ref.bounds)


def test_first_hits_equal_trimesh_embree(cave):
    plain, tm = cave
    rng = np.random.default_rng(3)
    o = np.array([0.0, 1.0, 0.2]) + rng.uniform(-0.5, 0.5, (2000, 3))
    d = rng.normal(size=(2000, 3))
    loc_a, ray_a, tri_a = plain.ray.intersects_location(o, d, multiple_hits=False)
    loc_b, ray_b, tri_b = tm.ray.intersects_location(o, d, multiple_hits=False)
    order_a, order_b = np.argsort(ray_a), np.argsort(ray_b)
    assert np.array_equal(ray_a[order_a], ray_b[order_b])
    same_face = tri_a[order_a] == tri_b[order_b]
    assert same_face.mean() > 0.999           # an edge hit may pick the neighbour face (float32 scaling)
    assert np.abs(loc_a[order_a] - loc_b[order_b])[same_face].max() < 1e-6
    # the analytic renderer's range images through either mesh
    c2w = look_at_c2w([0.0, -1.0, 0.3], [0.0, 2.0, 0.0])
    ra = analytic.range_image(plain, c2w, 32, 24, math.pi / 2)
    rb = analytic.range_image(tm, c2w, 32, 24, math.pi / 2)
    assert np.array_equal(np.isfinite(ra), np.isfinite(rb))
    assert np.abs(ra - rb)[np.isfinite(ra)].max() < 1e-6


def test_test_view_placement_equals_trimesh():
    ex = scenes.thin_structures()
    v, f, owner, names = tri = example_triangles(ex)
    objects = ground_truth.object_meshes(*tri, labelled=ex.objects)
    room = ground_truth.room_mesh(tri, objects)
    tm_objects = [trimesh.Trimesh(m.vertices, m.faces, process=False) for m, _ in objects.values()]
    tm_room = trimesh.Trimesh(room.vertices, room.faces, process=False)
    sensor = look_at_c2w([0.0, 0.0, 0.0], [0.0, 3.0, 0.0])
    s = SceneViewSettings(dolly=10, orbit=30)
    cams_a, rep_a = scene_test_view_cameras(PlainMesh(v, f), [m for m, _ in objects.values()], sensor, s,
                                            room_mesh=room, warn=False)
    cams_b, rep_b = scene_test_view_cameras(trimesh.Trimesh(v, f, process=False), tm_objects, sensor, s,
                                            room_mesh=tm_room, warn=False)
    assert np.allclose(cams_a, cams_b, atol=1e-9) and rep_a["n_invalid"] == rep_b["n_invalid"]
    assert rep_a["orbit_radius_m"] == pytest.approx(rep_b["orbit_radius_m"], abs=1e-6)
    origins = np.concatenate([cams_a[:, :3, 3], [[0.0, 3.0, -1.99], [0.0, 3.0, 5.0]]])   # on the floor, outside
    ok_a, why_a = free_space(PlainMesh(v, f), origins)
    ok_b, why_b = free_space(trimesh.Trimesh(v, f, process=False), origins)
    assert np.array_equal(ok_a, ok_b) and not ok_a[-2:].any()


def test_paper_views_checked_alike(cave):
    plain, tm = cave
    cams = paper_test_view_cameras(dolly_count=39, orbit_count=100)
    va, _ = check_test_views(plain, cams, warn=False)
    vb, _ = check_test_views(tm, cams, warn=False)
    assert np.array_equal(va, vb)
