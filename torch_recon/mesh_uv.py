"""UV atlas of an exported mesh (xatlas), in spatial blocks packed into a grid of tiles.

Used by `mesh_export.export_mesh` (skipped with `--no-uv`): Blender's texture painting and baking need UVs.
"""

from __future__ import annotations

import numpy as np


def _split_faces(centroids, idx, max_faces):
    """Recursive median split of faces (by centroid, longest axis) into blocks of <= max_faces."""
    if len(idx) <= max_faces:
        return [idx]
    c = centroids[idx]
    axis = int(np.argmax(c.max(0) - c.min(0)))
    order = idx[np.argsort(c[:, axis], kind="stable")]
    half = len(order) // 2
    return _split_faces(centroids, order[:half], max_faces) + _split_faces(centroids, order[half:], max_faces)


def _atlas(xatlas, positions, indices, tile_texels: int):
    """One block's (vertex map, faces, UVs in [0, 1]) from xatlas, its charts packed into a square of
    about `tile_texels` texels (0: xatlas' own estimate, about 1000 per block here)."""
    atlas = xatlas.Atlas()
    atlas.add_mesh(positions, indices)
    pack = xatlas.PackOptions()
    pack.resolution = int(tile_texels)
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count > 1:       # the charts did not fit one page: let xatlas size it
        atlas = xatlas.Atlas()
        atlas.add_mesh(positions, indices)
        atlas.generate()
    return atlas[0]


def uv_unwrap(mesh, block_faces: int = 2000, tile_texels: int = 256):
    """xatlas parametrisation; returns a new trimesh with per-vertex UVs (vertices split on seams).

    xatlas' time grows faster than linearly with the face count (about 10 s for 40k faces
    and minutes for 200k here), so large meshes are cut into spatial blocks of at most
    `block_faces` faces, each unwrapped on its own and packed into a grid of UV tiles.
    Measured on the 367k-face cave-chair fit (128 px, 2-core EPYC, one process, same load):
    blocks of 10000 / 5000 / 2000 faces took 54 / 35 / 24 s.
    Each block's charts are packed into about `tile_texels` squared texels: packing is half of
    xatlas' time at its own estimate (about 1000 x 1000 per 2000-face block, an atlas of some
    11000 texels across for 128 blocks); 256 halves the time (the charts, seams and vertex splits
    are the same; only where the charts lie in their tile changes).
    """
    import trimesh
    import xatlas
    from tqdm import tqdm

    v = np.asarray(mesh.vertices, np.float64)
    f = np.asarray(mesh.faces, np.int64)
    blocks = _split_faces(v[f].mean(axis=1), np.arange(len(f)), block_faces)
    n = int(np.ceil(np.sqrt(len(blocks))))
    verts, faces, uvs, base = [], [], [], 0
    # a bar once the atlas takes seconds (about 0.1 s per block here)
    for b, fi in enumerate(tqdm(blocks, desc="UV atlas", unit="block", disable=len(blocks) < 16, leave=False)):
        used, local = np.unique(f[fi], return_inverse=True)
        vmap, idx, uv = _atlas(xatlas, v[used].astype(np.float32), local.reshape(-1, 3).astype(np.uint32),
                               tile_texels)
        verts.append(v[used][vmap])
        faces.append(idx.astype(np.int64) + base)
        uvs.append((uv + np.array([b % n, b // n])) / n)   # tile b of an n x n grid
        base += len(vmap)
    return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False,
                           visual=trimesh.visual.TextureVisuals(uv=np.concatenate(uvs)))
