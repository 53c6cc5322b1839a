"""Holes in the exported mesh that nothing measured explains, closed where their cause is known (session 19), and
the pin-holes' rims held in place by the smoothing.

The mending (`sealed_shell`, `small_gaps`) is the fast mode's export heuristic: `mesh_export.mesh_from_volume` runs
it only with `mend_gaps` (the method table's `mends_mesh_gaps`, contract/methods.py), so BF Lidar's mesh, PlatoNeRF's
and `evaluate`'s density mesh stay plain marching cubes (session 20).

- `small_gaps`: pin-holes left by the free-space face filter (`mesh_export._faces_facing_free`): a few faces whose
  probes fell between the voxels and pixel rays that measured free space, enclosed by kept faces.
- `sealed_shell`: holes through a wall that lies within the box's margin: a carved voxel column reaches the box's
  face, and the box's empty padding (marching cubes' closure) leaves it open.
Measured in docs/reconstruction.md ("Holes in the mesh").
"""

from __future__ import annotations

import numpy as np

#: a dropped patch is closed when its faces' normals stay within this cosine of the mean normal of the kept faces
#: around it (0.5 or none: organic-occluded's obj-region spurious +0.2 / +0.6 points), or when it has at most
#: GAP_ANY_FACES faces (a thin part's pin-hole, whose rim has no one normal). 4 closed the chair seat's pin-holes
#: too but lost hidden R@2cm 0.004 on thin-structures and curved-wall (their rims, no longer pinned, are smoothed)
GAP_MIN_COS = 0.7
GAP_ANY_FACES = 0
#: a gap in the kept surface whose rim has at most this many edges is a pin-hole (closed by `small_gaps`; its rim is
#: not smoothed, `small_gap_rims`)
PIN_GAP_EDGES = 48
#: an empty patch of the volume's outer layer of voxels of at most this many voxels is a hole's mouth (`sealed_shell`)
SEALED_PATCH_VOXELS = 48


def sealed_shell(v, level: float) -> np.ndarray:
    """`v` with the small empty patches of its outer layer of voxels made occupied. The walls sit a voxel inside
    the box, so a column carved through a wall or floor (the room's edges where the view's corner rays meet them,
    a floor voxel under an object) reaches the box's face; the box's empty padding then left it open and the mesh
    had a hole through the wall. Occupied, the patch closes it half a voxel inside the box, behind the wall's
    surface. Large empty patches (the box cutting through free space, e.g. beside the sensor) stay as they are."""
    from scipy import ndimage

    shell = np.zeros(v.shape, bool)
    shell[[0, -1]] = shell[:, [0, -1]] = shell[:, :, [0, -1]] = True
    patch, count = ndimage.label(shell & (v < level))       # face-connected, across the box's edges too
    if count == 0:
        return v
    size = np.bincount(patch.ravel(), minlength=count + 1)
    small = (size <= SEALED_PATCH_VOXELS) & (np.arange(count + 1) > 0)
    if not small.any():
        return v
    out = v.copy()
    out[small[patch]] = max(float(v.max()), level + 1.0)
    return out


def small_gaps(mesh, keep, max_edges: int) -> np.ndarray:
    """Faces (bool mask) of the dropped patches that kept faces enclose with a rim of at most `max_edges` edges
    and that are no larger than a square with that rim: pin-holes, where the probes in front of a few faces fell
    between the voxels and pixel rays that measured free space although every face around them faces it."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    gap = np.zeros(len(keep), bool)
    dropped = ~keep
    if not dropped.any() or keep.all():
        return gap
    pairs = np.asarray(mesh.face_adjacency)
    inner = dropped[pairs[:, 0]] & dropped[pairs[:, 1]]
    n = len(keep)
    graph = coo_matrix((np.ones(int(inner.sum())), (pairs[inner, 0], pairs[inner, 1])), shape=(n, n))
    _, patch = connected_components(graph, directed=False)
    rim = pairs[dropped[pairs[:, 0]] != dropped[pairs[:, 1]]]
    if len(rim) == 0:       # nothing kept beside the dropped faces: no gap to close
        return gap
    inside_rim = dropped[rim[:, 0]]
    rim_patch = patch[np.where(inside_rim, rim[:, 0], rim[:, 1])]
    n_patch = patch.max() + 1
    rim_edges = np.bincount(rim_patch, minlength=n_patch)
    faces = np.bincount(patch[dropped], minlength=n_patch)
    # the kept faces around each patch: their area-weighted mean normal is the surface the gap interrupts
    around = np.where(inside_rim, rim[:, 1], rim[:, 0])
    weighted = mesh.face_normals[around] * mesh.area_faces[around, None]
    normal = np.stack([np.bincount(rim_patch, weighted[:, i], minlength=n_patch) for i in range(3)], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    turn = np.ones(n_patch)
    idx = np.nonzero(dropped)[0]
    np.minimum.at(turn, patch[idx], (mesh.face_normals[idx] * normal[patch[idx]]).sum(1))
    # a patch with no rim edge is a whole dropped surface (e.g. the back of a wall), not a gap; a patch that turns
    # away from the surface around it is a crevice in a hull lump (closing those added surface 2-8 cm off the
    # truth on organic-occluded's floor beside the blob) or a thin part's jagged faces
    small = ((rim_edges > 0) & (rim_edges <= max_edges) & (faces <= max_edges ** 2 // 8)
             & ((turn >= GAP_MIN_COS) | (faces <= GAP_ANY_FACES)))
    gap[dropped] = small[patch[dropped]]
    return gap


def small_gap_rims(mesh, max_edges: int) -> np.ndarray:
    """Vertices on boundary loops of at most `max_edges` edges (the rims of pin-holes)."""
    import trimesh
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    edges = mesh.edges_sorted[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    if len(edges) == 0:
        return np.zeros(0, np.int64)
    n = len(mesh.vertices)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    loop = label[edges[:, 0]]
    small = np.bincount(loop, minlength=label.max() + 1)[loop] <= max_edges
    return np.unique(edges[small])
