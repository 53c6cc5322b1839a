"""Pictures a person reads: normal-shaded renders and depth-error images from a few scene-aware viewpoints.

Renders are Embree ray casts (torch_recon.contract.analytic.first_hits), one-sided like the evaluation's depth
(faces seen from behind are passed through), shaded by a headlight: 0.15 + 0.85 |cos| between the view ray
and the face normal, with dark outlines on the near side of depth jumps. Viewpoints (`picture_viewpoints`): the sensor's own view, one from behind the objects
(the far side of the room), one from under the ceiling looking down, one from inside the room at an angle;
each is moved towards the objects until it lies in free space (contract.test_views.free_space).
"""

from __future__ import annotations

import math

import numpy as np

from ..contract.analytic import first_hits
from ..contract.frames import camera_ray_directions, look_at_c2w
from ..contract.test_views import free_space

PICTURE_FOV_RAD = math.radians(80.0)


def shaded_render(mesh, c2w, width, height, fov_rad=PICTURE_FOV_RAD, one_sided=True):
    """(grey image (H, W) in [0, 1], range (H, W) with inf on misses) of a mesh from a camera."""
    c2w = np.asarray(c2w, np.float64)
    dirs = (camera_ray_directions(width, height, fov_rad, "x") @ c2w[:3, :3].T).reshape(-1, 3)
    img = np.zeros(len(dirs))
    rng = np.full(len(dirs), np.inf)
    if mesh is not None and len(mesh.faces):
        hit, _, tri, dist = first_hits(mesh, np.broadcast_to(c2w[:3, 3], dirs.shape), dirs, one_sided)
        cos = np.abs(np.einsum("ij,ij->i", dirs[hit], mesh.face_normals[tri[hit]]))
        img[hit] = 0.15 + 0.85 * cos
        rng[hit] = dist[hit]
    img, rng = img.reshape(height, width), rng.reshape(height, width)
    return img * silhouette_shade(rng), rng


def silhouette_shade(rng, jump=0.03):
    """0.35 on pixels where the range jumps by more than `jump` (relative) to a neighbour, else 1: outlines
    that separate a panel from the parallel wall behind it, which a headlight shades alike."""
    r = np.where(np.isfinite(rng), rng, 1e6)
    edge = np.zeros(r.shape, bool)
    for a, b in ((r[1:, :], r[:-1, :]), (r[:, 1:], r[:, :-1])):
        j = np.abs(a - b) > jump * np.minimum(a, b)
        e = np.zeros(r.shape, bool)
        if a.shape[0] < r.shape[0]:
            e[1:, :] |= j & (a < b)
            e[:-1, :] |= j & (b < a)
        else:
            e[:, 1:] |= j & (a < b)
            e[:, :-1] |= j & (b < a)
        edge |= e
    return np.where(edge, 0.35, 1.0)


def _free_towards(gt_mesh, start, target, clearance=0.1, steps=40):
    """The first point on start -> target (evenly stepped, up to 90 %) in free space (else the last)."""
    start, target = np.asarray(start, float), np.asarray(target, float)
    pts = [start + (target - start) * (i / steps) * 0.9 for i in range(steps + 1)]
    ok, _ = free_space(gt_mesh, pts, clearance)
    return pts[int(np.argmax(ok))] if ok.any() else pts[-1]


