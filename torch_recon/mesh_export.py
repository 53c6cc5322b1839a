"""Occupancy/density volume -> mesh file that Blender imports in place, plus a sidecar JSON.

Pipeline: marching cubes (scikit-image; with `mend_gaps`, the fast mode's, small empty patches of the volume's outer
layer sealed, `mesh_gaps`) -> (optional) keep only faces facing measured free space (with `mend_gaps`, and the
pin-holes kept faces enclose, `mesh_gaps`) -> (optional) Taubin smoothing, pin-holes' rims pinned -> drop small
islands, merge micrometre-close vertices, drop zero-area faces (`mesh_clean`) -> UV unwrap (xatlas, `mesh_uv.py`) ->
.ply / .obj / .glb.

Volume convention: `volume[i, j, k]` is the value at the grid point
bbox_min + (i, j, k) * (bbox_max - bbox_min) / (shape - 1), world (Blender, Z-up)
frame; larger values are inside (occupancy probability, density).

Frames on disk, chosen so that Blender's importers with their DEFAULT settings
put the mesh back where it was reconstructed (checked with bpy 5.0.1 in
tests/torch_recon/test_eval_mesh_export.py when bpy is available):
- .ply: Blender world coordinates as they are (the PLY importer's defaults are
  forward Y, up Z: no conversion);
- .glb / .gltf: glTF is Y-up; we write (x, z, -y) and Blender's glTF importer
  converts back (x, -z, y) -> (x, y, z);
- .obj: the OBJ importer's defaults are forward -Z, up Y (a Y-up file), so .obj
  is written Y-up like glTF.
`load_mesh_world` undoes this for any file written here.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from .contract.errors import PlatolidarError
from . import mesh_gaps
from .mesh_clean import drop_small_islands, without_degenerate

#: Blender world (Z-up) -> Y-up file coordinates (glTF / OBJ default import): (x, y, z) -> (x, z, -y)
YUP_FROM_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
Y_UP_SUFFIXES = (".glb", ".gltf", ".obj")
SUPPORTED_SUFFIXES = (".ply", ".glb", ".gltf", ".obj")


class MeshExportError(PlatolidarError, ValueError):
    """The volume or settings cannot give a mesh; says why."""


@dataclass
class ExportResult:
    mesh: object                 # trimesh.Trimesh in the Blender world frame (with UVs when unwrapped)
    paths: list                  # written mesh files
    sidecar: Path
    n_vertices: int
    n_faces: int
    islands_removed: int
    seconds: float


def _as_numpy(volume) -> np.ndarray:
    if hasattr(volume, "detach"):
        volume = volume.detach().cpu().numpy()
    v = np.asarray(volume, dtype=np.float32)
    if v.ndim != 3 or min(v.shape) < 2:
        raise MeshExportError(f"expected a 3-D volume with at least 2 samples per axis, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise MeshExportError(f"volume has {int((~np.isfinite(v)).sum())} NaN or infinite value(s)")
    return v


@dataclass
class InwardSmoothing:
    """The hidden hull's bounded inward smoothing (`inward_smoothing`) on the grid of the exported volume."""

    movable: np.ndarray               # (same shape as the volume) bool: voxels whose mesh vertices may move inward
    max_move_m: float                 # no vertex moves farther than this from where the Taubin passes left it
    iterations: int                   # Laplacian steps
    face_offsets_m: np.ndarray | None = None  # optional (volume shape + (6,)): per voxel and face (-x, +x, -y, +y, -z,
                                      # +z), how far its vertices first move inward along their normal (recon/hull_flat.py)
    occupancy: tuple | None = None    # optional (voxels (K, 3), share (K,)) put in the field first (recon/lit_fans.py)
    unplaced_iterations: int = 0      # > 0: afterwards, Taubin passes of the vertices no camera ray places (recon/
    placed: np.ndarray | None = None  # hull_unplaced.py): not beside these voxels (bool, volume shape), each at most
    camera_free: np.ndarray | None = None  # unplaced_max_move_m from its start and never into these voxels
    unplaced_max_move_m: float = 0.0
    plane_normals: np.ndarray | None = None  # optional (P, 3), with plane_offsets (P,): unplaced vertices within
    plane_offsets: np.ndarray | None = None  # plane_snap_m of a plane bounding the observation, facing its way, go
    plane_snap_m: float = 0.0                # onto it (recon/hull_planes.py)


