"""The fast reconstructor (`FastModel`) behind the interface both reconstructors share
(`model_interface.ReconstructionModel`; the platonerf one: platonerf_model.py); both use the paper's losses.

A model owns its field(s) and optimiser and exposes: `loss(idx, step, total, gen)`, `before_step`,
`after_step`, `render_depth(origins, dirs)` (evaluation, no grad), `density_volume()` (for the mesh) and
`state_dict` / `load_state_dict` (checkpoints).
"""

from __future__ import annotations

from functools import partial

import numpy as np
import torch
import torch.nn.functional as F

from ..mesh_export import InwardSmoothing
from .adam import GridAdam
from .config import FitConfig
from .data import RayData, lit_path_tolerance, unexplained_lit, without_lit, without_shadowed
from .fields import DensityGrid, GridBox, dilate_cube
from .hull_subvoxel import SHRINK_ITERATIONS, binary_boundary_inset, shrinkable_hull
from .freeze_masks import frozen_voxels, masked_gradient, masks_gradient, measured_trainable, thin_part_mask
from .init import grid_bbox, in_view, initial_grid, room_planes, start_field_reads_planes
from .losses import all_finite
from .model_interface import ReconstructionModel, pair_loss, rendered_depth
from .renderer import render_pruned
from .sampler import ray_box
from .smoothness import NormalConsistencyPrior
from .thin_parts import thin_part_cloud
from .visible_surface_init import (coarse_sensor_seen_free, in_front_of_visible_surface, seen_depth,
                                   seen_free_points, surface_offset, visible_surface)
from .voxel_evidence import in_plane_pairs


