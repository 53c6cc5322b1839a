"""The hidden hull's faces on a plane bounding the observation go onto that plane (session 19, issue 11).

dark-room's floor behind its box is seen by no camera ray: the shadow hull's boundary puts it, carved by lit segments
that graze whole voxels (docs/reconstruction.md "Grazing lit segments"), so it lies in diagonal furrows 1-2 cm below
the floor the sensor measured in front of the box (and training deepened them). Outside the view the planes that bound
the observation continue (`unobserved.py`); behind an object inside the view the same prior says where such a plane
lies: a mesh vertex no camera ray places (`hull_unplaced.camera_placed`), within `max_m` of a bounding plane and with
its normal within 20 degrees of the plane's, goes onto it along the plane's normal. A table top or a seat is no
bounding plane (the floor lies behind it), and an object's face meets a plane at an angle, so only the room's own
surfaces move. A vertex whose move would fold a face of it over (turn its normal by more than 90 degrees, or make
it zero-area) stays where it is (session 20).
"""

from __future__ import annotations

import numpy as np

from .unobserved import _PlaneModel

#: a vertex's normal within this cosine of a plane's normal faces the way the plane does (the RANSAC inlier test)
NORMAL_COS = _PlaneModel.max_angle_cos
#: passes: a furrow's side faces the plane only once its floor is on it (their normals are computed again each pass)
PASSES = 3
#: a vertex does not move when a face of it would end with its normal at this cosine or less to the normal it had
#: before the snap (0: turned by 90 degrees or more, or collapsed): moving one vertex of a steep face past the
#: others turns the face inside out (a fold the exporter's degenerate-face pass does not remove)
FOLD_COS = 0.0


def set_plane_snap(model, inward, max_voxels: float) -> None:
    """Fill mesh_export `InwardSmoothing`'s plane fields from the fast model's bounding planes (`FastModel.room_planes`,
    the ones the start field and the edge freeze read)."""
    from .hull_unplaced import camera_placed

    box = model.grid.box
    planes = model.room_planes(box) if max_voxels > 0 else []
    if not planes:
        return
    if tuple(model._start_raw.shape) != tuple(box.shape):
        raise ValueError("the start field's grid differs from the mesh field's: cannot tell placed vertices")
    inward.plane_normals = np.stack([p.normal for p in planes]).astype(np.float64)
    inward.plane_offsets = np.array([p.offset for p in planes], np.float64)
    inward.plane_snap_m = float(max_voxels) * float(box.voxel)
    if inward.placed is None:
        inward.placed = camera_placed(model)


def snap_to_planes(mesh, placed: np.ndarray, lo, spacing, normals: np.ndarray, offsets: np.ndarray, max_m: float):
    """In place: `mesh`'s vertices no `placed` voxel pins (`hull_unplaced.placed_vertices`) within `max_m` of a
    plane (n . x = offset, unit `normals` (P, 3) facing free space), their normal within 20 degrees of n, go onto it."""
    from .hull_unplaced import placed_vertices

    if len(mesh.faces) == 0 or len(offsets) == 0:
        return mesh
    free = ~placed_vertices(mesh, placed, lo, spacing)
    start = np.asarray(mesh.vertices, np.float64).copy()
    for _ in range(PASSES):
        v = np.asarray(mesh.vertices, np.float64).copy()
        vn = np.asarray(mesh.vertex_normals, np.float64)
        for n, off in zip(np.asarray(normals, np.float64), np.asarray(offsets, np.float64)):
            d = v @ n - off
            on = free & (np.abs(d) <= max_m) & (vn @ n >= NORMAL_COS)
            v[on] -= d[on, None] * n
        if not np.all(np.isfinite(v)):
            raise ValueError("moving the hull's vertices onto the bounding planes gave non-finite positions")
        mesh.vertices = v
    # the passes' sum is checked (a face one pass tips past 90 degrees the next can right again: cave-chair's four)
    mesh.vertices = _without_folds(v.copy(), start, np.asarray(mesh.faces))
    return mesh


def _face_normals(v: np.ndarray, faces: np.ndarray):
    """(unit normals (F, 3), area > 0 (F,) bool) of the triangles `faces` over the vertices `v`."""
    cross = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    length = np.linalg.norm(cross, axis=1)
    return cross / np.maximum(length, 1e-300)[:, None], length > 0


def _without_folds(v: np.ndarray, start: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """`v` with the moved vertices (v != start) of every face whose normal would end at FOLD_COS or less to its
    normal at `start` (or with no area) put back at `start`, until no face is: each round puts back at least one
    vertex, and a face with all its vertices back is as it was."""
    moved = np.any(v != start, axis=1)
    before, checked = _face_normals(start, faces)           # faces with no area at the start have no normal
    while moved.any():
        normal, has_area = _face_normals(v, faces)
        folded = checked & moved[faces].any(1) & (~has_area | ((normal * before).sum(1) <= FOLD_COS))
        if not folded.any():
            break
        back = np.unique(faces[folded])
        back = back[moved[back]]
        v[back] = start[back]
        moved[back] = False
    return v