def mesh_from_volume(volume, bbox_min, bbox_max, level: float, close_boundary: bool = True,
                     min_island_fraction: float = 0.01, free_space=None, smooth_iterations: int = 0,
                     free_points=None, keep_near=None, inward=None, mend_gaps: bool = False):
    """Marching cubes + small-island removal -> (trimesh.Trimesh in world frame, islands removed).

    free_space: optional bool volume on the same grid points, True where the measurements say the
    space is empty; only faces whose outward side lies in it are kept (a surface facing space nobody
    measured, e.g. the back of a wall or the box's faces, is not reported). free_points: optional test
    `free_points(points (N, 3), margin_m) -> bool (N,)` of the same kind for any point (e.g. the sensor's
    pixel footprints, between voxel centres); a face is kept when either says its outward side is free.
    smooth_iterations: Taubin (lambda | mu) smoothing of the kept faces, which removes marching-cubes
    terracing without shrinking the volume; the rims of pin-holes (`mesh_gaps.PIN_GAP_EDGES`) stay in place.
    keep_near: optional (points (N, 3), radius_m): a small island with a vertex within radius of one of these
    points is kept (measured thin parts: a one-voxel pole stepping diagonally between voxels falls apart into
    pieces below the island size, which are not specks).
    inward: optional `InwardSmoothing`: its occupancy goes into the field first; after the Taubin passes, the
    vertices whose voxel half a grid step inside is movable are smoothed further, only inward (`inward_smoothing`).
    mend_gaps: the fast mode's hole mending (`mesh_gaps`): small empty patches of the box's outer layer sealed, and
    the free-space filter's pin-holes kept; off, marching cubes as it is (BF Lidar, PlatoNeRF, evaluate).
    Faces of zero area are removed and coincident vertices merged in every case (`mesh_clean`)."""
    import trimesh
    from skimage.measure import marching_cubes

    v = _as_numpy(volume)
    lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
    if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
        raise MeshExportError(f"bbox_max {hi.tolist()} must exceed bbox_min {lo.tolist()} on every axis")
    spacing = (hi - lo) / (np.array(v.shape) - 1)
    if not (v.min() < level < v.max()):
        raise MeshExportError(f"level {level} is outside the volume's range [{v.min():.4g}, {v.max():.4g}]: "
                              f"no surface (nothing occupied, or everything)")
    if free_space is not None and np.shape(free_space) != v.shape:
        raise MeshExportError(f"free_space has shape {np.shape(free_space)}, expected the volume's {v.shape}")
    if inward is not None and inward.occupancy is not None:
        from .recon.lit_fans import with_occupancy
        v = with_occupancy(v, *inward.occupancy, inward.movable)
    origin = lo
    if close_boundary:   # a surface touching the box is closed instead of left open
        shell = mesh_gaps.sealed_shell(v, level) if mend_gaps else v
        v = np.pad(shell, 1, mode="constant", constant_values=min(float(v.min()), level - 1.0))
        origin = lo - spacing
    verts, faces, _, _ = marching_cubes(v, level=level, spacing=tuple(spacing), allow_degenerate=False)
    # scikit-image winds its triangles so that their normals point into the larger values (the
    # occupied side); reverse them: outward normals, positive volume, correct shading and culling
    mesh = trimesh.Trimesh(verts + origin, np.ascontiguousarray(faces[:, ::-1]), process=True)
    if free_space is not None or free_points is not None:
        mesh = _faces_facing_free(mesh, None if free_space is None else np.asarray(free_space, bool), lo, spacing,
                                  np.array(np.shape(volume)), free_points, mend_gaps)
    if smooth_iterations > 0 and len(mesh.faces):
        # the rims of small gaps (a few faces left out) stay where marching cubes put them: smoothed, they
        # pulled back and pin-holes grew into visible holes; long rims (the edge of the view) are smoothed
        pins = mesh_gaps.small_gap_rims(mesh, mesh_gaps.PIN_GAP_EDGES)
        lap = trimesh.smoothing.laplacian_calculation(mesh, pinned_vertices=pins)
        trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53, iterations=int(smooth_iterations),
                                        laplacian_operator=lap)
    if inward is not None and len(mesh.faces):
        inside = mesh.vertices - 0.5 * spacing * mesh.vertex_normals
        g = nearest_grid_point(inside, lo, spacing, np.shape(volume))
        mov = np.asarray(inward.movable, bool)[g[:, 0], g[:, 1], g[:, 2]]
        first = None
        if inward.face_offsets_m is not None:   # a vertex's face: its voxel's face along the normal's main axis
            n = np.asarray(mesh.vertex_normals)
            axis = np.abs(n).argmax(1)
            face = 2 * axis + (n[np.arange(len(n)), axis] > 0)
            first = np.where(mov, inward.face_offsets_m[g[:, 0], g[:, 1], g[:, 2], face], 0.0)
        inward_smoothing(mesh, mov, float(inward.max_move_m), int(inward.iterations), first_move=first)
        if inward.unplaced_iterations > 0:
            from .recon.hull_unplaced import unplaced_taubin
            unplaced_taubin(mesh, np.asarray(inward.placed, bool), np.asarray(inward.camera_free, bool), lo, spacing,
                            int(inward.unplaced_iterations), float(inward.unplaced_max_move_m))
        if inward.plane_snap_m > 0:
            from .recon.hull_planes import snap_to_planes
            snap_to_planes(mesh, np.asarray(inward.placed, bool), lo, spacing, inward.plane_normals,
                           inward.plane_offsets, float(inward.plane_snap_m))
    removed = drop_small_islands(mesh, min_island_fraction, keep_near)
    if close_boundary:   # the padded ring lies just outside the box: clamp it onto the box faces
        mesh.vertices = np.clip(mesh.vertices, lo, hi)
    return without_degenerate(mesh), removed


