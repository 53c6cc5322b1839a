"""Object-level and scene-level surface metrics: what a user sees, not what the room's walls average to.

Definitions (all distances point-to-triangle, metres; samples area-weighted and seeded):
- Ground-truth objects: labelled meshes (dataset `ground_truth.objects`, or split off the room's shell by
  torch_recon.contract.scene_objects when a dataset has no labels). Everything else in the GT is the room.
- An object's region: its bounding box grown by `region_margin_m` on every side.
- Contact points: GT object samples within `contact_m` of another GT surface (a box's bottom on the floor,
  a chair leg's foot) or of another part of the same object (its connected components: a backrest's foot on the
  seat, a leg's top under it) are left out of recall: no sensor can see them and no method is asked to.
- Sensor-visible GT points: inside the sensor's field of view, facing the sensor, and not occluded (an Embree
  ray from the sensor reaches them). All other (non-contact) GT points are hidden.
- Per object, for thresholds tau in `thresholds_m`:
  recall@tau (all, visible, hidden) = share of GT points within tau of the reconstruction;
  precision@tau = share of the reconstruction's samples in the object's region that are attributed to the
  object (nearer to it than to any other GT surface, or farther than `spurious_m` from every GT surface)
  lying within tau of the object; F@tau = 2PR/(P+R); chamfer_m = 0.5 (mean of both directions).
  spurious_fraction = share of the reconstruction's area in the region farther than `spurious_m` from any
  GT surface. normal_consistency = mean |n_rec . n_gt| over the object's reconstruction samples within
  `shape_band_m` of it (n_gt: the nearest object face): how lumpy the surface is where it is roughly right,
  which the distance metrics miss (a smooth egg and a lumpy blob 1-2 cm off it score alike).
- Scene: spurious_fraction over the whole reconstruction; objects_spurious_fraction over the union of all
  objects' regions; room_off_surface_fraction = share of the reconstruction outside every object's region
  (walls, floor, ceiling) farther than `room_flat_m` from any GT surface: the dents and bumps on planar
  surfaces that the 2 cm spurious threshold misses (room_off_surface_exact: false where the GT was too large
  to measure the candidates exactly, then an upper bound);
  normal_consistency = mean |n_rec . n_gt| of nearest faces, both directions averaged;
  degenerate_faces = faces of area <= `degenerate_area_m2` (or non-finite vertices).
Cost: distances come from candidate faces of the nearest surface samples (`surface.point_to_mesh_distance`); where
only a comparison is needed (contact, which GT surface a sample is nearer to) the search stops at the compared
distance, and contact between an object's parts is measured exactly against the faces whose bounding spheres reach
(`surface.within_distance`): the same numbers as unbounded / brute-force queries, 80 -> 16 s on cave-chair (session 21).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .surface import exact_point_to_mesh_distance, point_to_mesh_distance, within_distance


@dataclass
class ObjectMetricSettings:
    thresholds_m: tuple = (0.01, 0.02, 0.05)
    spurious_m: float = 0.02            # reconstruction farther than this from every true surface is spurious
    contact_m: float = 0.01             # GT object points this close to another surface are contact, not scored
    region_margin_m: float = 0.10       # an object's region: its bounding box grown by this much
    gt_samples_per_object: int = 20_000
    recon_samples_per_m2: float = 40_000.0   # reconstruction samples inside the objects' regions
    max_region_samples: int = 200_000
    shape_band_m: float = 0.05          # per-object normal consistency: reconstruction samples this close to it
    room_flat_m: float = 0.005          # the room's surface farther than this from the true one: a dent or bump
    scene_samples: int = 100_000        # whole-scene spurious fraction / normal consistency
    scene_samples_per_m2: float = 4000.0  # density of the samples that find candidate faces on whole scenes
    degenerate_area_m2: float = 1e-12
    seed: int = 0

    def validate(self):
        from ..contract.errors import SettingsError

        if not self.thresholds_m or any(not t > 0 for t in self.thresholds_m):
            raise SettingsError("object_metric_settings.thresholds_m",
                                f"expected positive distances (m), got {self.thresholds_m}")
        for name in ("spurious_m", "contact_m", "region_margin_m", "recon_samples_per_m2", "shape_band_m",
                     "room_flat_m"):
            if not getattr(self, name) > 0:
                raise SettingsError(f"object_metric_settings.{name}", f"expected a value > 0, got {getattr(self, name)}")


class Surface:
    """A mesh with dense seeded surface samples for distance (and nearest-face) queries."""

    def __init__(self, mesh, n_samples: int, seed: int, max_edge_m: float = 0.1, k: int = 16):
        import trimesh
        self.k = k
        # candidate faces come from the nearest samples: split large triangles (a wall is two) so that the
        # nearest samples' faces include the nearest face
        self.mesh = _split_large_triangles(mesh, max_edge_m)
        n = max(int(n_samples), 1)
        self.samples, self.sample_faces = trimesh.sample.sample_surface(self.mesh, n, seed=seed)
        self._tree = None

    def distance(self, points, return_faces=False, max_m=None):
        """surface.point_to_mesh_distance (max_m: only distances up to it are needed)."""
        from scipy.spatial import cKDTree
        if self._tree is None:          # one k-d tree per surface, not per query
            self._tree = cKDTree(self.samples)
        return point_to_mesh_distance(np.asarray(points, np.float64).reshape(-1, 3), self.mesh, self.samples,
                                      self.sample_faces, k=self.k, return_faces=return_faces, max_m=max_m,
                                      tree=self._tree)


def _split_large_triangles(mesh, max_edge_m):
    import trimesh
    tri = np.asarray(mesh.triangles)
    if len(tri) == 0 or np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max() <= max_edge_m:
        return mesh
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge_m, max_iter=20)
    return trimesh.Trimesh(v, f, process=False)


def sample_count(area, per_m2, lo=2000, hi=400_000):
    """Surface samples for a mesh of `area` m2 at `per_m2`, clipped to [lo, hi] (one rule for every sampler
    here and in hidden_causes, so both draw identical samples)."""
    return int(np.clip(area * per_m2, lo, hi))


def degenerate_face_count(mesh, area_m2=1e-12) -> int:
    v = np.asarray(mesh.vertices)
    bad = ~np.isfinite(v).all(axis=1)
    areas = np.nan_to_num(np.asarray(mesh.area_faces), nan=0.0)
    return int(((areas <= area_m2) | bad[np.asarray(mesh.faces)].any(axis=1)).sum())


def sensor_visible(points, normals, gt_mesh, sensor) -> np.ndarray:
    """Which points the sensor sees: in its field of view, facing it, first along its ray (two-sided GT)."""
    from ..contract.analytic import first_hits
    from ..contract.frames import project_points

    points = np.asarray(points, np.float64).reshape(-1, 3)
    if sensor is None or len(points) == 0:
        return np.zeros(len(points), bool)
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    c = c2w[:3, 3]
    col, row, depth = project_points(c2w, sensor.width, sensor.height, sensor.fov_rad, points, sensor.fov_axis)
    ok = (depth > 0) & (col >= 0) & (col < sensor.width) & (row >= 0) & (row < sensor.height)
    to_c = c - points
    dist = np.linalg.norm(to_c, axis=1)
    ok &= np.einsum("ij,ij->i", normals, to_c) > 0
    idx = np.flatnonzero(ok)
    if len(idx):
        dirs = -to_c[idx] / dist[idx, None]
        hit, _, _, d = first_hits(gt_mesh, np.broadcast_to(c, dirs.shape), dirs)
        ok[idx] = ~hit | (d >= dist[idx] - 1e-3)
    return ok


def _fscore(p, r):
    return 0.0 if p + r <= 0 else float(2 * p * r / (p + r))


def _tau_key(t):
    return f"{round(t * 100, 3):g}cm"


def _in_box(points, lo, hi):
    return np.all((points >= lo) & (points <= hi), axis=1)


def object_surface_metrics(recon, gt_mesh, objects, sensor=None, settings: ObjectMetricSettings | None = None) -> dict:
    """Per-object and scene-level metrics (see module doc).

    recon: trimesh reconstruction (world frame); gt_mesh: the whole ground truth; objects: list of
    (name, trimesh) labelled GT objects (may be empty); sensor: a dataset SensorSpec (None: every GT point
    counts as hidden). Returns {'scene': {...}, 'objects': {name: {...}}, 'settings': {...}}.
    """
    import trimesh
    s = settings or ObjectMetricSettings()
    s.validate()
    out = {"settings": asdict(s), "objects": {}}
    n_deg = 0 if recon is None else degenerate_face_count(recon, s.degenerate_area_m2)
    empty = recon is None or len(recon.faces) == 0 or float(recon.area) <= 0
    gt_all = Surface(gt_mesh, sample_count(gt_mesh.area, s.scene_samples_per_m2, 20_000, 300_000), s.seed + 1)
    scene = {"degenerate_faces": n_deg, "n_faces": 0 if recon is None else int(len(recon.faces))}
    boxes = [(np.asarray(m.bounds[0]) - s.region_margin_m, np.asarray(m.bounds[1]) + s.region_margin_m)
             for _, m in objects]
    if empty:
        scene.update({"spurious_fraction": None, "normal_consistency": None, "note": "empty reconstruction"})
    else:
        r_pts, r_faces = trimesh.sample.sample_surface(recon, s.scene_samples, seed=s.seed)
        d_rg, f_g = gt_all.distance(r_pts, return_faces=True)
        rec_surf = Surface(recon, sample_count(recon.area, s.scene_samples_per_m2, 20_000, 300_000), s.seed + 2, k=8)
        g_pts, g_faces = gt_all.samples[:s.scene_samples], gt_all.sample_faces[:s.scene_samples]
        d_gr, f_r = rec_surf.distance(g_pts, return_faces=True)
        nc_r = np.abs(np.einsum("ij,ij->i", recon.face_normals[r_faces], gt_all.mesh.face_normals[f_g]))
        nc_g = np.abs(np.einsum("ij,ij->i", gt_all.mesh.face_normals[g_faces], rec_surf.mesh.face_normals[f_r]))
        scene.update({"spurious_fraction": float((d_rg > s.spurious_m).mean()),
                      "spurious_fraction_5cm": float((d_rg > 0.05).mean()),
                      "normal_consistency": float(0.5 * (np.nan_to_num(nc_r).mean() + np.nan_to_num(nc_g).mean())),
                      "chamfer_m": float(0.5 * (d_rg.mean() + d_gr.mean()))})
        room = np.ones(len(r_pts), bool)
        for lo, hi in boxes:
            room &= ~_in_box(r_pts, lo, hi)
        if room.any():
            # the candidate-face distance is an upper bound a few mm off at thin slabs' edges: the samples it
            # puts beyond room_flat_m are measured again against every GT face
            d_room = d_rg[room].copy()
            over = d_room > s.room_flat_m
            exact = exact_point_to_mesh_distance(r_pts[room][over], gt_mesh) if over.any() else None
            if exact is not None:
                d_room[over] = np.minimum(d_room[over], exact)
            scene.update({"room_off_surface_fraction": float((d_room > s.room_flat_m).mean()),
                          "room_off_surface_exact": bool(exact is not None or not over.any())})
    out["scene"] = scene
    if not objects:
        return out

    # the reconstruction inside the union of the objects' regions, sampled densely
    reg_pts, reg_nrm = np.zeros((0, 3)), np.zeros((0, 3))
    rec_surf_region = None
    if not empty:
        tri = np.asarray(recon.triangles)
        tmin, tmax = tri.min(axis=1), tri.max(axis=1)
        near = np.zeros(len(tri), bool)
        for lo, hi in boxes:
            near |= np.all((tmax >= lo) & (tmin <= hi), axis=1)
        if near.any():
            sub = _split_large_triangles(recon.submesh([np.flatnonzero(near)], append=True), 0.05)
            tri = np.asarray(sub.triangles)
            tmin, tmax = tri.min(axis=1), tri.max(axis=1)
            near = np.zeros(len(tri), bool)
            for lo, hi in boxes:
                near |= np.all((tmax >= lo) & (tmin <= hi), axis=1)
            sub = sub.submesh([np.flatnonzero(near)], append=True)
            n = min(sample_count(sub.area, s.recon_samples_per_m2, 2000, s.max_region_samples),
                    s.max_region_samples)
            reg_pts, reg_faces = trimesh.sample.sample_surface(sub, n, seed=s.seed + 3)
            inside = np.zeros(len(reg_pts), bool)
            for lo, hi in boxes:
                inside |= _in_box(reg_pts, lo, hi)
            reg_pts, reg_nrm = reg_pts[inside], np.asarray(sub.face_normals)[reg_faces[inside]]
            rec_surf_region = Surface(sub, sample_count(sub.area, s.recon_samples_per_m2, 20_000,
                                                            2 * s.max_region_samples), s.seed + 4)
    d_reg_all = gt_all.distance(reg_pts) if len(reg_pts) else np.zeros(0)
    scene["objects_spurious_fraction"] = float((d_reg_all > s.spurious_m).mean()) if len(reg_pts) else None
    scene["objects_region_samples"] = int(len(reg_pts))

    obj_surfs = [Surface(m, s.gt_samples_per_object, s.seed + 10 + i) for i, (_, m) in enumerate(objects)]
    for i, (name, m) in enumerate(objects):
        os_ = obj_surfs[i]
        rest = rest_of_scene(gt_mesh, objects, i)
        rest_surf = Surface(rest, sample_count(rest.area, s.scene_samples_per_m2, 20_000, 300_000),
                            s.seed + 30 + i) if rest is not None else None
        contact = contact_samples(os_, rest_surf, s.contact_m)
        g_pts, g_faces = os_.samples[~contact], os_.sample_faces[~contact]
        vis = sensor_visible(g_pts, os_.mesh.face_normals[g_faces], gt_mesh, sensor)
        res = {"n_gt_points": int(len(g_pts)), "n_contact_points": int(contact.sum()),
               "visible_share": float(vis.mean()) if len(vis) else None}
        lo, hi = boxes[i]
        sel = _in_box(reg_pts, lo, hi) if len(reg_pts) else np.zeros(0, bool)
        p_pts = reg_pts[sel]
        if rec_surf_region is None:
            d_gr = np.full(len(g_pts), np.inf)
        else:
            d_gr = rec_surf_region.distance(g_pts)
        d_po, f_po = os_.distance(p_pts, return_faces=True) if len(p_pts) else (np.zeros(0), np.zeros(0, int))
        d_prest = (_bounded_by(rest_surf, p_pts, d_po) if (len(p_pts) and rest_surf is not None)
                   else np.full(len(p_pts), np.inf))
        d_pall = d_reg_all[sel]
        mine = (d_po <= d_prest) | (d_pall > s.spurious_m)
        d_mine = d_po[mine]
        res["n_recon_points"] = int(mine.sum())
        band = mine & (d_po < s.shape_band_m)
        res["normal_consistency"] = (float(np.nan_to_num(np.abs(np.einsum(
            "ij,ij->i", reg_nrm[sel][band], os_.mesh.face_normals[f_po[band]]))).mean()) if band.any() else None)
        res["spurious_fraction"] = float((d_pall > s.spurious_m).mean()) if len(d_pall) else None
        res["chamfer_m"] = (float(0.5 * (d_mine.mean() + d_gr.mean()))
                            if len(d_mine) and np.isfinite(d_gr).all() else None)
        for t in s.thresholds_m:
            k = _tau_key(t)
            p = float((d_mine < t).mean()) if len(d_mine) else 0.0
            r = float((d_gr < t).mean()) if len(d_gr) else 0.0
            res[f"precision@{k}"], res[f"recall@{k}"], res[f"fscore@{k}"] = p, r, _fscore(p, r)
            res[f"recall_visible@{k}"] = float((d_gr[vis] < t).mean()) if vis.any() else None
            res[f"recall_hidden@{k}"] = float((d_gr[~vis] < t).mean()) if (~vis).any() else None
        out["objects"][name] = res
    out["summary"] = _summary(out["objects"], s.thresholds_m)
    return out


def contact_samples(object_surface: Surface, rest_surface: Surface | None, contact_m: float) -> np.ndarray:
    """bool per sample of `object_surface`: within contact_m of the rest of the scene (`rest_surface`, None: nothing
    else) or of another of the object's own parts (`part_contact`); such points are not scored."""
    pts, faces = object_surface.samples, object_surface.sample_faces
    contact = (rest_surface.distance(pts, max_m=contact_m) < contact_m if rest_surface is not None
               else np.zeros(len(pts), bool))
    return contact | part_contact(object_surface.mesh, pts, faces, contact_m)


