"""Taubin passes of the mesh vertices that no camera ray places (session 17, issue 11).

organic-occluded's blob is a lumpy mass from behind (per-object normal consistency 0.895, the 16 spots' oracle hull
0.962). Measured on main's fit (docs/reconstruction.md "The hidden hull's lumps: where they sit"): 95 % of the blob's
back-facing mesh lies on voxels the start labelled hidden (label 0), but half of those are no longer the saturated
shadow hull (`hull_subvoxel.unmeasured_hull`) at export: training lowered them part-way, or the hull inset did, and
the top's worst facets sit on restored blockers. Smoothing restricted to the saturated hull (session 15's hull
Taubin, an occupancy blur, session 16's lit fans) therefore barely moved the normals. Here every vertex moves except
those the sensor places: on a visible surface's ramp or point voxel (the start field's ramp, evidence labels 1 and
6) or on a thin part, on either side of the surface. Taubin (lambda | mu) keeps the volume; each vertex stays within
`max_move` of where it started and never enters space the sensor saw through (`hull_subvoxel.camera_free`).
"""

from __future__ import annotations

import numpy as np

from .voxel_evidence import NEAREST

#: evidence label of a visible surface point's voxel (`voxel_evidence.evidence_grid`, priority 1)
SURFACE = 1


def camera_placed(model) -> np.ndarray:
    """bool (nx, ny, nz): voxels whose surface the sensor measured (the start field's visible-surface ramp, between its
    free and occupied values, and the voxels holding a visible or nearest surface point), a thin part, or a restored
    blocker (a shadowed segment needs it whole: a chair leg's one-voxel column; moved, cave-chair's hidden R@2cm fell
    0.920 -> 0.907)."""
    fc = model.fc
    start = model._start_raw.cpu()
    label = model.evidence.label.cpu()
    placed = (start > fc.raw_free + 1e-3) & (start < fc.raw_occupied - 1e-3)
    placed |= (label == SURFACE) | (label == NEAREST) | model.evidence.restored.cpu()
    if model.thin_parts is not None:
        placed |= model.thin_parts[0, 0].permute(2, 1, 0).cpu()
    return placed.numpy()


def set_unplaced_smoothing(model, inward, iterations: int, max_move_voxels: float, silhouettes: bool = True) -> None:
    """Fill mesh_export `InwardSmoothing`'s unplaced-vertex Taubin fields from the model's start field; with
    `silhouettes`, vertices beside space the sensor saw through are placed too (a silhouette, placed to a pixel:
    organic-occluded's occluder +x face, as `hull_subvoxel.shrinkable_hull`'s rule)."""
    from .fields import next_to
    from .hull_subvoxel import camera_free

    if iterations <= 0:
        return
    if tuple(model._start_raw.shape) != tuple(model.grid.box.shape):
        raise ValueError("the start field's grid differs from the mesh field's: cannot tell placed vertices")
    seen = camera_free(model, model.grid.box).cpu()
    inward.placed = camera_placed(model)
    if silhouettes:
        inward.placed |= (seen | next_to(seen)).numpy()
    inward.camera_free = seen.numpy()
    inward.unplaced_iterations = int(iterations)
    inward.unplaced_max_move_m = float(max_move_voxels) * float(model.grid.box.voxel)


def unplaced_taubin(mesh, placed: np.ndarray, camera_free: np.ndarray, lo, spacing, iterations: int,
                    max_move: float):
    """Taubin passes (as the exporter's) of `mesh`'s vertices whose grid points half a step inside and outside along
    the normal are both not `placed`, in place; every other vertex pinned. A vertex ends at most `max_move` (m) from
    where it started, and one that ends in a `camera_free` voxel goes back (the sensor saw that space empty)."""
    import trimesh

    from ..mesh_export import nearest_grid_point

    if iterations <= 0 or len(mesh.faces) == 0:
        return mesh
    shape = np.array(placed.shape)
    lo, spacing = np.asarray(lo, np.float64), np.asarray(spacing, np.float64)

    def cell(p):
        return tuple(nearest_grid_point(p, lo, spacing, shape).T)

    v0 = np.asarray(mesh.vertices, np.float64).copy()
    pinned = placed_vertices(mesh, placed, lo, spacing)
    if pinned.all():
        return mesh
    lap = trimesh.smoothing.laplacian_calculation(mesh, pinned_vertices=np.nonzero(pinned)[0])
    trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=int(iterations), laplacian_operator=lap)
    v = np.asarray(mesh.vertices, np.float64)
    move = v - v0
    length = np.linalg.norm(move, axis=1, keepdims=True)
    v = v0 + move * np.minimum(1.0, max_move / np.maximum(length, 1e-12))
    seen = camera_free[cell(v)] & ~camera_free[cell(v0)]
    v[seen] = v0[seen]
    if not np.all(np.isfinite(v)):
        raise ValueError("Taubin passes of the unplaced vertices gave non-finite positions")
    mesh.vertices = v
    return mesh


def placed_vertices(mesh, placed: np.ndarray, lo, spacing) -> np.ndarray:
    """bool (V,): `mesh`'s vertices whose grid point half a step inside or outside along the normal is `placed`."""
    from ..mesh_export import nearest_grid_point

    lo, spacing = np.asarray(lo, np.float64), np.asarray(spacing, np.float64)
    v = np.asarray(mesh.vertices, np.float64)
    n = np.asarray(mesh.vertex_normals, np.float64)
    shape = np.array(placed.shape)
    return (placed[tuple(nearest_grid_point(v - 0.5 * spacing * n, lo, spacing, shape).T)]
            | placed[tuple(nearest_grid_point(v + 0.5 * spacing * n, lo, spacing, shape).T)])