def nearest_grid_point(points, lo, spacing, shape) -> np.ndarray:
    """(N, 3) int64 index of the grid point nearest each of `points` (N, 3), clipped into a grid of `shape` whose
    point (0, 0, 0) lies at `lo` with `spacing` between points: the voxel a mesh vertex or a point beside it reads."""
    g = np.rint((np.asarray(points, np.float64) - lo) / spacing).astype(np.int64)
    return np.clip(g, 0, np.asarray(shape) - 1)


def inward_smoothing(mesh, movable, max_move: float, iterations: int, lamb: float = 0.5, first_move=None):
    """Umbrella-Laplacian steps (lamb each) on the `movable` vertices (bool (V,)) with every outward component
    (along the vertex normal) removed and the total displacement clamped to `max_move` (m), in place: a staircase's
    convex steps are cut (a visual hull over-estimates its object), its flat runs stay, and no vertex leaves the
    side of the surface it started on by more than the clamp. first_move: optional (V,) m: each vertex first moves
    this far inward along its normal (flat runs, recon/hull_flat.py); the clamp then grows by the largest one."""
    import trimesh

    if not np.any(movable):
        return mesh
    if first_move is not None:
        first_move = np.asarray(first_move, np.float64)
        if not np.all(np.isfinite(first_move)):
            raise MeshExportError("flat hull offsets are not finite")
        moved = first_move > 0
        if moved.any():
            v = np.asarray(mesh.vertices, np.float64).copy()
            v[moved] -= first_move[moved, None] * np.asarray(mesh.vertex_normals, np.float64)[moved]
            mesh.vertices = v
            max_move = max_move + float(first_move.max())
    start = np.asarray(mesh.vertices, np.float64).copy()
    lap = trimesh.smoothing.laplacian_calculation(mesh)     # row-normalised adjacency: the neighbours' mean
    idx = np.nonzero(movable)[0]
    for _ in range(int(iterations)):
        v = np.asarray(mesh.vertices, np.float64)
        n = np.asarray(mesh.vertex_normals, np.float64)[idx]
        step = lamb * (lap.dot(v)[idx] - v[idx])
        step -= np.maximum((step * n).sum(1), 0.0)[:, None] * n
        moved = v[idx] + step - start[idx]
        length = np.linalg.norm(moved, axis=1, keepdims=True)
        moved *= np.minimum(1.0, max_move / np.maximum(length, 1e-12))
        v = v.copy()
        v[idx] = start[idx] + moved
        mesh.vertices = v
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshExportError("inward smoothing of the hull gave non-finite vertex positions")
    return mesh


