"""Where to aim the next laser spots: a spot advisor from a first reconstruction (issue 11).

Part of the hidden space is crossed by no lit secondary segment (spot -> visible lit point) of a capture:
the fast fit keeps it as shadow hull (`voxel_evidence.evidence_grid` label 0), bounded by shadows only. A new spot l
whose segments l -> x (x: a point the sensor sees) pass that space measures it: a lit segment carves every
hull voxel it crosses, a shadowed one says a blocker lies along it. The advisor scores candidate spots by
the hull voxels their segments would carve, under a simple model: each hull voxel is occupied with
probability `occupied_prior`, independently, so a segment crossing n hull voxels (and no surface the fit
is sure of) is lit with probability (1 - p)^n. A candidate's value for a hull voxel is the best such
probability over its segments; the spots already in the capture hold their own values (what they
measured), and N candidates are chosen greedily by the expected number of hull voxels they add
(coverage: a candidate that repeats an existing spot's segments gains nothing).

Back faces (session 13): hidden voxels within SURFACE_BAND_VOXELS of a measured surface count as that
surface's thickness (solid), except where they bound free space on their side away from the sensor: the
back face of a part (a table top's underside, a box's far side). Those FACE voxels are targets that light
passes without the occupancy prior's attenuation (a segment along the face, lit or shadowed, places it):
with them thin-structures' two-pass capture lights the table's underside, which the hull-only score left to
the first pass (docs/reconstruction.md "Back faces as targets").

Candidates: spread-out points of the sensor-visible surface (`contract.spots.select_diverse_spots`, the
one diversity rule) that the laser reaches; and laser directions beyond the sensor's view, which land on
the fit's surface (a galvo scans wider than the camera sees; such spots are placed by preprocessing from
their two-bounce returns, see docs/reconstruction.md "Laser spots outside the sensor's view"), up to a set
angle or (none) as far beyond the view as the capture's own spots lie. Off by default: such a spot lands
where the fit puts a surface in space no camera ray saw, and twice it met a real object the fit had not
placed (outside-fov), lit only surfaces the sensor does not see, and preprocessing refused the dataset.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..contract.errors import PlatolidarError, SettingsError
from ..contract.spots import select_diverse_spots
from .fields import GridBox
from .spot_geometry import (PATH_MARGIN_M, _longest_lit_path, _path_range_end, beyond_view_directions,
                            degrees_beyond_view)
from .spot_refine import covered_total, refine_spots
from .spot_voxels import FACE, HULL, landing_points, laser_reaches, segment_values, voxel_classes
from .visible_surface_init import visible_surface

@dataclass
class AdviceSettings:
    """Settings of the spot advisor (`platolidar advise-spots`)."""

    add: int = 4                      # spots to advise
    candidates: int = 300             # spread-out candidate spots scored (on the sensor-visible surface)
    occupied_prior: float = 0.25      # chance that one shadow-hull voxel is really occupied (the lit-segment model)
    beyond_view_deg: float | None = 0.0   # also laser directions up to this far beyond the sensor's view (0: in
                                      # view only; none: as far beyond as the capture's own farthest spot)
    pixel_stride: int = 2             # segments to every n-th pixel along each image axis
    back_faces: bool = False          # also aim at the fit's hidden back faces next to a measured surface (a table
                                      # top's underside): targets light passes unattenuated. Opt-in: 8 + 8 advised
                                      # lifts thin-structures (hidden R 0.690 -> 0.726 at 300 candidates, 0.789 at
                                      # 1000) but not organic-occluded (0.898 -> 0.893 / 0.875) nor dark-room
                                      # (0.828 -> 0.786 / 0.804); docs/reconstruction.md, session 13
    refine_voxels: float = 0.0        # then move each chosen spot to the best sensor-visible point within this many
                                      # voxels, given the other spots (recon/spot_refine.py; 0: off). Opt-in: at 4 it
                                      # raises the expected coverage 2-14 %, but 8 + 8 two-pass thin-structures lost
                                      # (hidden R 0.789 -> 0.736), organic-occluded +0.011 / -0.012 at seeds 0 / 1
                                      # (docs/reconstruction.md, session 14)
    seed: int = 0                     # candidate choice (select_diverse_spots)
    device: str = "cpu"               # torch device
    threads: int | None = None        # CPU threads for torch

    SETTINGS_META = {"add": {"range": (1, None)}, "candidates": {"range": (1, None)},
                     "occupied_prior": {"range": (0.0, 1.0)}, "beyond_view_deg": {"range": (0.0, 60.0),
                                                                                   "unit": "deg"},
                     "pixel_stride": {"range": (1, None)},
                     "refine_voxels": {"range": (0.0, 20.0), "unit": "voxels"}, "threads": {"range": (1, None)}}

    def validate(self):
        if not 0.0 < self.occupied_prior < 1.0:
            raise SettingsError("occupied_prior", f"expected a probability in (0, 1), got {self.occupied_prior}")


@dataclass
class AdvisedSpot:
    point: np.ndarray                 # (3,) world, m: where the laser lands (aim the laser here)
    pixel: tuple | None               # (col, row) of the sensor pixel that sees it; None beyond the view
    voxels: int                       # hull voxels its segments reach with no sure surface in the way
    gain: float                       # expected hull voxels carved that no earlier spot reaches


@dataclass
class Advice:
    spots: list                       # AdvisedSpot, in choice order
    existing: np.ndarray              # (S, 3) the capture's spot points
    hull_voxels: int                  # unbounded hull voxels of the fit (in the measured space, still occupied)
    reached_by_existing: int          # of those, reached by an existing spot's segment
    covered: float                    # expected hull voxels the existing and advised spots cover (the objective)
    voxel_m: float
    notes: list = field(default_factory=list)
    details: dict = field(default_factory=dict, repr=False)   # the grid's arrays, for diagnostics

    def spot_list(self, include_existing: bool = False) -> str:
        """The simulator's --spot-list text 'x,y,z;...' (m)."""
        pts = [*(self.existing if include_existing else []), *(s.point for s in self.spots)]
        return ";".join(",".join(f"{v:.4f}" for v in p) for p in pts)

    def to_json(self) -> dict:
        return {"advised": [{"point": [round(float(v), 4) for v in s.point],
                             "pixel": None if s.pixel is None else [int(s.pixel[0]), int(s.pixel[1])],
                             "voxels_reached": s.voxels, "expected_voxels_carved": round(s.gain, 1)}
                            for s in self.spots],
                "existing": [[round(float(v), 4) for v in p] for p in self.existing],
                "hull_voxels": self.hull_voxels, "hull_voxels_reached_by_existing": self.reached_by_existing,
                "expected_voxels_covered": round(self.covered, 1),
                "voxel_m": self.voxel_m, "spot_list": self.spot_list(),
                "spot_list_with_existing": self.spot_list(True), "notes": self.notes}


