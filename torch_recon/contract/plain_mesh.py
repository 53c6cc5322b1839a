"""A triangle mesh as plain arrays: the part of trimesh.Trimesh that writing the ground truth uses.

Why not trimesh here: `import trimesh` (networkx, scipy.spatial, scipy.optimize) costs about 1 s of CPU,
a third of a 128 x 128 simulation's fixed cost (docs/simulator.md). The ground truth needs only the
vertices and faces as rendered, bounds, face normals, first-hit ray casts (Embree, as trimesh uses) and a
binary PLY file, so the simulator's ground truth goes through this class. Everything that takes a mesh
in ground_truth.py, test_views.py and analytic.py accepts a PlainMesh or a trimesh.Trimesh alike (the
same attribute names and numbers); PLY files hold the same bytes after the header as trimesh's export.
No bpy, no torch: numpy, and embreex when a ray is cast.
"""

from __future__ import annotations

import numpy as np


class PlainMesh:
    """Vertices (V, 3) float64 and faces (F, 3) int64, not merged or repaired."""

    def __init__(self, vertices, faces):
        self.vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
        self.faces = np.asarray(faces, np.int64).reshape(-1, 3)
        self._face_normals = None
        self._ray = None

    @classmethod
    def compact(cls, vertices, faces) -> "PlainMesh":
        """The mesh of `faces` with only the vertices they use, in their original order (as trimesh's
        remove_unreferenced_vertices keeps them)."""
        vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
        faces = np.asarray(faces, np.int64).reshape(-1, 3)
        used = np.zeros(len(vertices), bool)
        used[faces] = True
        new_index = np.cumsum(used) - 1
        return cls(vertices[used], new_index[faces])

    @property
    def triangles(self) -> np.ndarray:
        return self.vertices[self.faces]

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3): min and max corner of the vertices the faces use."""
        if not len(self.faces):
            return None
        used = self.vertices[np.unique(self.faces)]
        return np.stack([used.min(axis=0), used.max(axis=0)])

    @property
    def face_normals(self) -> np.ndarray:
        """Unit normals by the right-hand rule (v1 - v0) x (v2 - v0); zero for degenerate faces."""
        if self._face_normals is None:
            t = self.triangles
            n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
            length = np.linalg.norm(n, axis=1, keepdims=True)
            self._face_normals = np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)
        return self._face_normals

    @property
    def ray(self) -> "EmbreeFirstHits":
        if self._ray is None:
            self._ray = EmbreeFirstHits(self)
        return self._ray

    def export(self, path, file_type: str = "ply") -> None:
        if file_type != "ply":
            raise ValueError(f"PlainMesh writes PLY only, not {file_type!r}")
        write_ply(path, self.vertices, self.faces)


class EmbreeFirstHits:
    """First hits of rays on a PlainMesh (Embree in float32, the hit point on the hit face's plane in
    float64, as trimesh's Embree intersector computes it): trimesh's `mesh.ray.intersects_location`."""

    def __init__(self, mesh: PlainMesh):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.mesh = mesh
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, mesh.triangles.astype(np.float32))

    def intersects_location(self, ray_origins, ray_directions, multiple_hits: bool = True):
        """(locations (M, 3), ray index (M,), face index (M,)) of each ray's first hit (first hits only)."""
        if multiple_hits:
            raise NotImplementedError("PlainMesh casts first hits only (multiple_hits=False)")
        o = np.asarray(ray_origins, np.float64).reshape(-1, 3)
        d = np.asarray(ray_directions, np.float64).reshape(-1, 3)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        if not len(o):
            return np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64)
        face = np.asarray(self.scene.run(o.astype(np.float32), d.astype(np.float32)), np.int64)
        ray = np.flatnonzero(face >= 0)
        face = face[ray]
        n = self.mesh.face_normals[face]
        p0 = self.mesh.vertices[self.mesh.faces[face, 0]]
        dn = np.einsum("ij,ij->i", d[ray], n)
        ok = np.abs(dn) > 1e-12            # a ray along the face's plane has no single hit point
        ray, face, n, p0, dn = ray[ok], face[ok], n[ok], p0[ok], dn[ok]
        t = np.einsum("ij,ij->i", p0 - o[ray], n) / dn
        return o[ray] + t[:, None] * d[ray], ray, face


def write_ply(path, vertices, faces) -> None:
    """Binary little-endian PLY: float32 x, y, z per vertex, uchar count + int32 indices per face (the layout
    of trimesh's PLY export, which Blender, trimesh and MeshLab read)."""
    v = np.asarray(vertices, "<f4").reshape(-1, 3)
    f = np.asarray(faces).reshape(-1, 3)
    header = ("ply\nformat binary_little_endian 1.0\ncomment platolidar ground truth (world frame, metres)\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
    rows = np.zeros(len(f), dtype=[("count", "u1"), ("index", "<i4", (3,))])
    rows["count"] = 3
    rows["index"] = f
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(v.tobytes())
        fh.write(rows.tobytes())