def _faces_facing_free(mesh, free, lo, spacing, shape, free_points=None, mend_gaps=False):
    """Keep the faces whose outward side (0.5 to 1.5 grid steps along the normal) is known free space: the
    nearest grid point (of a grid of `shape` points) is in `free`, or `free_points` passes the point itself
    (half a grid step of margin); with `mend_gaps`, also the pin-holes kept faces enclose (`mesh_gaps.small_gaps`)."""
    if len(mesh.faces) == 0:
        return mesh
    c = mesh.triangles_center
    n = mesh.face_normals
    keep = np.zeros(len(c), bool)
    for s in (0.5, 1.0, 1.5):
        q = c + s * spacing * n
        g = np.rint((q - lo) / spacing).astype(np.int64)
        inside = np.all((g >= 0) & (g < shape), 1)        # nearest grid point in the box
        if free is not None:
            gi = np.clip(g, 0, shape - 1)
            keep |= inside & free[gi[:, 0], gi[:, 1], gi[:, 2]]
        if free_points is not None and inside.any():
            keep[inside] |= np.asarray(free_points(q[inside], 0.5 * float(np.min(spacing))), bool)
    if mend_gaps:
        keep |= mesh_gaps.small_gaps(mesh, keep, mesh_gaps.PIN_GAP_EDGES)
    mesh.update_faces(keep)
    mesh.remove_unreferenced_vertices()
    return mesh


def _to_file_frame(mesh, suffix: str):
    out = mesh.copy()
    if suffix in Y_UP_SUFFIXES:
        out.vertices = np.asarray(mesh.vertices) @ YUP_FROM_BLENDER.T
    return out


