"""Ground-truth measurements by ray casting a dataset's ground-truth mesh, and the accuracy of extracted ones.

What preprocessing should have found, per spot and pixel (numpy + trimesh/Embree, no torch, no bpy):
- `lit_fraction`: of n x n sub-pixel camera rays, the share whose surface point x sees the spot l
  (segment x -> l unblocked, x and l facing each other: the simulator's Lambertian two-bounce rule).
  A 1-pixel-wide leg's shadow covers part of a pixel: 0 < lit_fraction < 1 there.
- `path_m`: the mean two-bounce optical path |l - o| + |x - l| + |c - x| of the lit sub-samples.
- `blocker_object`: the labelled object (index into the dataset's ground_truth.objects, -1: the room or
  nothing) that blocks the segment x -> l of the pixel-centre-most blocked sample.
`measurement_accuracy` scores a Measurements against it: shadow precision / recall (truth: lit fraction
below one half), recall on thin shadows (truth shadow pixels that a 3 x 3 opening of the truth mask
removes: shadows at most about two pixels wide, as legs and poles cast), on shadows cast by labelled
objects, the false-shadow rate on fully lit pixels, the share of pixels a labelled object shadows in part
(lit fraction below 0.9) that are called lit (their lit segment carves through the object), and the
two-bounce path error on fully lit pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .contract.analytic import RAY_EPS, first_hits
from .contract.frames import camera_ray_directions


@dataclass
class SpotTruth:
    lit_fraction: np.ndarray     # (H, W) float32 in [0, 1]; NaN where no sub-sample hits a surface
    path_m: np.ndarray           # (H, W) float32 mean path of the lit sub-samples; NaN where none is lit
    path_spread_m: np.ndarray    # (H, W) float32 max - min path of the lit sub-samples (depth-edge pixels)
    blocker_object: np.ndarray   # (H, W) int16: labelled object blocking the pixel's light, -1 none/room


def _object_boxes(dataset, grow=0.01):
    import trimesh
    boxes = []
    for obj in dataset.manifest.ground_truth.objects:
        m = trimesh.load(dataset.path(obj.mesh_file), force="mesh", process=False)
        boxes.append((np.asarray(m.bounds[0]) - grow, np.asarray(m.bounds[1]) + grow))
    return boxes


def spot_truths(dataset, subpixel: int = 3) -> list[SpotTruth]:
    """SpotTruth for every enabled spot of a dataset with a ground-truth mesh (l = the recorded first bounce)."""
    import trimesh
    gt = dataset.manifest.ground_truth
    if gt is None or not gt.mesh_file:
        raise ValueError(f"{dataset.root}: no ground_truth.mesh_file: measurement truth needs the scene's mesh")
    mesh = trimesh.load(dataset.path(gt.mesh_file), force="mesh", process=False)
    s = dataset.sensor
    c2w = np.asarray(s.camera_to_world, np.float64)
    c, o = c2w[:3, 3], np.asarray(s.laser_origin, np.float64)
    g = (np.arange(subpixel) + 0.5) / subpixel - 0.5
    offsets = np.stack(np.meshgrid(g, g, indexing="xy"), -1).reshape(-1, 2)
    # centre-most sample first: it names the blocker when several are blocked
    offsets = offsets[np.argsort(np.abs(offsets).sum(1), kind="stable")]
    dirs = camera_ray_directions(s.width, s.height, s.fov_rad, s.fov_axis, offsets) @ c2w[:3, :3].T
    dirs = dirs.reshape(len(offsets), -1, 3)
    cams = []
    for d in dirs:
        hit, x, tri, dist = first_hits(mesh, c + RAY_EPS * d, d)
        n = np.zeros_like(x)
        n[hit] = mesh.face_normals[tri[hit]]
        flip = np.einsum("ij,ij->i", n, c - np.where(hit[:, None], x, 0)) < 0
        n[flip] *= -1                                 # two-sided: the side the sensor sees
        cams.append((hit, x, n, dist + RAY_EPS))
    boxes = _object_boxes(dataset)
    out = []
    npx = s.width * s.height
    for sp in dataset.manifest.enabled_spots:
        ld = np.asarray(sp.laser_direction, np.float64)
        ld /= np.linalg.norm(ld)
        lh, lp, lt, _ = first_hits(mesh, (o + RAY_EPS * ld)[None], ld[None])
        l = np.asarray(sp.first_bounce, np.float64) if sp.first_bounce is not None else lp[0]
        nl = mesh.face_normals[lt[0]] if lh[0] else -ld
        if np.dot(nl, o - l) < 0:
            nl = -nl
        d_lo = float(np.linalg.norm(l - o))
        n_hit = np.zeros(npx)
        n_lit = np.zeros(npx)
        psum = np.zeros(npx)
        pmin, pmax = np.full(npx, np.inf), np.full(npx, -np.inf)
        blocker = np.full(npx, -1, np.int16)
        named = np.zeros(npx, bool)
        for hit, x, n, dist in cams:
            idx = np.flatnonzero(hit)
            xs, ns = x[idx], n[idx]
            v = l - xs
            r = np.linalg.norm(v, axis=1)
            u = v / np.maximum(r, 1e-9)[:, None]
            facing = (r > 1e-6) & (np.einsum("ij,ij->i", ns, u) > 0) & (-(u @ nl) > 0)
            a = xs + RAY_EPS * ns
            seg = (l + RAY_EPS * nl) - a
            slen = np.linalg.norm(seg, axis=1)
            su = seg / np.maximum(slen, 1e-12)[:, None]
            bh, bp, _, bd = first_hits(mesh, a + RAY_EPS * su, su)
            blocked = bh & (bd < slen - 2 * RAY_EPS)
            lit = facing & ~blocked
            path = d_lo + r + dist[idx]
            n_hit[idx] += 1
            n_lit[idx] += lit
            psum[idx] += np.where(lit, path, 0.0)
            pmin[idx] = np.where(lit, np.minimum(pmin[idx], path), pmin[idx])
            pmax[idx] = np.where(lit, np.maximum(pmax[idx], path), pmax[idx])
            first = blocked & ~named[idx]
            for j, (lo, hi) in enumerate(boxes):
                inside = first & np.all((bp >= lo) & (bp <= hi), axis=1)
                blocker[idx[inside]] = j
            named[idx[first]] = True
        with np.errstate(invalid="ignore", divide="ignore"):
            frac = np.where(n_hit > 0, n_lit / np.maximum(n_hit, 1), np.nan)
            path = np.where(n_lit > 0, psum / np.maximum(n_lit, 1), np.nan)
        spread = np.where(n_lit > 0, pmax - pmin, np.nan)
        hw = (s.height, s.width)
        out.append(SpotTruth(frac.reshape(hw).astype(np.float32), path.reshape(hw).astype(np.float32),
                             spread.reshape(hw).astype(np.float32), blocker.reshape(hw)))
    return out


def thin_shadow_mask(truth_shadow: np.ndarray) -> np.ndarray:
    """Truth-shadow pixels that a 3 x 3 opening removes: shadows about two pixels wide or less."""
    from scipy.ndimage import binary_opening
    return truth_shadow & ~binary_opening(truth_shadow, structure=np.ones((3, 3), bool))


def measurement_accuracy(meas, truths: list[SpotTruth], bin_width_m: float) -> dict:
    """Pooled over spots and usable pixels (not excluded, a surface in the truth): see the module docstring."""
    tp = fp = fn = 0
    thin_tp = thin_n = obj_tp = obj_n = part_tp = part_n = 0
    lit_n = lit_fa = n_usable = n_unlabelled = occl_n = occl_lit = 0
    errs = []
    for sm, t in zip(meas.spots, truths):
        usable = ~np.asarray(sm.excluded, bool) & np.isfinite(t.lit_fraction)
        f = np.nan_to_num(t.lit_fraction, nan=1.0)
        truth = (f < 0.5) & usable
        pred = np.asarray(sm.shadow, bool) & usable
        n_usable += int(usable.sum())
        n_unlabelled += int((usable & ~pred & ~np.asarray(sm.signal, bool)).sum())
        tp += int((pred & truth).sum())
        fp += int((pred & ~truth & usable).sum())
        fn += int((~pred & truth).sum())
        thin = thin_shadow_mask(truth)
        thin_n += int(thin.sum())
        thin_tp += int((pred & thin).sum())
        obj = truth & (t.blocker_object >= 0)
        obj_n += int(obj.sum())
        obj_tp += int((pred & obj).sum())
        part = usable & (f > 0) & (f < 0.5)
        part_n += int(part.sum())
        part_tp += int((pred & part).sum())
        # pixels a labelled object shadows in part (at least a tenth): called lit, their segment carves it
        occl = usable & (f < 0.9) & (t.blocker_object >= 0)
        occl_n += int(occl.sum())
        occl_lit += int((occl & np.asarray(sm.signal, bool)).sum())
        full = usable & (f >= 1.0)
        lit_n += int(full.sum())
        lit_fa += int((pred & full).sum())
        clean = full & np.asarray(sm.signal, bool) & (np.nan_to_num(t.path_spread_m, nan=np.inf) < 0.5 * bin_width_m)
        errs.append((np.asarray(sm.path_length, np.float64) - t.path_m)[clean])
    e = np.concatenate(errs) if errs else np.zeros(0)
    e = e[np.isfinite(e)]
    ratio = (lambda a, b: float(a / b) if b else float("nan"))
    prec, rec = ratio(tp, tp + fp), ratio(tp, tp + fn)
    return {"shadow_precision": prec, "shadow_recall": rec,
            "shadow_f1": ratio(2 * prec * rec, prec + rec) if tp else 0.0,
            "thin_shadow_recall": ratio(thin_tp, thin_n), "n_thin_shadow": thin_n,
            "object_shadow_recall": ratio(obj_tp, obj_n), "n_object_shadow": obj_n,
            "partial_shadow_recall": ratio(part_tp, part_n), "n_partial_shadow": part_n,
            "object_lit_rate": ratio(occl_lit, occl_n), "false_shadow_rate": ratio(lit_fa, lit_n), "unlabelled_rate": ratio(n_unlabelled, n_usable), "n_truth_shadow": tp + fn,
            "path_median_mm": float(np.median(np.abs(e)) * 1e3) if e.size else float("nan"),
            "path_p95_mm": float(np.percentile(np.abs(e), 95) * 1e3) if e.size else float("nan"),
            "path_bias_mm": float(np.median(e) * 1e3) if e.size else float("nan"),
            "path_within_half_bin": float(np.mean(np.abs(e) <= 0.5 * bin_width_m)) if e.size else float("nan")}


def truth_label_measurements(meas, truths: list[SpotTruth]):
    """A copy of `meas` whose lit / shadow labels are the ray-cast truth's (lit: lit fraction >= 1/2), for
    fits that tell what perfect shadow decisions would give. A pixel turned lit takes the truth's path where
    it had no measured one; pixels without a surface in the truth are excluded."""
    import copy
    out = copy.deepcopy(meas)
    for sm, t in zip(out.spots, truths):
        known = np.isfinite(t.lit_fraction)
        usable = ~np.asarray(sm.excluded, bool) & known
        lit = usable & (np.nan_to_num(t.lit_fraction, nan=0.0) >= 0.5)
        measured = np.asarray(sm.signal, bool) & np.isfinite(sm.path_length)
        sm.path_length = np.where(lit, np.where(measured, sm.path_length, t.path_m), np.nan).astype(np.float32)
        if sm.first_return_path is not None:
            sm.first_return_path = np.where(lit, np.fmin(sm.first_return_path, sm.path_length),
                                            np.nan).astype(np.float32)
        sm.signal, sm.shadow = lit, usable & ~lit
        sm.excluded = np.asarray(sm.excluded, bool) | ~known
    return out
