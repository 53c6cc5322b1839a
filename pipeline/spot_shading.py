"""Two-bounce radiance of sensor samples lit by one laser spot, by deferred Lambertian shading.

The spot-independent Cycles passes (position x, shading normal n_x, diffuse colour rho_x)
already hold everything the light transport of a Lambertian scene needs; per spot only the
visibility of l from each sample is new. It comes from Embree shadow rays against the same
evaluated triangles Cycles renders (blender_scene.world_triangles), so a spot costs about
one ray per facing sample instead of a Cycles render (measured in docs/simulator.md).

    L2(x) = (rho_l / pi) (rho_x / pi) P cos_l cos_x / r^2 * V(x, l)

with r = |x - l|, cos_l = n_l . (x - l) / r, cos_x = n_x . (l - x) / r: the radiance a
Cycles disk emitter of power rho_l P at l gives (cycles_render.py) and torch_recon.contract.analytic's.
Materials with glossy lobes need the Cycles per-spot render instead (setting shading='cycles').
No bpy here: numpy + embreex.
"""

from __future__ import annotations

import math

import numpy as np
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh

from torch_recon.contract.frames import camera_ray_directions

#: offset of shadow-ray ends off the surfaces (m): keeps a sample out of its own shadow test
RAY_EPS_M = 1e-4


class SceneRays:
    """Embree scene of world triangles: first hits and occlusion tests (float32, like Cycles)."""

    def __init__(self, vertices, faces, face_albedo=None, corner_normals=None):
        v = np.asarray(vertices, np.float64)
        f = np.asarray(faces, np.int64)
        self.triangles = v[f].astype(np.float32)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        self.face_normals = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        self.plane_offset = np.einsum("ij,ij->i", v[f[:, 0]], self.face_normals)    # n . x of each face's plane
        self._camera_dirs = (None, None)          # (key, unit directions) of the last range_image size
        self.face_albedo = None if face_albedo is None else np.asarray(face_albedo, np.float64)
        # (T, 3, 3) shading normals at the corners (blender_scene.world_geometry); None: flat faces
        self.corner_normals = None if corner_normals is None else np.asarray(corner_normals, np.float32)
        if self.corner_normals is not None and self.corner_normals.shape != (len(f), 3, 3):
            raise ValueError(f"corner_normals: expected shape {(len(f), 3, 3)}, got {self.corner_normals.shape}")
        self.scene = rtcore_scene.EmbreeScene()
        TriangleMesh(self.scene, self.triangles)

    def first_hits(self, origins, dirs, shading_normals: bool = False):
        """(hit (N,), distance (N,), face (N,)) of rays from origins along unit dirs; with shading_normals
        also the unit normal (N, 3) at each hit: the corner normals interpolated as Cycles does, else the
        face normal (not yet turned towards the ray)."""
        o = np.ascontiguousarray(origins, np.float32)
        d = np.ascontiguousarray(dirs, np.float32)
        if not len(o):
            empty = (np.zeros(0, bool), np.zeros(0), np.zeros(0, np.int64))
            return (*empty, np.zeros((0, 3))) if shading_normals else empty
        res = self.scene.run(o, d, output=1)
        face = np.asarray(res["primID"], np.int64)
        hit = face >= 0
        dist = np.where(hit, np.asarray(res["tfar"], np.float64), np.inf)
        if not shading_normals:
            return hit, dist, face
        fi = np.maximum(face, 0)
        if self.corner_normals is None:
            return hit, dist, face, self.face_normals[fi]
        u = np.asarray(res["u"], np.float64)[:, None]       # Embree: x = (1 - u - v) v0 + u v1 + v v2
        w = np.asarray(res["v"], np.float64)[:, None]
        cn = self.corner_normals[fi].astype(np.float64)
        n = (1.0 - u - w) * cn[:, 0] + u * cn[:, 1] + w * cn[:, 2]
        n_len = np.sqrt(np.einsum("ij,ij->i", n, n))[:, None]      # np.linalg.norm's numbers, 4x faster
        n = np.where(n_len > 1e-12, n / np.maximum(n_len, 1e-30), self.face_normals[fi])
        return hit, dist, face, n

    def range_image(self, c2w, width: int, height: int, fov_rad: float, fov_axis: str = "x") -> np.ndarray:
        """Range along each pixel-centre ray (H, W), inf where nothing is hit: analytic.range_image's
        numbers (rays start RAY_EPS_M ahead; the range is the float64 distance to the hit triangle's
        plane, as trimesh computes it), without trimesh's per-call overhead (ground-truth views)."""
        c2w = np.asarray(c2w, np.float64)
        key = (width, height, fov_rad, fov_axis)
        if self._camera_dirs[0] != key:
            self._camera_dirs = (key, camera_ray_directions(width, height, fov_rad, fov_axis).reshape(-1, 3))
        d = self._camera_dirs[1] @ c2w[:3, :3].T
        c = c2w[:3, 3]
        face = self.scene.run((c + RAY_EPS_M * d).astype(np.float32), d.astype(np.float32))
        out = np.full(len(d), np.inf)
        hit = np.flatnonzero(np.asarray(face) >= 0)
        f = np.asarray(face)[hit]
        n = self.face_normals[f]
        # ray c + t d meets the plane n . x = k at t = (k - n . c) / (n . d)
        out[hit] = (self.plane_offset[f] - n @ c) / np.einsum("ij,ij->i", d[hit], n)
        return out.reshape(height, width)

    def unoccluded(self, a, b) -> np.ndarray:
        """True where the open segment a -> b (N, 3) is free of triangles."""
        a = np.asarray(a, np.float32)
        d = np.asarray(b, np.float32) - a
        length = np.sqrt(np.einsum("ij,ij->i", d, d))
        out = np.ones(len(a), bool)
        ok = length > 2 * RAY_EPS_M
        if not ok.all():
            if not ok.any():
                return out
            a, d, length = a[ok], d[ok], length[ok]
        d /= length[:, None]                     # unit directions, in place
        a = a + np.float32(RAY_EPS_M) * d         # a new array: the caller's a stays as it was
        length -= np.float32(2 * RAY_EPS_M)
        res = self.scene.run(a, d, dists=length, query="OCCLUDED")
        out[ok] = np.asarray(res) != 0          # embreex: 0 occluded, -1 free
        return out