class FastModel(ReconstructionModel):
    """Explicit density grid, initialised from the measurements, occupancy-pruned marching."""

    def __init__(self, data: RayData, cfg: FitConfig, meas_meta: dict):
        self.data, self.cfg, self.fc = data, cfg, cfg.fast
        self.meta = meas_meta
        self.device = data.pixel_dirs.device
        self.bbox = grid_bbox(data, self.fc.resolution, self.fc.bbox_margin_voxels)
        self._surface = None    # (voxel, visible surface) of the latest grid: the start field and the mesh share it
        self._planes = None     # (voxel, room_planes) likewise: the start field, the edge freeze and the plane snap
        self._thin_points = None    # (voxel, thin_part_cloud) of the latest grid: the start field and `thin_parts`
        self.evidence = None        # the latest start field's VoxelEvidence: the mesh export reads it back
        self._start_raw = None      # ... and its raw density (nx, ny, nz), where the hull's placement reads it
        self._surface_field = None  # (what it depends on, surface_volume()): the export asks for it twice
        self.level = 0 if self.fc.coarse_fraction > 0 and self.fc.coarse_resolution < self.fc.resolution else 1
        self.grid, self.free = self._initial(self.fc.coarse_resolution if self.level == 0 else self.fc.resolution)
        # lit pairs whose light came from another surface in the pixel: the start field carved from where their
        # own path puts it; training, which pairs each with the rendered depth, leaves them out
        voxel = float(torch.as_tensor(self.bbox[1] - self.bbox[0]).max()) / self.fc.resolution
        tol = lit_path_tolerance(data, voxel, self.fc.lit_path_tolerance_voxels)
        self._training_data = without_lit(data, unexplained_lit(data, tol)) if tol > 0 else data
        if self.fc.explain_in_plane_voxels > 0:    # a spot in the pixel's own plane: no shadow evidence (voxel_evidence)
            plane = in_plane_pairs(data, self.visible_surface(self.grid.box), self.fc.explain_in_plane_voxels * voxel)
            self._training_data = without_shadowed(self._training_data, plane)
        self._hook = None
        self._thin_index = None     # (thin_parts, their flat indices) for the gradient mask
        self._trainable_cast = None     # (trainable, the same mask as the gradient's dtype): cast once
        self._normal_cells = None
        self._set_measured_mask(self.grid.raw)
        self._set_freeze_masks(self.grid.box)
        self.occupancy = None
        self.refresh_occupancy()
        self.make_optimizer()

    def _initial(self, res=None, box=None):
        """The start field and its free space on `box`, or on a new box of `res` voxels along the longest side; its
        evidence (and, for the hull's inward smoothing and the plane snap, its raw density) are kept for the mesh
        export."""
        box = GridBox(self.bbox[0], self.bbox[1], res).to(self.device) if box is None else box
        seen = coarse_sensor_seen_free(self.data, box, self.fc, self.meta)
        planes = self.room_planes(box) if start_field_reads_planes(self.fc) else []
        start, free, self.evidence = initial_grid(self.data, box, self.fc, self.offset_for(box.voxel), self._view(box),
                                                  self.visible_surface(box), seen_free=seen,
                                                  thin_points=self.thin_points(box), planes=planes)
        # a copy (training changes the grid in place): the hull's shrink and the plane snap tell placed voxels by it
        if self.fc.mesh_hull_shrink_voxels > 0 or self.fc.mesh_plane_snap_voxels > 0:
            self._start_raw = start.raw_xyz().detach().clone()
        return start, free

    def start_evidence(self):
        """The current grid's start-field `VoxelEvidence` (labels, lit crossings, restored blockers), built again only
        where none was built on this grid (a resumed fit; the fine level of a coarse-to-fine fit without freezing)."""
        if self.evidence is None or tuple(self.evidence.label.shape) != tuple(self.grid.box.shape):
            self._initial(box=self.grid.box)
        return self.evidence

    def training_data(self, data: RayData) -> RayData:
        return self._training_data if data is self.data else data

    def visible_surface(self, box):
        """`visible_surface` (points, normals) for `box`; it depends on the box's voxel size only, so it
        is computed once per grid level."""
        if self._surface is None or self._surface[0] != box.voxel:
            self._surface = (box.voxel, visible_surface(self.data, box))
        return self._surface[1]

    def room_planes(self, box):
        """`init.room_planes` (the planes bounding the observation) for `box`'s voxel size, computed once per grid
        level: every setting that reads them shares them (RANSAC, 0.3-0.5 s a time: session 19 fitted them three
        times per fit)."""
        if self._planes is None or self._planes[0] != box.voxel:
            self._planes = (box.voxel, room_planes(self.data, box, self.fc, self.visible_surface(box)))
        return self._planes[1]

    def thin_points(self, box):
        """`thin_part_cloud` (N, 3) for `box`'s voxel size, computed once per grid level; None where the fit
        places no thin parts (`fast.nearest_surface` off, or no earliest returns measured)."""
        if not (self.fc.nearest_surface and self.data.nearest_depth is not None):
            return None
        if self._thin_points is None or self._thin_points[0] != box.voxel:
            self._thin_points = (box.voxel, thin_part_cloud(self.data, box.voxel, self.fc.thin_part_edges,
                                                            self.fc.thin_part_centre))
        return self._thin_points[1]

    @property
    def skip_warmup(self) -> bool:
        """With the sensor-measured voxels frozen the distance loss has nothing left to move (camera rays
        stop in the frozen surface band), so its warm-up would be idle steps."""
        return self.fc.freeze_measured

    def _set_freeze_masks(self, box):
        """The thin parts' mask and the frozen voxels of the grid `box` (freeze_masks.py)."""
        self.thin_parts = thin_part_mask(self, box)
        self.frozen_voxels = frozen_voxels(self, box)

    def _set_measured_mask(self, raw):
        """`trainable` (freeze_masks.measured_trainable) and `raw_start` (the start values the anchor prior pulls to)
        of the start field `raw`; both None when neither freezing nor the anchor asks for them."""
        self.trainable = measured_trainable(self, raw)
        self.raw_start = None if self.trainable is None else raw.detach().clone()

    def fixed_depth(self, px):
        """The visible depth of pixels `px` where the surface band is frozen (NaN where unknown)."""
        return self.data.visible_depth[px] if self.fc.freeze_measured else None

    def _view(self, box):
        return in_view(self.data, box, self.meta["camera_to_world"], self.meta["fov_rad"], self.meta["fov_axis"])

    def free_evidence(self) -> np.ndarray:
        """Voxels (nx, ny, nz) the measurements show empty, on the current grid (for the mesh export)."""
        if tuple(self.free.shape) != tuple(self.grid.box.shape):
            self.free = self._initial(box=self.grid.box)[1]
        free = self.free
        if self.fc.mesh_front_of_visible:   # measured surfaces keep their faces where no camera ray passed
            box = self.grid.box
            vol, iso = self.surface_volume()
            front = in_front_of_visible_surface(self.visible_surface(box), box, torch.from_numpy(vol < iso))
            free = free | front.to(free.device)
        return free.cpu().numpy()

    def free_points_test(self):
        """`seen_free_points` for the mesh's face test (None with `fast.mesh_seen_free` off): the sensor saw
        through a point between its pixel rays too (its footprint), where no camera ray's march passed."""
        if not self.fc.mesh_seen_free:
            return None
        m = self.meta
        return seen_free_points(self.data, m["camera_to_world"], m["fov_rad"], m["fov_axis"], self.grid.box.voxel,
                                seen_depth(self.data, self.fc), corner_planes=self.fc.seen_free_corners)

    def offset_for(self, voxel):
        return max(self.cfg.loss.secondary_offset_m, self.fc.secondary_offset_voxels * voxel)

    @property
    def offset(self):
        return self.offset_for(self.grid.box.voxel)

    @property
    def step_len(self):
        return self.fc.step_voxels * self.grid.box.voxel

    def make_optimizer(self):
        self.optimizer = GridAdam(self.grid.parameters(), lr=self.fc.lr, eps=self.fc.adam_eps)     # torch.optim.Adam, bit for bit
        if self._hook is not None:      # one gradient mask at a time, also when called again on the same grid
            self._hook.remove()
            self._hook = None
        if masks_gradient(self):
            self._hook = self.grid.raw.register_hook(partial(masked_gradient, self))

    def refresh_occupancy(self):
        self._normal_prior = None       # the surface band moves with the field
        with torch.no_grad():
            tau = self.grid.density_scale * F.softplus(self.grid.raw) * self.grid.box.voxel
            occ = dilate_cube((tau > self.fc.occupancy_threshold).float(), 1) > 0     # max_pool3d(., 3, 1, 1)
            self.occupancy = occ[0, 0].permute(2, 1, 0).contiguous()
            # early termination must not stop too soon: the smallest raw density in a cell's neighbourhood
            # bounds the trilinear value from below, so its optical depth is a safe estimate
            raw_lo = -dilate_cube(-self.grid.raw, 1)
            tau_lo = self.grid.density_scale * F.softplus(raw_lo) * self.grid.box.voxel
            self.tau_step = (tau_lo[0, 0] * self.fc.step_voxels).permute(2, 1, 0).contiguous()

    def normal_prior(self) -> NormalConsistencyPrior:
        """The surface-normal prior on the current surface band (rebuilt with the occupancy)."""
        if self._normal_prior is None:
            iso = surface_offset(self.grid.density_scale, self.grid.box.voxel, max(self.fc.surface_slope, 1.0))
            cells, self._normal_cells = self._normal_cells, None     # from a checkpoint: the same cells as before
            self._normal_prior = NormalConsistencyPrior(self.grid.raw, iso, self.fc.normal_max_angle_deg, cells)
        return self._normal_prior

    def before_step(self, step: int, total: int) -> bool:
        """Coarse -> fine switch and occupancy refresh; True when the optimiser was rebuilt."""
        if self.level == 0 and step >= int(self.fc.coarse_fraction * total):
            self.grid = self.grid.upsampled(self.fc.resolution)
            self.level = 1
            if self.trainable is not None:  # the mask of the fine level: from its own start field (built
                start, self.free = self._initial(box=self.grid.box)     # once: free_evidence reuses `free`)
                self._set_measured_mask(start.raw)
            self._set_freeze_masks(self.grid.box)
            self.refresh_occupancy()
            self.make_optimizer()
            return True
        if step > 0 and step % self.fc.occupancy_update_every == 0:
            self.refresh_occupancy()
        return False

    def camera_depths(self, c, dirs, px=None):
        fixed = self.fixed_depth(px) if px is not None else None
        if fixed is not None and bool(torch.isfinite(fixed).all()):
            return [fixed]          # frozen surface band: the rendering would return the start's depth
        near, far = ray_box(c, dirs, self.grid.box.bbox_min, self.grid.box.bbox_max)
        depth = render_pruned(self.grid, self.occupancy, c, dirs, near, torch.maximum(far, near),
                              self.step_len, self.tau_step).depth
        return [depth if fixed is None else torch.where(torch.isfinite(fixed), fixed, depth)]

    def segment_transmittances(self, o, u, near, far):
        return [render_pruned(self.grid, self.occupancy, o, u, near, far, self.step_len, self.tau_step).transmittance]

    def loss(self, idx, step, total, gen):
        loss, stats = pair_loss(self, self.data, idx, step, total, self.cfg, self.offset)
        if self.fc.normal_weight > 0:
            prior = self.fc.normal_weight * self.normal_prior()(self.grid.raw)
            stats["normal"] = float(prior.detach())
            loss = loss + prior
        if self.fc.anchor_weight > 0 and self.trainable is not None:
            dev = (self.grid.raw - self.raw_start) * ~self.trainable
            loss = loss + self.fc.anchor_weight * (dev * dev).sum()
        return loss, stats

    @torch.no_grad()
    def render_depth(self, origins, dirs, chunk=1 << 14, min_opacity=None):
        """Expected depth; leftover transmittance goes to the box exit, or with `min_opacity` the
        evaluator's convention: sum(w t) / sum(w), inf (a miss) below that opacity."""
        out = []
        for i in range(0, origins.shape[0], chunk):
            o, d = origins[i:i + chunk], dirs[i:i + chunk]
            near, far = ray_box(o, d, self.grid.box.bbox_min, self.grid.box.bbox_max)
            far = torch.maximum(far, near)
            r = render_pruned(self.grid, self.occupancy, o, d, near, far, self.step_len, self.tau_step)
            out.append(rendered_depth(r, far, min_opacity))
        return torch.cat(out) if out else origins.new_zeros(0)

    def density(self, pts):
        return self.grid(pts)

    def density_volume(self):
        """Opacity of each voxel (nx, ny, nz) in [0, 1], and the box."""
        sigma = self.grid.sigma_xyz()
        op = 1.0 - torch.exp(-sigma * self.grid.box.voxel)
        return op.cpu().numpy(), self.grid.box.bbox_min.cpu().numpy(), self.grid.box.bbox_max.cpu().numpy()

    def surface_volume(self):
        """A field for marching cubes (nx, ny, nz) and its level: the raw density clipped to one voxel's
        signed-distance ramp around the raw value at the surface (where a ray crossing the initial
        ramp has half its transmittance left: the depth volume rendering puts there).

        The ramp is steep (surface_slope per voxel), so opacity at voxel centres is nearly binary and
        marching cubes on it snaps the surface to the midpoint between centres (grid-aligned terraces
        of up to half a voxel). Clipped raw is linear in the signed distance across the surface: the
        interpolated crossing is the measured surface to a fraction of a voxel.

        `fast.mesh_level_shift_voxels` moves the level that far inward (raw grows by `surface_slope` per
        voxel across a ramp); `fast.mesh_hull_inset_voxels` places the surface between a saturated occupied
        voxel and a saturated free one (the shadow hull's binary boundary, which the ramp never reached)
        that far inside the midpoint (see `binary_boundary_inset`)."""
        key = (self.grid, self.grid.raw._version, self.thin_parts, repr(self.fc))
        if self._surface_field is None or not _same_key(self._surface_field[0], key):
            self._surface_field = (key, self.build_surface_volume())     # (free_evidence asks first, the export next)
        vol, level = self._surface_field[1]
        return vol.copy(), level

    def build_surface_volume(self):
        """`surface_volume` built afresh, not cached (needs only `fc`, `grid`, `thin_parts`: the representation
        oracle calls it on a namespace holding a ground-truth grid)."""
        slope = max(self.fc.surface_slope, 1.0)
        level = surface_offset(self.grid.density_scale, self.grid.box.voxel, slope) \
            + self.fc.mesh_level_shift_voxels * slope
        half = max(min(slope, level - self.fc.raw_free, self.fc.raw_occupied - level), 1e-3)   # inside the init's clamp
        raw = self.grid.raw_xyz().detach().clamp(level - half, level + half)
        keep = None if self.thin_parts is None else self.thin_parts[0, 0].permute(2, 1, 0)
        if self.fc.mesh_hull_inset_voxels > 0:
            raw = binary_boundary_inset(raw, level, half, self.fc.mesh_hull_inset_voxels,
                                        self.fc.mesh_hull_inset_max_voxels, keep, self.fc.mesh_hull_inset_min_voxels)
        if self.fc.mesh_sheet_inset_voxels > 0:     # thin_sheets.py
            from .thin_sheets import sheet_inset
            from .hull_subvoxel import camera_free
            seen = camera_free(self, self.grid.box) if self.fc.mesh_sheet_unseen_sides else None
            raw = sheet_inset(raw, level, half, self.fc.mesh_sheet_inset_voxels, self.fc.mesh_sheet_min_in_plane, keep,
                              self.fc.mesh_sheet_max_voxels, seen)
        return raw.cpu().numpy(), level

    def mesh_inward(self, volume, level: float):
        """The mesh's bounded inward smoothing of the hidden hull (`mesh_export.InwardSmoothing`;
        `fast.mesh_hull_shrink_voxels`, hull_subvoxel.py) of the mesh field `volume` (`surface_volume`), or None; the
        plane snap (`fast.mesh_plane_snap_voxels`, hull_planes.py) rides on it, also with the shrink off (nothing
        movable then: mesh_export snaps after the smoothing)."""
        shrink, snap = self.fc.mesh_hull_shrink_voxels, self.fc.mesh_plane_snap_voxels
        if shrink <= 0 and snap <= 0:
            return None
        if self._start_raw is None or tuple(self._start_raw.shape) != tuple(self.grid.box.shape):
            self._initial(box=self.grid.box)        # (sets the evidence of this grid too)
        if shrink > 0:
            vol = torch.as_tensor(volume)
            saturated = vol >= level + 0.5 * (float(vol.max()) - level)
            movable = shrinkable_hull(self, self._start_raw, self.evidence, self.fc.mesh_hull_shrink_graze_samples,
                                      saturated).cpu().numpy()
        else:
            movable = np.zeros(tuple(self.grid.box.shape), bool)
        out = InwardSmoothing(movable, max(shrink, 0.0) * self.grid.box.voxel, SHRINK_ITERATIONS)
        if shrink > 0:
            self._hull_passes(out)
        if snap > 0:      # hull_planes.py
            from .hull_planes import set_plane_snap
            set_plane_snap(self, out, snap)
        return out

    def _hull_passes(self, out) -> None:
        """The hull's flat patches, lit fans and unplaced Taubin passes into `out` (`InwardSmoothing`), each on its
        setting."""
        flat = None
        if self.fc.mesh_hull_flat_approach:     # hull_flat.py
            from .hull_flat import flat_patches_inward
            flat = flat_patches_inward(self, out)
        if self.fc.mesh_hull_lit_fan:           # the rest of the hull's boundary by the lit fans' share (lit_fans.py)
            from .lit_fans import hull_occupancy
            hull_occupancy(self, out, flat)
        if self.fc.mesh_unplaced_taubin_iterations > 0:     # hull_unplaced.py
            from .hull_unplaced import set_unplaced_smoothing
            set_unplaced_smoothing(self, out, self.fc.mesh_unplaced_taubin_iterations, self.fc.mesh_unplaced_max_voxels,
                                   self.fc.mesh_unplaced_silhouettes)

    def params_finite(self) -> bool:
        return all_finite(self.grid.raw)

    def state_dict(self):
        return {"level": self.level, "raw": self.grid.raw.detach().clone(),
                "bbox_min": self.grid.box.bbox_min.cpu(), "voxel": self.grid.box.voxel,
                "shape": list(self.grid.box.shape), "free": self.free.clone(),
                "trainable": self.trainable, "raw_start": self.raw_start, "thin_parts": self.thin_parts, "occupancy": self.occupancy.clone(), "tau_step": self.tau_step.clone(), "optimizer": self.optimizer.state_dict(),
                "normal_cells": None if self._normal_prior is None else self._normal_prior.cells.clone()}

    def load_state_dict(self, st):
        self.level = int(st["level"])
        box = GridBox.exact(st["bbox_min"], st["voxel"], st["shape"]).to(self.device)
        self.grid = DensityGrid(box, self.fc.density_scale, st["raw"].to(self.device))
        if "free" in st:
            self.free = st["free"].to(self.device)
        t = st.get("trainable")
        self.trainable = None if t is None else t.to(self.device)
        r0 = st.get("raw_start")
        self.raw_start = None if r0 is None else r0.to(self.device)
        tp = st.get("thin_parts")
        self.thin_parts = None if tp is None else tp.to(self.device)
        self.occupancy = st["occupancy"].to(self.device)
        self._normal_prior = None       # rebuilt on the surface cells the run had (resume == uninterrupted)
        self._normal_cells = st.get("normal_cells")
        self.tau_step = st["tau_step"].to(self.device)
        self.make_optimizer()
        self.optimizer.load_state_dict(st["optimizer"])


def _same_key(a, b) -> bool:
    """Keys of `FastModel.surface_volume`: the same grid and thin-part objects, unchanged since, the same settings."""
    return a[0] is b[0] and a[1] == b[1] and a[2] is b[2] and a[3] == b[3]


def build_fast(data: RayData, cfg: FitConfig, meas_meta: dict, generator: torch.Generator):
    return FastModel(data, cfg, meas_meta)


def build_platonerf(data: RayData, cfg: FitConfig, meas_meta: dict, generator: torch.Generator):
    from .platonerf_model import PlatoNeRFModel

    return PlatoNeRFModel(data, cfg, meas_meta, generator)


def build_model(data: RayData, cfg: FitConfig, meas_meta: dict, generator: torch.Generator):
    """The model of cfg.mode, as the method table (contract/methods.py) names it."""
    from ..contract.methods import load, method

    return load(method(cfg.mode).model)(data, cfg, meas_meta, generator)

