"""The distance queries behind the object metrics: the pruned / bounded ones give what the brute force and the
unbounded search give (surface.within_distance, point_to_mesh_distance's max_m)."""

from __future__ import annotations

import numpy as np
import trimesh

from torch_recon.evaluation.objects import Surface, part_contact
from torch_recon.evaluation.surface import exact_point_to_mesh_distance, within_distance


def _scene():
    """A subdivided room floor plus a chair-like pair of parts, and points at 0-60 cm from them."""
    floor = trimesh.creation.box([3.0, 3.0, 0.02])
    seat = trimesh.creation.box([0.4, 0.4, 0.03]).apply_translation([0.0, 0.0, 0.45])
    leg = trimesh.creation.box([0.03, 0.03, 0.43]).apply_translation([0.15, 0.15, 0.225])
    mesh = trimesh.util.concatenate([floor, seat, leg])
    rng = np.random.default_rng(3)
    base, _ = trimesh.sample.sample_surface(mesh, 3000, seed=1)
    pts = base + rng.normal(size=base.shape) * rng.choice([0.002, 0.01, 0.05, 0.3], size=(len(base), 1))
    return mesh, pts


def test_within_distance_is_the_brute_force_answer():
    mesh, pts = _scene()
    exact = exact_point_to_mesh_distance(pts, mesh)
    for r in (0.001, 0.01, 0.05, 0.2):
        assert np.array_equal(within_distance(pts, mesh, r), exact < r), r


def test_bounded_distance_is_unbounded_up_to_the_bound_and_larger_beyond():
    mesh, pts = _scene()
    surf = Surface(mesh, 20_000, seed=2, max_edge_m=0.1)
    full = surf.distance(pts)
    for bound in (0.01, 0.05, 0.2):
        got = surf.distance(pts, max_m=bound)
        near = full <= bound
        assert near.any() and (~near).any()
        assert np.array_equal(got[near], full[near])
        assert np.all(got[~near] > bound)


def test_part_contact_is_exact_on_large_objects_too():
    """Seat and leg of one object: points where they meet are contact (the old code fell back to an upper bound
    above 50M point-face pairs)."""
    seat = trimesh.creation.box([0.4, 0.4, 0.03]).apply_translation([0.0, 0.0, 0.45])
    leg = trimesh.creation.box([0.03, 0.03, 0.43]).apply_translation([0.15, 0.15, 0.23])    # its top in the seat
    obj = trimesh.util.concatenate([seat, leg])
    obj = Surface(obj, 5000, seed=0, max_edge_m=0.02).mesh
    pts, faces = trimesh.sample.sample_surface(obj, 5000, seed=4)
    got = part_contact(obj, pts, faces, 0.01)
    label = trimesh.graph.connected_component_labels(obj.face_adjacency, node_count=len(obj.faces))
    want = np.zeros(len(pts), bool)
    for part in np.unique(label):
        on = label[faces] == part
        others = obj.submesh([np.flatnonzero(label != part)], append=True)
        want[on] = exact_point_to_mesh_distance(pts[on], others, max_pairs=10**12) < 0.01
    assert got.any() and np.array_equal(got, want)