class ShadingSamples:
    """Spot-independent parts of samples: positions, normals turned to the sensor, albedo, |c - x|."""

    def __init__(self, x, n_x, rho_x, sensor_centre):
        c = np.asarray(sensor_centre, np.float64)
        self.x = np.ascontiguousarray(x, np.float32).reshape(-1, 3)
        n = np.asarray(n_x, np.float32).reshape(-1, 3)
        to_c = c.astype(np.float32) - self.x
        back = np.einsum("ij,ij->i", n, to_c) < 0          # two-sided surfaces, as Cycles shades them
        self.n = np.where(back[:, None], -n, n)
        self.rho = np.asarray(rho_x, np.float32).reshape(-1)
        self.to_camera = np.sqrt(np.einsum("ij,ij->i", to_c, to_c))

    FIELDS = ("x", "n", "rho", "to_camera")

    @classmethod
    def _from_fields(cls, fields: dict) -> "ShadingSamples":
        out = cls.__new__(cls)
        out.__dict__.update(fields)
        return out

    def __len__(self) -> int:
        return len(self.rho)

    def take(self, index) -> "ShadingSamples":
        """The samples at `index` (gathered, nothing recomputed)."""
        return self._from_fields({k: getattr(self, k)[index] for k in self.FIELDS})

    @classmethod
    def concatenate(cls, parts) -> "ShadingSamples":
        return cls._from_fields({k: np.concatenate([getattr(p, k) for p in parts]) for k in cls.FIELDS})


def two_bounce_radiance(rays: SceneRays, samples: ShadingSamples, first_bounce, normal_l, rho_l: float,
                        power_w: float, laser_origin):
    """(radiance (N,) float32 towards the sensor, optical path (N,) float64 |l - o| + |x - l| + |c - x|).

    float32 like Cycles' passes: 1e-6 relative on ~10 m paths is ~3e-4 of a 3.84 cm bin.
    """
    l = np.asarray(first_bounce, np.float64)
    n_l = np.asarray(normal_l, np.float32)
    v = l.astype(np.float32) - samples.x
    r = np.sqrt(np.einsum("ij,ij->i", v, v))
    cos_x_r = np.einsum("ij,ij->i", samples.n, v)            # cos_x r and cos_l r: no (N, 3) unit vectors
    cos_l_r = -(v @ n_l)
    idx = np.flatnonzero((r > 1e-6) & (cos_x_r > 0) & (cos_l_r > 0))
    start = samples.n[idx]              # shadow rays start just off the surface, x + eps n (float32)
    start *= np.float32(RAY_EPS_M)
    start += samples.x[idx]
    free = rays.unoccluded(start, (l + RAY_EPS_M * np.asarray(normal_l, np.float64))[None, :])
    idx = idx[free]
    rad = np.zeros(len(r), np.float32)
    k = np.float32((rho_l / math.pi) * power_w / math.pi)
    r_lit = r[idx]
    rad[idx] = k * samples.rho[idx] * cos_x_r[idx] * cos_l_r[idx] / (r_lit * r_lit * r_lit * r_lit)
    path = float(np.linalg.norm(l - np.asarray(laser_origin, np.float64))) + r.astype(np.float64) + samples.to_camera
    return rad, path