def load_fit_volume(fit_dir):
    """(opacity (nx, ny, nz), bbox_min, bbox_max, level, fit settings dict) from a `fit --out` folder."""
    root = Path(fit_dir)
    vol_path, rep_path = root / "volume.npz", root / "fit.json"
    for p in (vol_path, rep_path):
        if not p.is_file():
            raise PlatolidarError(f"{p}: no such file (expected the output folder of `platolidar fit --mode fast`)")
    try:
        with np.load(vol_path) as z:
            opacity, lo, hi, level = z["opacity"], z["bbox_min"], z["bbox_max"], float(z["level"])
        report = json.loads(rep_path.read_text())
        settings = {**report["settings"], "source_hash": report.get("source_hash")}
    except (KeyError, ValueError, OSError, json.JSONDecodeError) as exc:
        raise PlatolidarError(f"{root}: unreadable fit output ({exc})") from None
    if opacity.ndim != 3 or not np.all(np.isfinite(opacity)):
        raise PlatolidarError(f"{vol_path}: opacity: expected a finite 3-D grid, got shape {opacity.shape}")
    if settings.get("mode") != "fast":
        raise PlatolidarError(f"{rep_path}: settings.mode is {settings.get('mode')!r}: the advisor needs a "
                              f"`--mode fast` fit (its grid and shadow hull)")
    return opacity, lo, hi, level, settings