def write_mesh(mesh, path) -> Path:
    """Write a world-frame mesh so that Blender's default importer places it in place (see module doc)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise MeshExportError(f"{path}: unsupported mesh format {suffix!r}; use one of {list(SUPPORTED_SUFFIXES)}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    m = _to_file_frame(mesh, suffix)
    if suffix == ".obj":   # UVs as 'vt', but no material/texture files beside it (nothing to show in them)
        from trimesh.exchange.obj import export_obj
        text, _ = export_obj(m, include_texture=True, return_texture=True, mtl_name=f"{path.stem}.mtl")
        text = re.sub(r"^(?:mtllib|usemtl)\b[^\n]*\n?", "", text, flags=re.MULTILINE)   # one line each
        tmp.write_text(text if text.endswith("\n") else text + "\n")
    else:
        m.export(tmp)
    tmp.replace(path)
    return path


def load_mesh_world(path):
    """Read a mesh file (as written here) back into the Blender world frame (trimesh.Trimesh)."""
    import trimesh
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mesh file not found")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds for bad files
        raise MeshExportError(f"{path}: cannot read mesh ({exc})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise MeshExportError(f"{path}: no triangles in the file")
    if path.suffix.lower() in Y_UP_SUFFIXES:
        mesh.vertices = np.asarray(mesh.vertices) @ YUP_FROM_BLENDER   # inverse of an orthonormal matrix
    return mesh


def sidecar_path(out_path) -> Path:
    p = Path(out_path)
    return p.with_name(p.stem + ".mesh.json")


def export_mesh(volume, bbox_min, bbox_max, level, out_path, metadata=None, *, extra_formats=(), uv=True,
                close_boundary=True, min_island_fraction=0.01, max_uv_faces=1_000_000, free_space=None,
                smooth_iterations: int = 0, free_points=None, keep_near=None, inward=None,
                mend_gaps: bool = False) -> ExportResult:
    """Volume -> mesh file(s) in the Blender world frame + `<stem>.mesh.json` with metadata.

    metadata: JSON-able dict from the caller (method, settings, run time, dataset hash, ...);
    the sidecar adds level, bbox, grid, counts, frames and timing. extra_formats: more
    suffixes (e.g. ('.ply', '.obj')) written next to out_path from the same mesh. The mesh: `mesh_from_volume`.
    """
    t0 = time.perf_counter()
    out_path = Path(out_path)
    suffixes = [out_path.suffix.lower()] + [s.lower() if s.startswith(".") else "." + s.lower()
                                            for s in extra_formats]
    for s in suffixes:
        if s not in SUPPORTED_SUFFIXES:
            raise MeshExportError(f"unsupported mesh format {s!r}; use one of {list(SUPPORTED_SUFFIXES)}")
    try:
        json.dumps(metadata or {})
    except TypeError as exc:
        raise MeshExportError(f"metadata must be JSON-serialisable: {exc}") from None
    mesh, removed = mesh_from_volume(volume, bbox_min, bbox_max, level, close_boundary, min_island_fraction,
                                     free_space=free_space, smooth_iterations=smooth_iterations,
                                     free_points=free_points, keep_near=keep_near, inward=inward,
                                     mend_gaps=mend_gaps)
    uv_done = False
    if uv and len(mesh.faces) <= max_uv_faces:
        from .mesh_uv import uv_unwrap

        mesh = uv_unwrap(mesh)
        uv_done = True
    paths = [write_mesh(mesh, out_path.with_suffix(s)) for s in dict.fromkeys(suffixes)]
    seconds = time.perf_counter() - t0
    shape = list(np.shape(volume))
    side = {"metadata": metadata or {},
            "mesh": {"files": [p.name for p in paths],
                     "file_frames": {p.name: ("y_up (x, z, -y); Blender's default importer restores Z-up"
                                              if p.suffix.lower() in Y_UP_SUFFIXES else "blender_world_z_up")
                                     for p in paths},
                     "world_frame": "blender_world_z_up", "units": "m",
                     "n_vertices": int(len(mesh.vertices)), "n_faces": int(len(mesh.faces)),
                     "bounds_world": np.asarray(mesh.bounds).tolist(), "uv": "xatlas" if uv_done else None,
                     "islands_removed": int(removed)},
            "volume": {"shape": shape, "bbox_min": np.asarray(bbox_min, float).tolist(),
                       "bbox_max": np.asarray(bbox_max, float).tolist(), "level": float(level),
                       "sample_convention": "grid points span the bbox (corner-aligned)",
                       "close_boundary": bool(close_boundary), "min_island_fraction": float(min_island_fraction),
                       "faces_facing_measured_free_space_only": free_space is not None or free_points is not None,
                       "free_space_point_test": free_points is not None,
                       "taubin_iterations": int(smooth_iterations), "gaps_mended": bool(mend_gaps)},
            "export_seconds": round(seconds, 4),
            "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds")}
    sc = sidecar_path(out_path)
    tmp = sc.with_name("." + sc.name + ".partial")
    tmp.write_text(json.dumps(side, indent=1))
    tmp.replace(sc)
    return ExportResult(mesh=mesh, paths=paths, sidecar=sc, n_vertices=len(mesh.vertices), n_faces=len(mesh.faces),
                        islands_removed=removed, seconds=seconds)