def picture_viewpoints(gt_mesh, object_meshes, sensor_c2w) -> list:
    """[(title, c2w)]: sensor side, behind, top, inside (see module doc)."""
    lo, hi = np.asarray(gt_mesh.bounds[0], float), np.asarray(gt_mesh.bounds[1], float)
    if object_meshes:
        olo = np.min([m.bounds[0] for m in object_meshes], axis=0)
        ohi = np.max([m.bounds[1] for m in object_meshes], axis=0)
    else:
        olo, ohi = lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo)
    centre = 0.5 * (olo + ohi)
    sensor_c2w = np.asarray(sensor_c2w, float)
    s = sensor_c2w[:3, 3]
    away = np.array([centre[0] - s[0], centre[1] - s[1], 0.0])
    away /= max(np.linalg.norm(away), 1e-9)
    side = np.array([-away[1], away[0], 0.0])
    span = float(np.linalg.norm(hi - lo))
    views = [("sensor view", sensor_c2w)]
    behind = _free_towards(gt_mesh, centre + away * span + np.array([0, 0, 0.4]), centre)
    views.append(("from behind the objects", look_at_c2w(behind, centre)))
    top = _free_towards(gt_mesh, np.array([centre[0], centre[1], hi[2] - 0.08]) - 0.3 * away, centre)
    views.append(("from above", look_at_c2w(top, centre, up=tuple(away))))
    oblique = _free_towards(gt_mesh, centre + (0.3 * away + side) * span * 0.5 + np.array([0, 0, 0.5]), centre)
    views.append(("inside the room, oblique", look_at_c2w(oblique, centre)))
    return views


def picture_grid(gt_mesh, recon, views, size=192, vmax_err=0.25):
    """Per viewpoint: (title, GT shade, reconstruction shade, |range error| with nan where GT misses)."""
    rows = []
    for title, c2w in views:
        g_img, g_rng = shaded_render(gt_mesh, c2w, size, size)
        r_img, r_rng = shaded_render(recon, c2w, size, size)
        err = np.where(np.isfinite(g_rng), np.abs(np.where(np.isfinite(r_rng), r_rng, 0.0) - g_rng), np.nan)
        rows.append((title, g_img, r_img, err))
    return rows


def plot_grid(rows, path, vmax_err=0.25, table_text=None, title=None):
    """One PNG: a row per viewpoint (GT | reconstruction | depth error with a colour bar), optional text."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rows)
    extra = 1 if table_text else 0
    height = 3.3 * n + 3.0 * extra
    fig = plt.figure(figsize=(11, height))
    gs = fig.add_gridspec(n + extra, 3, height_ratios=[1] * n + ([0.9] * extra))
    cmap = matplotlib.colormaps["magma"].with_extremes(bad="#3060a0")   # blue: the GT ray hits nothing
    for i, (vt, g, r, e) in enumerate(rows):
        for j, (img, t) in enumerate(((g, "ground truth"), (r, "reconstruction"))):
            ax = fig.add_subplot(gs[i, j])
            ax.imshow(img, cmap="gray", vmin=0, vmax=1)
            ax.set_title(f"{vt}: {t}", fontsize=9)
            ax.axis("off")
        ax = fig.add_subplot(gs[i, 2])
        im = ax.imshow(np.ma.masked_invalid(e), cmap=cmap, vmin=0, vmax=vmax_err)
        ax.set_title(f"{vt}: |depth error| (m)", fontsize=9)
        ax.axis("off")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    if table_text:
        ax = fig.add_subplot(gs[n, :])
        ax.axis("off")
        ax.text(0.0, 1.0, table_text, family="monospace", fontsize=8, va="top")
    if title:
        fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / height if title else 1))   # room for the title above the panels
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_test_view_errors(preds, gts, indices, path, max_depth, vmax_err=0.5):
    """Chosen test views: GT range | reconstruction range | |error|, titled, with colour bars."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(indices), 3, figsize=(10, 3.1 * len(indices)), squeeze=False)
    for row, i in zip(axes, indices):
        g, p = gts[i], preds[i]
        e = np.where(np.isfinite(g), np.abs(np.where(np.isfinite(p), p, 0.0) - g), np.nan)
        l1 = float(np.nanmean(e)) if np.isfinite(e).any() else float("nan")
        for ax, img, t, cm, vmax in ((row[0], g, "ground truth range (m)", "viridis", max_depth),
                                     (row[1], p, "reconstruction range (m)", "viridis", max_depth),
                                     (row[2], e, f"|error| (m), view L1 {l1:.3f} m", "magma", vmax_err)):
            im = ax.imshow(np.ma.masked_invalid(img), cmap=cm, vmin=0, vmax=vmax)
            ax.set_title(f"test view {i}: {t}", fontsize=9)
            ax.axis("off")
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.02)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