def spot_normals(box, opacity, spots, surface_points, surface_normals):
    """Unit normals (N, 3) of the surfaces at spots (N, 3): the sensor-visible point's normal where one lies
    within 1.5 voxels, else minus the fit's opacity gradient around the spot's voxel (zero where flat: no
    facing test then). A Lambertian spot lights only the half-space in front of its surface."""
    d, i = _nearest(surface_points, spots)
    out = torch.where((d <= 1.5 * box.voxel)[:, None], surface_normals[i], torch.zeros_like(spots))
    need = torch.nonzero(d > 1.5 * box.voxel).squeeze(1)
    if len(need):
        vol = torch.as_tensor(opacity, dtype=torch.float32, device=spots.device)
        grad = torch.stack(torch.gradient(vol), -1)                  # (nx, ny, nz, 3), per voxel
        pooled = torch.nn.functional.avg_pool3d(grad.permute(3, 0, 1, 2)[None], 3, 1, 1)[0].permute(1, 2, 3, 0)
        idx, _ = box.cell_index(spots[need])
        g = -pooled[idx[:, 0], idx[:, 1], idx[:, 2]]
        out[need] = g / torch.linalg.vector_norm(g, dim=1, keepdim=True).clamp(min=1e-9)
    return out


def _nearest(points, queries, chunk: int = 256):
    """Distance and index of the nearest of `points` (P, 3) to each of `queries` (Q, 3)."""
    ds, ids = [], []
    for q in torch.split(queries, chunk):
        d, i = torch.cdist(q, points).min(1)
        ds.append(d)
        ids.append(i)
    return torch.cat(ds), torch.cat(ids)