def part_contact(mesh, points, faces, contact_m: float) -> np.ndarray:
    """bool (N,): points (sampled on `faces` of an object's mesh) within contact_m of another of the object's parts
    (connected components: a chair's backrest standing on its seat, a leg under it). The faces where parts meet lie
    inside the solid: no sensor sees them, as no sensor sees a box's bottom on the floor."""
    import trimesh
    merged = mesh.copy()
    merged.merge_vertices()         # keeps the face order: labels index the samples' faces
    label = trimesh.graph.connected_component_labels(merged.face_adjacency, node_count=len(merged.faces))
    out = np.zeros(len(points), bool)
    if label.max(initial=0) == 0:
        return out
    for part in np.unique(label):
        on = label[faces] == part
        others = merged.submesh([np.flatnonzero(label != part)], append=True)
        out[on] = within_distance(points[on], others, contact_m)
    return out


def _bounded_by(surface, points, bound):
    """surface.distance(points) where it is <= the per-point `bound`, some value > bound elsewhere (the caller
    only compares the two): points grouped by bound, each group's search stopped at its largest bound."""
    out = np.empty(len(points))
    edges = np.array([0.02, 0.05, 0.1, 0.2, 0.4, 0.8, 1.6])
    group = np.searchsorted(edges, bound)
    for g in np.unique(group):
        sel = group == g
        top = float(bound[sel].max())
        out[sel] = surface.distance(points[sel], max_m=top if np.isfinite(top) else None)
    return out


