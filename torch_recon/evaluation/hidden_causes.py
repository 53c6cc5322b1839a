"""Where and why a reconstruction misses hidden object surface (recall_hidden, `objects.py`).

Splits each labelled object's missed hidden points (evaluate's samples: non-contact, not sensor-visible,
farther than tau from the reconstruction) by cause:
- `no_lit_segment`: no lit two-bounce segment passes just outside the point (q = p + `offset_m` n): for
  every spot l, the ray l -> q ends on a surface x the sensor does not see, or not facing l, or is blocked
  before q. No pixel's segment x -> l can carve there, so only the shadow hull bounds that surface.
- `labels`: a lit segment passes there, and a fit on the same data with the ray-cast truth labels
  (`measurement_truth.truth_label_measurements`) gets the point: a shadow decision cost it.
- `fit`: a lit segment passes there and the truth-label fit misses it too (grid, training, meshing).
Also whether the nearest reconstruction point lies outside the true surface (along its normal: space not
carved, the hull too big) or inside (carved away, or nothing there), and the face direction (+x .. -z).
`python -m torch_recon.evaluation.hidden_causes DATASET MESH [TRUTH_LABEL_MESH]` prints the table.
"""

from __future__ import annotations

import numpy as np

from ..contract.analytic import first_hits
from .objects import ObjectMetricSettings, Surface, contact_samples, rest_of_scene, sample_count, sensor_visible

FACE_DIRECTIONS = ("+x", "-x", "+y", "-y", "+z", "-z")


def lit_segment_passes(points, gt_mesh, spots, sensor) -> np.ndarray:
    """(N,) bool: some spot's light passes `points` and lands on a surface the sensor sees, facing the spot."""
    out = np.zeros(len(points), bool)
    for l in spots:
        v = points - l
        dist = np.linalg.norm(v, axis=1)
        u = v / np.maximum(dist, 1e-12)[:, None]
        hit, x, tri, d = first_hits(gt_mesh, l + 1e-4 * u, u)
        ok = hit & (d > dist)                       # nothing between l and the point; x lies beyond it
        n = gt_mesh.face_normals[np.where(ok, tri, 0)]
        n = np.where((np.einsum("ij,ij->i", n, u) > 0)[:, None], -n, n)     # two-sided: the side facing l
        ok &= np.einsum("ij,ij->i", n, -u) > 0.05
        idx = np.flatnonzero(ok & ~out)
        if len(idx):
            out[idx] = sensor_visible(x[idx], n[idx], gt_mesh, sensor)
    return out


def face_direction(normals) -> np.ndarray:
    """'+x' .. '-z': the dominant axis of each normal."""
    ax = np.abs(normals).argmax(1)
    neg = normals[np.arange(len(normals)), ax] < 0
    return np.array(FACE_DIRECTIONS)[2 * ax + neg]


def hidden_miss_causes(gt_mesh, objects, sensor, spots, recon, truth_recon=None, tau=0.02, offset_m=0.015,
                       settings: ObjectMetricSettings | None = None) -> dict:
    """{object: {hidden, missed, no_lit_segment, labels, fit, outside, inside, by_face: {dir: missed}}}.

    objects: [(name, trimesh)] as evaluate loads them; spots: (3,) first bounces; truth_recon: the mesh of
    a fit with truth labels (None: `labels` and `fit` are not split, `lit_segment` counts both)."""
    from scipy.spatial import cKDTree
    s = settings or ObjectMetricSettings()
    rec = Surface(recon, sample_count(recon.area, s.recon_samples_per_m2, 20_000, 400_000), s.seed + 4)
    tru = None if truth_recon is None else Surface(truth_recon, sample_count(
        truth_recon.area, s.recon_samples_per_m2, 20_000, 400_000), s.seed + 4)
    out = {}
    for i, (name, m) in enumerate(objects):      # the same samples, seeds and contact rule as evaluate's
        os_ = Surface(m, s.gt_samples_per_object, s.seed + 10 + i)
        rest = rest_of_scene(gt_mesh, objects, i)
        rs = (None if rest is None else
              Surface(rest, sample_count(rest.area, s.scene_samples_per_m2, 20_000, 300_000), s.seed + 30 + i))
        keep = ~contact_samples(os_, rs, s.contact_m)
        g, gf = os_.samples[keep], os_.sample_faces[keep]
        nrm = os_.mesh.face_normals[gf]
        hid = ~sensor_visible(g, nrm, gt_mesh, sensor)
        p, n = g[hid], nrm[hid]
        miss = rec.distance(p) >= tau
        lit = lit_segment_passes(p + offset_m * n, gt_mesh, spots, sensor)
        _, j = cKDTree(rec.samples).query(p)
        outside = np.einsum("ij,ij->i", rec.samples[j] - p, n) > 0
        faces = face_direction(n)
        row = {"hidden": int(len(p)), "missed": int(miss.sum()), "recall": float(1 - miss.mean()) if len(p) else None,
               "no_lit_segment": int((miss & ~lit).sum()), "outside": int((miss & outside).sum()),
               "inside": int((miss & ~outside).sum()),
               "by_face": {f: int((miss & (faces == f)).sum()) for f in FACE_DIRECTIONS if (faces == f).any()}}
        if tru is None:
            row["lit_segment"] = int((miss & lit).sum())
        else:
            got = tru.distance(p) < tau
            row["labels"], row["fit"] = int((miss & lit & got).sum()), int((miss & lit & ~got).sum())
            row["truth_labels_recall"] = float(got.mean()) if len(p) else None
        out[name] = row
    return out


def main(argv=None) -> int:
    import argparse
    import json

    import trimesh

    from ..contract.dataset import load_dataset
    from ..mesh_export import load_mesh_world
    from .report import load_gt_objects
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("mesh")
    ap.add_argument("truth_label_mesh", nargs="?")
    a = ap.parse_args(argv)
    ds = load_dataset(a.dataset)
    gt = trimesh.load(ds.path(ds.manifest.ground_truth.mesh_file), force="mesh", process=False)
    objects, _ = load_gt_objects(ds, gt)
    spots = [np.asarray(sp.first_bounce, np.float64) for sp in ds.manifest.enabled_spots if sp.first_bounce is not None]
    # the fit's mesh in the world frame (a .glb is written Y-up)
    res = hidden_miss_causes(gt, objects, ds.sensor, spots, load_mesh_world(a.mesh),
                             load_mesh_world(a.truth_label_mesh) if a.truth_label_mesh else None)
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