def advise_spots(dataset, fit_dir, settings: AdviceSettings | None = None, measurements=None) -> Advice:
    """Advise `settings.add` laser spots for `dataset` from its fast fit in `fit_dir` (see the module doc).
    measurements: the dataset's `Measurements` when already preprocessed (else preprocessed here)."""
    from types import SimpleNamespace

    from ..device import resolve_device
    from .api import load_source
    from .data import build_ray_data

    s = settings or AdviceSettings()
    s.validate()
    opacity, lo, hi, level, fit_settings = load_fit_volume(fit_dir)
    dev = resolve_device(s.device, s.threads)
    meas, src_hash = load_source(measurements if measurements is not None else dataset, progress=False, device=dev)
    if fit_settings.get("source_hash") not in (None, src_hash):
        raise PlatolidarError(f"{fit_dir}: fitted to other data than {dataset} (fit.json source_hash "
                              f"{fit_settings['source_hash'][:24]}..., the data's {src_hash[:24]}...)")
    data = build_ray_data(meas).to(dev)
    if not bool(torch.isfinite(data.visible_depth).any()):
        raise PlatolidarError(f"{dataset}: no visible depth: the advisor needs the surface the sensor sees")
    fast = fit_settings["fast"]
    shape = opacity.shape
    voxel = float(np.max((np.asarray(hi) - np.asarray(lo)) / np.asarray(shape)))
    box = GridBox.exact(lo, voxel, shape).to(dev)
    meta = {"camera_to_world": np.asarray(meas.camera_to_world), "fov_rad": meas.fov_rad, "fov_axis": meas.fov_axis}
    sensor = SimpleNamespace(width=meas.width, height=meas.height, fov_rad=meas.fov_rad, fov_axis=meas.fov_axis,
                             camera_to_world=meta["camera_to_world"])
    fit_offset = max(fit_settings["loss"]["secondary_offset_m"], fast["secondary_offset_voxels"] * box.voxel)
    surface = visible_surface(data, box)    # the voxel classes' and the segments' far ends (computed once)
    cls = voxel_classes(data, box, opacity, level, fast, meta, fit_offset, back_faces=s.back_faces, surface=surface)
    hull_flat = torch.nonzero((cls == HULL) | (cls == FACE)).squeeze(1)
    hull_index = torch.full((cls.numel(),), -1, dtype=torch.long, device=dev)
    hull_index[hull_flat] = torch.arange(len(hull_flat), device=dev)
    n_hull = len(hull_flat)
    notes = [] if n_hull else ["the fit has no unbounded shadow hull in the measured space: no spot to advise"]
    off = max(fit_offset, fast["surface_margin_voxels"] * box.voxel)
    step = fast["step_voxels"] * box.voxel

    # the segments' far ends: the sensor-visible points (every stride-th pixel) and their normals
    h, w = meas.height, meas.width
    pts_all, nrm_all = (torch.as_tensor(a, dtype=torch.float32, device=dev) for a in surface)
    valid = torch.isfinite(data.visible_depth).reshape(h, w)
    pix = torch.nonzero(valid)                                  # (row, col) of each visible point, row-major
    on_grid = (pix[:, 0] % s.pixel_stride == 0) & (pix[:, 1] % s.pixel_stride == 0)
    xs, ns = pts_all[on_grid], nrm_all[on_grid]

    def values_of(spot: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
        # Lambertian both ways: x faces the spot and the spot's surface faces x
        facing = (((spot - xs) * ns).sum(1) > 0) & (((xs - spot) * normal).sum(1) >= 0)
        return segment_values(box, cls, hull_index, n_hull, xs[facing], spot.expand_as(xs[facing]), off, step,
                               s.occupied_prior, dev)

    covered = torch.zeros(n_hull, device=dev)
    for spot, normal in zip(data.spot_points, spot_normals(box, opacity, data.spot_points, pts_all, nrm_all)):
        covered = torch.maximum(covered, values_of(spot, normal))

    # candidates: spread-out visible points the laser reaches (+ laser directions beyond the view)
    end_m = _path_range_end(dataset) if measurements is None else None

    def laser_gets_to(p):       # the laser's ray gets to the points p (N, 3) (always when it starts at the sensor)
        if float(torch.linalg.vector_norm(data.laser_origin - data.sensor_origin)) <= 1e-6:
            return torch.ones(len(p), dtype=torch.bool, device=dev)
        return laser_reaches(box, cls, data.laser_origin, p, off, step)

    def in_range(p, n):         # the sensor records every two-bounce return of spots p with normals n
        if end_m is None:
            return torch.ones(len(p), dtype=torch.bool, device=dev)
        return _longest_lit_path(p, n, pts_all, nrm_all, data) < end_m - PATH_MARGIN_M

    rng = np.random.default_rng(s.seed)
    cand_pts, cand_src = [], []     # cand_src: the candidate's index into pts_all (None: beyond the view)
    pick = select_diverse_spots(pts_all.cpu().numpy(), nrm_all.cpu().numpy(), s.candidates, rng)
    p_in = pts_all[torch.as_tensor(pick, device=dev)]
    reach = laser_gets_to(p_in)
    p_in, pick = p_in[reach], pick[reach.cpu().numpy()]
    cand_pts.append(p_in)
    cand_src += [int(i) for i in pick]
    beyond = s.beyond_view_deg
    if beyond is None:          # the laser is known to reach as far as the capture's own spots
        beyond = min(degrees_beyond_view(sensor, data.spot_points.cpu().numpy()), 60.0)
        if beyond > 0:
            notes.append(f"candidates up to {beyond:.0f} deg beyond the view: as far as the capture's spots")
    if beyond > 0:
        dirs = torch.as_tensor(beyond_view_directions(sensor, beyond), dtype=torch.float32, device=dev)
        land = landing_points(box, cls, data.laser_origin, dirs, step)
        land = land[torch.isfinite(land).all(1)]
        if len(land):
            keep = select_diverse_spots(land.cpu().numpy(), None, max(1, s.candidates // 2), rng)
            cand_pts.append(land[torch.as_tensor(keep, device=dev)])
            cand_src += [None] * len(keep)
        else:
            notes.append(f"no laser direction within {beyond:.0f} deg beyond the view lands on the fit's surface")
    cand = torch.cat(cand_pts)
    cand_nrm = spot_normals(box, opacity, cand, pts_all, nrm_all)
    fits = in_range(cand, cand_nrm)
    if not bool(fits.all()):
        notes.append(f"{int((~fits).sum())} candidate(s) left out: their two-bounce paths would run past the "
                     f"sensor's last bin ({end_m:.2f} m)")
    cand, cand_nrm = cand[fits], cand_nrm[fits]
    cand_src = [p for p, ok in zip(cand_src, fits.tolist()) if ok]
    if len(cand) == 0:
        raise PlatolidarError(f"{dataset}: no candidate spot: no visible surface point the laser reaches")
    cand_values = torch.stack([values_of(p, n) for p, n in zip(cand, cand_nrm)])     # (C, n_hull)

    by_existing = int((covered > 0).sum())
    details = {"box": box, "hull_flat": hull_flat, "candidates": cand, "candidate_values": cand_values,
               "existing_values": covered.clone()}
    chosen = []
    for _ in range(min(s.add, len(cand))):
        gain = (cand_values - covered).clamp(min=0).sum(1)
        if chosen:
            gain[torch.as_tensor(chosen, device=dev)] = -1.0
        j = int(torch.argmax(gain))
        if float(gain[j]) <= 0:
            if n_hull:
                notes.append(f"only {len(chosen)} spot(s) add anything: no other candidate reaches a hull voxel "
                             f"they do not")
            break
        chosen.append(j)
        covered = torch.maximum(covered, cand_values[j])
    points, values = [cand[j] for j in chosen], [cand_values[j] for j in chosen]
    details.update(covered_greedy=float(covered.sum()), greedy=chosen)
    if s.refine_voxels > 0 and chosen:
        def usable(ids):
            return laser_gets_to(pts_all[ids]) & in_range(pts_all[ids], nrm_all[ids])

        def values_at(ids):
            return torch.stack([values_of(pts_all[k], nrm_all[k]) for k in ids.tolist()])

        src, values, moved = refine_spots([cand_src[j] for j in chosen], values, details["existing_values"],
                                          pts_all, usable, values_at, s.refine_voxels * box.voxel, rng)
        points = [cand[j] if k is None else pts_all[k] for j, k in zip(chosen, src)]
        notes.append(f"refined within {s.refine_voxels:g} voxels: {moved} of {len(chosen)} spot(s) moved, expected "
                     f"hull voxels covered {details['covered_greedy']:.0f} -> "
                     f"{covered_total(details['existing_values'], values):.0f}")
    else:
        src = [cand_src[j] for j in chosen]
    spots, cov = [], details["existing_values"]
    for p, k, v in zip(points, src, values):    # gains in choice order, after any refinement
        spots.append(AdvisedSpot(point=p.cpu().double().numpy(), pixel=None if k is None else
                                 (int(pix[k, 1]), int(pix[k, 0])), voxels=int((v > 0).sum()),
                                 gain=float((v - cov).clamp(min=0).sum())))
        cov = torch.maximum(cov, v)
    return Advice(spots=spots, existing=data.spot_points.cpu().double().numpy(), hull_voxels=n_hull,
                  reached_by_existing=by_existing, covered=float(cov.sum()), voxel_m=box.voxel, notes=notes,
                  details=details)
