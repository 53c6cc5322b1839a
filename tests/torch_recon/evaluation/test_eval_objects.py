"""Object metrics against hand-made reconstructions with known answers (torch_recon.evaluation.objects)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from torch_recon.contract.dataset import SensorSpec
from torch_recon.evaluation.objects import ObjectMetricSettings, degenerate_face_count, object_surface_metrics
from torch_recon.contract.frames import look_at_c2w

S = ObjectMetricSettings(thresholds_m=(0.005, 0.01, 0.02, 0.05), gt_samples_per_object=8000,
                         recon_samples_per_m2=20_000, scene_samples=30_000)


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return trimesh.creation.box(extents=hi - lo, transform=trimesh.transformations.translation_matrix((lo + hi) / 2))


def _scene():
    """A floor slab and a back wall (the room) and a 0.5 m box standing on the floor (the object)."""
    room = trimesh.util.concatenate([_box((-1, 0, -0.02), (1, 2, 0.0)), _box((-1, 2, 0.0), (1, 2.02, 1.0))])
    obj = _box((-0.25, 0.75, 0.0), (0.25, 1.25, 0.5))
    gt = trimesh.util.concatenate([room, obj])
    sensor = SensorSpec(width=64, height=64, camera_to_world=look_at_c2w((0, -2, 0.8), (0, 1, 0.25)).tolist())
    return gt, room, obj, sensor


def test_exact_copy_scores_perfectly():
    gt, room, obj, sensor = _scene()
    r = object_surface_metrics(gt.copy(), gt, [("box", obj)], sensor, S)
    o = r["objects"]["box"]
    # distances are exact to within the candidate-face search (a few samples at edges may miss by mm)
    assert o["fscore@0.5cm"] > 0.999 and o["recall_hidden@0.5cm"] > 0.999 and o["recall_visible@0.5cm"] > 0.999
    assert o["fscore@2cm"] == 1.0 and o["chamfer_m"] < 1e-4 and o["spurious_fraction"] == 0.0
    # the bottom face (area 0.25 of 1.5) lies on the floor: contact, left out
    assert o["n_contact_points"] / (o["n_contact_points"] + o["n_gt_points"]) == pytest.approx(0.25 / 1.5, abs=0.02)
    # the sensor sees the front and top faces (0.5 of the 1.25 m^2 scored) of the box
    assert o["visible_share"] == pytest.approx(0.5 / 1.25, abs=0.03)
    assert r["scene"]["spurious_fraction"] == 0.0 and r["scene"]["degenerate_faces"] == 0
    assert r["scene"]["normal_consistency"] > 0.99 and o["normal_consistency"] > 0.99


def test_lumpy_copy_close_in_distance_but_not_in_normals():
    """A copy of the box with seeded bumps (vertices moved up to 8 mm along their normals, 2 cm apart) is within 2 cm
    everywhere, so the distance metrics call it near perfect; its normals are not (the lumpy blob a user sees)."""
    gt, room, obj, sensor = _scene()
    v, f = trimesh.remesh.subdivide_to_size(obj.vertices, obj.faces, max_edge=0.02)
    lumpy = trimesh.Trimesh(v, f, process=True)
    rng = np.random.default_rng(0)
    lumpy.vertices = lumpy.vertices + rng.uniform(-0.008, 0.008, (len(lumpy.vertices), 1)) * lumpy.vertex_normals
    r = object_surface_metrics(trimesh.util.concatenate([room, lumpy]), gt, [("box", obj)], sensor, S)
    o = r["objects"]["box"]
    assert o["fscore@2cm"] > 0.97
    assert o["normal_consistency"] < 0.9
    assert r["summary"]["normal_consistency"] == o["normal_consistency"]


def test_copy_shifted_by_one_cm():
    gt, room, obj, sensor = _scene()
    shift = np.array([1.0, 1.0, 1.0]) / math.sqrt(3) * 0.01       # every face lies 5.77 mm from its original
    moved = obj.copy()
    moved.apply_translation(shift)
    r = object_surface_metrics(trimesh.util.concatenate([room, moved]), gt, [("box", obj)], sensor, S)
    o = r["objects"]["box"]
    # faces 5.77 mm off their originals; near the edges points find a nearer face of the other box (lower)
    assert 0.8 * 0.01 / math.sqrt(3) < o["chamfer_m"] < 1.02 * 0.01 / math.sqrt(3)
    assert o["fscore@0.5cm"] < 0.05
    assert o["fscore@1cm"] > 0.97 and o["fscore@2cm"] == 1.0 and o["fscore@5cm"] == 1.0
    assert r["scene"]["spurious_fraction"] == 0.0


def test_missing_hidden_half():
    gt, room, obj, sensor = _scene()
    c = np.asarray(sensor.camera_to_world)[:3, 3]
    facing = np.einsum("ij,ij->i", obj.face_normals, c - obj.triangles_center) > 0
    front = obj.submesh([np.flatnonzero(facing)], append=True)     # what the sensor sees: front and top
    r = object_surface_metrics(trimesh.util.concatenate([room, front]), gt, [("box", obj)], sensor, S)
    o = r["objects"]["box"]
    assert o["recall_visible@2cm"] > 0.99
    # hidden faces count as found only in the strips within tau of a visible face's edge (5 edges of 0.5 m)
    assert o["recall_hidden@0.5cm"] < 0.03
    assert o["recall_hidden@2cm"] == pytest.approx(5 * 0.5 * 0.02 / 0.75, abs=0.03)
    # visible 0.5 of 1.25 m^2, plus those edge strips, plus the sides' 1-2 cm band above the floor (2 m long)
    assert o["recall@2cm"] == pytest.approx((0.5 + 5 * 0.5 * 0.02 + 2.0 * 0.01) / 1.25, abs=0.03)
    assert o["precision@2cm"] == 1.0 and o["spurious_fraction"] == 0.0


def test_spikes_are_spurious_and_degenerate_faces_counted():
    gt, room, obj, sensor = _scene()
    rng = np.random.default_rng(0)
    h, b, spikes = 0.2, 0.02, []
    for x, y in rng.uniform((-0.9, 0.1), (0.9, 1.9), (20, 2)):    # vertical triangles standing on the floor
        spikes.append([[x - b / 2, y, 0.0], [x + b / 2, y, 0.0], [x, y, h]])
    for x in (-0.1, 0.0, 0.1):                                         # spikes on the box's top, inside its region
        spikes.append([[x - b / 2, 1.0, 0.5], [x + b / 2, 1.0, 0.5], [x, 1.0, 0.5 + h]])
    sp = np.asarray(spikes)
    sp_mesh = trimesh.Trimesh(sp.reshape(-1, 3), np.arange(len(sp) * 3).reshape(-1, 3), process=False)
    zero = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]] * 5, process=False)  # collinear
    rec = trimesh.util.concatenate([gt, sp_mesh, zero])
    area_sp = len(sp) * 0.5 * b * h
    expected = area_sp * ((h - S.spurious_m) / h) ** 2 / rec.area      # the part of each spike above 2 cm
    r = object_surface_metrics(rec, gt, [("box", obj)], sensor, S)
    assert r["scene"]["degenerate_faces"] == 5 == degenerate_face_count(rec)
    assert r["scene"]["spurious_fraction"] == pytest.approx(expected, rel=0.25)
    o = r["objects"]["box"]
    assert 0 < o["spurious_fraction"] < 0.1 and o["precision@2cm"] < 1.0 and o["recall@0.5cm"] == 1.0


def test_empty_reconstruction():
    gt, room, obj, sensor = _scene()
    r = object_surface_metrics(trimesh.Trimesh(), gt, [("box", obj)], sensor, S)
    o = r["objects"]["box"]
    assert o["fscore@5cm"] == 0.0 and o["recall_hidden@5cm"] == 0.0 and o["chamfer_m"] is None


def test_a_dent_in_a_wall_is_room_surface_off_by_more_than_5mm():
    """A 1.2 cm dent 10 cm across in the back wall, far from the box: inside the 2 cm spurious threshold, so only
    the room's flatness sees it (the dents training made at every laser spot, session 18)."""
    gt, room, obj, sensor = _scene()
    exact = object_surface_metrics(gt.copy(), gt, [("box", obj)], sensor, S)["scene"]
    assert exact["room_off_surface_fraction"] == 0.0 and exact["room_off_surface_exact"]
    wall = _box((-1, 2, 0.0), (1, 2.02, 1.0))
    v, f = trimesh.remesh.subdivide_to_size(wall.vertices, wall.faces, max_edge=0.01)
    dented = trimesh.Trimesh(v, f, process=True)
    v = dented.vertices.copy()
    disc = (np.hypot(v[:, 0] - 0.6, v[:, 2] - 0.7) < 0.05) & (v[:, 1] < 2.001)     # the wall's front face only
    v[disc, 1] += 0.012
    dented.vertices = v
    rec = trimesh.util.concatenate([_box((-1, 0, -0.02), (1, 2, 0.0)), dented, obj])
    scene = object_surface_metrics(rec, gt, [("box", obj)], sensor, S)["scene"]
    lo, hi = np.asarray(obj.bounds[0]) - S.region_margin_m, np.asarray(obj.bounds[1]) + S.region_margin_m
    pts, _ = trimesh.sample.sample_surface(rec, 200_000, seed=1)
    outside = ~np.all((pts >= lo) & (pts <= hi), axis=1)
    expected = math.pi * 0.05 ** 2 / (rec.area * outside.mean())       # the dent's floor over the room's area
    assert scene["room_off_surface_fraction"] == pytest.approx(expected, rel=0.5)
    assert scene["spurious_fraction"] == 0.0                            # 1.2 cm: not spurious at 2 cm


def test_faces_where_an_object_s_parts_meet_are_contact():
    """Two boxes stacked as one object (a backrest on a seat): the lower one's top and the upper one's bottom meet
    inside the solid; like the bottom on the floor they are contact points, left out of recall."""
    gt, room, obj, sensor = _scene()
    lower, upper = _box((-0.25, 0.75, 0.0), (0.25, 1.25, 0.25)), _box((-0.25, 0.75, 0.25), (0.25, 1.25, 0.5))
    stacked = trimesh.util.concatenate([lower, upper])         # two parts (connected components), 2.0 m^2
    gt = trimesh.util.concatenate([room, stacked])
    o = object_surface_metrics(gt.copy(), gt, [("stack", stacked)], sensor, S)["objects"]["stack"]
    share = o["n_contact_points"] / (o["n_contact_points"] + o["n_gt_points"])
    # the floor contact, the two faces that meet, 1 cm strips of the sides at the floor and at the joint
    assert share == pytest.approx((0.25 + 0.25 + 0.25 + 0.02 + 0.04) / 2.0, abs=0.02)
    assert o["recall_hidden@0.5cm"] > 0.999