def rest_of_scene(gt_mesh, objects, i):
    """The GT without object i: the other objects and the room (found by removing object i's faces)."""
    import trimesh
    others = [m for j, (_, m) in enumerate(objects) if j != i]
    room = room_without_objects(gt_mesh, [m for _, m in objects])
    parts = [p for p in others + [room] if p is not None and len(p.faces)]
    return trimesh.util.concatenate(parts) if parts else None


def room_without_objects(gt_mesh, object_meshes):
    """GT faces that belong to no object (matched by triangle centroid and vertex positions)."""
    from scipy.spatial import cKDTree
    if not object_meshes:
        return gt_mesh
    obj_tri = np.concatenate([np.asarray(m.triangles).reshape(-1, 9) for m in object_meshes])
    gt_tri = np.asarray(gt_mesh.triangles).reshape(-1, 9)
    d, _ = cKDTree(obj_tri).query(gt_tri, k=1)
    keep = d > 1e-6
    if not keep.any():
        return None
    return gt_mesh.submesh([np.flatnonzero(keep)], append=True)


def _summary(objects: dict, thresholds) -> dict:
    """Means over objects (each object weighs the same), for tables."""
    out = {}
    if not objects:
        return out
    keys = ["chamfer_m", "spurious_fraction", "normal_consistency"] + [f"{m}@{_tau_key(t)}" for t in thresholds
                                                 for m in ("fscore", "precision", "recall", "recall_visible",
                                                           "recall_hidden")]
    for k in keys:
        vals = [o[k] for o in objects.values() if o.get(k) is not None]
        out[k] = float(np.mean(vals)) if vals else None
    return out
