"""The cleanup every exported mesh gets (`mesh_export.mesh_from_volume`, every method): small islands dropped,
micrometre-close vertices merged, zero-area faces dropped."""

from __future__ import annotations

import numpy as np

#: vertices closer than this are one (m): marching cubes puts three vertices within micrometres where the field
#: crosses the level at a voxel corner, and that sliver's area rounds to zero in the file's float32 coordinates
MERGE_DISTANCE_M = 1e-5


def drop_small_islands(mesh, min_fraction: float, keep_near=None) -> int:
    """In place: drop the islands (faces connected through shared edges) with fewer than `min_fraction` of the
    largest one's faces, except those with a vertex within radius of one of `keep_near`'s points ((points (N, 3),
    radius_m) or None); returns how many were dropped."""
    import trimesh

    if min_fraction <= 0 or len(mesh.faces) == 0:
        return 0
    # labelled in one pass (as mesh.split): split builds a Trimesh per island, minutes for the thousands of specks
    # of an early field on a busy machine
    label = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(mesh.faces))
    size = np.bincount(label)
    small = size < min_fraction * size.max()
    if keep_near is not None and len(keep_near[0]) and small.any():
        from scipy.spatial import cKDTree
        near = np.isfinite(cKDTree(np.asarray(keep_near[0], np.float64)).query(
            mesh.vertices, distance_upper_bound=float(keep_near[1]))[0])
        touched = np.zeros(len(size), bool)
        touched[label[near[mesh.faces].any(1)]] = True
        small &= ~touched
    removed = int(small.sum())
    if removed:
        mesh.update_faces(~small[label])
        mesh.remove_unreferenced_vertices()
    return removed


def without_degenerate(mesh):
    """Merge vertices closer than MERGE_DISTANCE_M, drop zero-area faces (e.g. collapsed by the clamp onto the box)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    mesh.merge_vertices()
    pairs = cKDTree(np.asarray(mesh.vertices)).query_pairs(MERGE_DISTANCE_M, output_type="ndarray")
    if len(pairs):
        n = len(mesh.vertices)
        _, group = connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n)),
                                        directed=False)
        first = np.full(group.max() + 1, n)
        np.minimum.at(first, group, np.arange(n))          # each group's first vertex stands for it
        faces = first[group][np.asarray(mesh.faces)]
        mesh.faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
        mesh.update_faces(mesh.unique_faces())      # two faces the merge made one
    mesh.update_faces(mesh.nondegenerate_faces(height=1e-9))
    mesh.remove_unreferenced_vertices()
    return mesh
