"""Settings of a fit, as dataclasses (JSON round-trip; every number a person may tune lives here).

Two modes share the data, the losses and the evaluation:
- ``platonerf``: the published method trained like the authors' code (NeRF MLPs + positional
  encoding, 64 coarse + 128 fine samples, 1024 rays per step; warm-up: plain MSE of path / 15 on lit
  rays for the first 12.5 % of the steps; then 6000 x that MSE + MSE of the secondary rays'
  transmittance on shadowed and lit rays; both for the coarse and fine depth; total x 100; networks
  re-created when their gradient is exactly zero).
- ``fast``: the same measurements and losses on an explicit density grid that starts from the closed-form
  visible depth and shadow carving, samples only occupied cells, runs coarse to fine, stops on a plateau.
"""

from __future__ import annotations

import math

from dataclasses import asdict, dataclass, field

from ..contract import settings
from ..contract.errors import SettingsError
from ..contract.methods import DEFAULT_FIT_METHOD, FIT_METHODS, method
from ..contract.settings import check_device_name
from .fast_config import FastConfig

MODES = FIT_METHODS   # the fit methods of the method table (contract/methods.py)
#: largest grid side a fit accepts (1024^3 voxels: ~43 GB of optimiser state)
MAX_VOXELS_PER_SIDE = 1024


@dataclass
class LossConfig:
    """The paper's losses (both modes)."""

    path_scale_m: float = 15.0        # optical paths are divided by this before the MSE (paper: 15)
    distance_weight: float = 6000.0   # paper's dist_weight for the chair scene
    shadow_weight: float = 1.0        # weight of the mean squared transmittance on shadowed rays (target 0)
    lit_weight: float = 1.0           # weight of the mean squared (1 - transmittance) on lit rays
    loss_scale: float = 100.0         # paper: the total is multiplied by 100
    warmup_fraction: float = 0.125    # distance loss alone for this fraction of the steps (25k of 200k)
    secondary_offset_m: float = 0.0   # the secondary ray x -> l starts/ends this far from x and l


@dataclass
class PlatoNeRFConfig:
    """The authors' published training (src/run_platonerf.py + configs/chair.txt); differences and
    reasons in docs/reconstruction.md."""

    depth: int = 8
    width: int = 256
    skip: int = 4                     # the input is concatenated again after this layer
    pe_frequencies: int = 10          # multires 10
    coarse_samples: int = 64          # N_samples
    fine_samples: int = 128           # N_importance
    rays_per_batch: int = 1024        # N_rand
    lr: float = 5e-4
    lr_decay_steps: int = 500_000     # lr * 0.1 ** (step / lr_decay_steps) (lrate_decay 500 x 1000)
    steps: int = 200_000
    near_m: float = 0.1               # camera and secondary rays start here (their default --near)
    far_m: float | None = 6.0         # camera rays end here (their fixed far); None: the scene box exit
    test_near_m: float = 0.0          # their test-view rendering starts at 0
    reinit_dead: str = "both"         # re-create both networks when the weights' gradient of 'coarse'
                                      # (theirs), of 'either' network ('both', default) is exactly 0; 'off'
    reinit_snapshot_every: int = 5000  # ... from the networks saved this often (their i_weights), if any
    volume_resolution: int = 128      # density sampled on this grid for the mesh


@dataclass
class FitConfig:
    mode: str = DEFAULT_FIT_METHOD
    seed: int = 0
    device: str = "auto"              # 'auto' (CUDA when present), 'cpu', 'cuda', 'cuda:N'
    threads: int = 2                  # torch CPU threads
    max_seconds: float | None = None  # wall-clock budget for the optimisation (None: run all steps)
    steps: int | None = None          # overrides the mode's default step count
    checkpoint_every_s: float = 30.0
    resume: bool = True               # continue from OUT/checkpoint.pt when it matches this config
    plateau_patience: int = 60        # early stop: steps without a relative improvement of plateau_rel_tol
    plateau_rel_tol: float = 1e-3
    max_nan_restores: int = 3
    progress: bool = True
    eval_every_s: float | None = None  # benchmark hook: call `on_eval` this often (seconds of training)
    mesh_level: float = 0.5           # iso level on opacity over one voxel
    mesh_smooth_iterations: int = 10  # Taubin smoothing passes on the exported mesh (0: raw marching cubes)
    loss: LossConfig = field(default_factory=LossConfig)
    fast: FastConfig = field(default_factory=FastConfig)
    platonerf: PlatoNeRFConfig = field(default_factory=PlatoNeRFConfig)

    SETTINGS_META = {"mode": {"choices": FIT_METHODS, "help": "reconstruction method (contract/methods.py)"},
                     "threads": {"range": (1, None)},
                     "steps": {"range": (0, None)}, "max_seconds": {"range": (0, None), "unit": "s"},
                     "checkpoint_every_s": {"unit": "s"}}

    def __post_init__(self):
        method(self.mode)       # SettingsError naming 'mode' for an unknown method
        if not 0.0 <= self.loss.warmup_fraction <= 1.0:
            raise SettingsError("loss.warmup_fraction",
                                f"expected a fraction in [0, 1], got {self.loss.warmup_fraction}")
        for key in ("resolution", "coarse_resolution"):
            if getattr(self.fast, key) < 4:
                raise SettingsError(f"fast.{key}", f"expected an integer >= 4 (a coarse level at or above the "
                                                   f"resolution is skipped), got {getattr(self.fast, key)}")
        if self.platonerf.reinit_dead not in ("both", "coarse", "off"):
            raise SettingsError("platonerf.reinit_dead",
                                f"expected 'both', 'coarse' or 'off', got {self.platonerf.reinit_dead!r}")
        if self.fast.thin_part_centre not in ("off", "depth", "mean", "seen", "coverage"):
            raise SettingsError("fast.thin_part_centre", f"expected 'off', 'depth', 'mean', 'coverage' or 'seen', got "
                                                          f"{self.fast.thin_part_centre!r}")
        if self.fast.surface_concave_corners not in ("off", "planes", "all"):
            raise SettingsError("fast.surface_concave_corners", f"expected 'off', 'planes' or 'all', got "
                                                                f"{self.fast.surface_concave_corners!r}")
        if self.fast.thin_part_training not in ("free", "frozen", "grow"):
            raise SettingsError("fast.thin_part_training", f"expected 'free', 'frozen' or 'grow', got "
                                                            f"{self.fast.thin_part_training!r}")
        if self.fast.explain_score not in ("ratio", "spots"):
            raise SettingsError("fast.explain_score", f"expected 'ratio' or 'spots', got {self.fast.explain_score!r}")
        if not (math.isfinite(self.fast.explain_neighbour_power) and self.fast.explain_neighbour_power >= 0):
            raise SettingsError("fast.explain_neighbour_power",
                                f"expected a power >= 0 (0: off), got {self.fast.explain_neighbour_power}")
        if not math.isfinite(self.fast.thin_part_raw) or self.fast.thin_part_raw < self.fast.raw_occupied:
            raise SettingsError("fast.thin_part_raw", f"expected a number >= fast.raw_occupied "
                                                       f"({self.fast.raw_occupied}), got {self.fast.thin_part_raw}")
        if not 0.0 <= self.fast.thin_part_half_width_voxels <= 0.5:
            raise SettingsError("fast.thin_part_half_width_voxels", f"expected a value in [0, 0.5] (voxels; 0: off), "
                                                                    f"got {self.fast.thin_part_half_width_voxels}")
        if not (math.isfinite(self.fast.max_voxels_per_pixel) and self.fast.max_voxels_per_pixel >= 0):
            raise SettingsError("fast.max_voxels_per_pixel", f"expected voxels >= 0 (0: off), got "
                                                             f"{self.fast.max_voxels_per_pixel}")
        if not (math.isfinite(self.fast.lit_path_tolerance_voxels) and self.fast.lit_path_tolerance_voxels >= 0):
            raise SettingsError("fast.lit_path_tolerance_voxels",
                                f"expected voxels >= 0 (0: off), got {self.fast.lit_path_tolerance_voxels}")
        if self.fast.explain_shared_cluster_voxels < 0:
            raise SettingsError("fast.explain_shared_cluster_voxels",
                                f"expected a count of voxels >= 0 (0: off), got {self.fast.explain_shared_cluster_voxels}")
        scale = self.fast.explain_measured_scale_voxels
        if not (math.isfinite(scale) and scale >= 0):
            raise SettingsError("fast.explain_measured_scale_voxels",
                                f"expected voxels >= 0 (0: off), got {self.fast.explain_measured_scale_voxels}")
        if not (math.isfinite(self.fast.freeze_plane_edges_voxels) and 0 <= self.fast.freeze_plane_edges_voxels <= 8):
            raise SettingsError("fast.freeze_plane_edges_voxels",
                                f"expected voxels in [0, 8] (0: off), got {self.fast.freeze_plane_edges_voxels}")
        if not (math.isfinite(self.fast.freeze_spot_radius_voxels) and self.fast.freeze_spot_radius_voxels >= 0):
            raise SettingsError("fast.freeze_spot_radius_voxels",
                                f"expected voxels >= 0 (0: off), got {self.fast.freeze_spot_radius_voxels}")
        if not (math.isfinite(self.fast.mesh_plane_snap_voxels) and 0 <= self.fast.mesh_plane_snap_voxels <= 2):
            raise SettingsError("fast.mesh_plane_snap_voxels", f"expected voxels in [0, 2] (0: off), got "
                                                               f"{self.fast.mesh_plane_snap_voxels}")
        if not (math.isfinite(self.fast.plane_refit_mad) and self.fast.plane_refit_mad >= 0):
            raise SettingsError("fast.plane_refit_mad",
                                f"expected robust standard deviations >= 0 (0: off), got {self.fast.plane_refit_mad}")
        if not self.fast.explain_lead_voxels >= 0:
            raise SettingsError("fast.explain_lead_voxels",
                                f"expected voxels >= 0 (0: off), got {self.fast.explain_lead_voxels}")
        if not 0.0 <= self.fast.thin_part_radius_voxels <= 1.0:
            raise SettingsError("fast.thin_part_radius_voxels", f"expected a value in [0, 1] (voxels; 0: whole voxels), "
                                                                f"got {self.fast.thin_part_radius_voxels}")
        if self.fast.hull_closure not in ("off", "convex"):
            raise SettingsError("fast.hull_closure", f"expected 'off' or 'convex', got {self.fast.hull_closure!r}")
        if not (self.fast.hull_closure_margin_voxels >= 0 and self.fast.hull_closure_graze_samples >= 1
                and self.fast.hull_closure_min_segments >= 1):
            raise SettingsError("fast.hull_closure_*", "expected margin_voxels >= 0, graze_samples >= 1, min_segments >= 1")
        if self.fast.hull_opening_voxels < 0:
            raise SettingsError("fast.hull_opening_voxels", f"expected an integer >= 0 (0: off), got {self.fast.hull_opening_voxels}")
        if self.fast.trim_hull_voxels < 0:
            raise SettingsError("fast.trim_hull_voxels", f"expected an integer >= 0 (0: off), got {self.fast.trim_hull_voxels}")
        # bounded fast.* settings: (key, low, high, unit, what 0 means) -> one line naming the key
        for key, low, high, unit, note in (("mesh_hull_inset_voxels", 0, 0.45, "voxels", " (0: off)"),
                                           ("mesh_sheet_inset_voxels", 0, 0.45, "voxels", " (0: off)"),
                                           ("mesh_sheet_max_voxels", 1, 4, "voxels", ""),
                                           ("mesh_sheet_min_in_plane", 1, 8, "a count", ""),
                                           ("mesh_hull_inset_max_voxels", 0, 8, "voxels", " (0: any thickness)"),
                                           ("mesh_hull_shrink_voxels", 0, 0.5, "voxels", " (0: off)"),
                                           ("mesh_level_shift_voxels", -0.5, 0.5, "voxels", " (0: off)"),
                                           ("surface_hidden_hull_voxels", 0, 4, "voxels", " (0: off)"),
                                           ("seen_through_voxels", 0, 4, "voxels", " (0: off)"),
                                           ("surface_seen_through_voxels", 0, 4, "voxels", " (0: off)"),
                                           ("surface_plane_blocker_voxels", 0, 2, "voxels", " (0: off)"),
                                           ("explain_in_plane_voxels", 0, 2, "voxels", " (0: off)"),):
            value = getattr(self.fast, key)
            if not low <= value <= high:     # NaN fails too
                raise SettingsError(f"fast.{key}", f"expected {unit} in [{low}, {high}]{note}, got {value}")
        if not 1 <= self.fast.mesh_hull_inset_min_voxels <= max(self.fast.mesh_hull_inset_max_voxels, 1):
            raise SettingsError("fast.mesh_hull_inset_min_voxels",
                                f"expected voxels in [1, fast.mesh_hull_inset_max_voxels], got "
                                f"{self.fast.mesh_hull_inset_min_voxels}")
        if not (isinstance(self.fast.mesh_keep_restored_voxels, int) and self.fast.mesh_keep_restored_voxels >= 0):
            raise SettingsError("fast.mesh_keep_restored_voxels",
                                f"expected a voxel count >= 0 (0: off), got {self.fast.mesh_keep_restored_voxels}")
        if not (isinstance(self.fast.mesh_hull_flat_patch_faces, int) and self.fast.mesh_hull_flat_patch_faces >= 1):
            raise SettingsError("fast.mesh_hull_flat_patch_faces",
                                f"expected a face count >= 1, got {self.fast.mesh_hull_flat_patch_faces}")
        if self.fast.mesh_hull_lit_fan and not self.fast.mesh_hull_shrink_voxels > 0:
            raise SettingsError("fast.mesh_hull_lit_fan", "needs fast.mesh_hull_shrink_voxels > 0 (it shapes the hull "
                                                          "that setting makes shrinkable)")
        if not (isinstance(self.fast.mesh_unplaced_taubin_iterations, int) and self.fast.mesh_unplaced_taubin_iterations >= 0):
            raise SettingsError("fast.mesh_unplaced_taubin_iterations",
                                f"expected a count >= 0 (0: off), got {self.fast.mesh_unplaced_taubin_iterations}")
        if not 0 < self.fast.mesh_unplaced_max_voxels <= 2:     # NaN fails too
            raise SettingsError("fast.mesh_unplaced_max_voxels",
                                f"expected voxels in (0, 2], got {self.fast.mesh_unplaced_max_voxels}")
        if self.fast.mesh_unplaced_taubin_iterations > 0 and not self.fast.mesh_hull_shrink_voxels > 0:
            raise SettingsError("fast.mesh_unplaced_taubin_iterations", "needs fast.mesh_hull_shrink_voxels > 0 (it runs "
                                                                        "in that setting's export step)")
        if self.fast.mesh_hull_shrink_graze_samples < 0:
            raise SettingsError("fast.mesh_hull_shrink_graze_samples",
                                f"expected an integer >= 0 (0: no shadow-edge exception), got "
                                f"{self.fast.mesh_hull_shrink_graze_samples}")
        if not self.fast.normal_weight >= 0:
            raise SettingsError("fast.normal_weight", f"expected a weight >= 0 (0: off), got {self.fast.normal_weight}")
        if not 0 < self.fast.normal_max_angle_deg <= 90:
            raise SettingsError("fast.normal_max_angle_deg",
                                f"expected an angle in (0, 90] degrees, got {self.fast.normal_max_angle_deg}")
        check_device_name(self.device)
        for key in ("fast.lr", "fast.adam_eps", "fast.step_voxels", "fast.rays_per_batch", "platonerf.lr", "platonerf.rays_per_batch",
                    "loss.path_scale_m"):
            section, name = key.split(".")
            v = getattr(getattr(self, section), name)
            if not v > 0:      # the optimiser would raise deep inside torch
                raise SettingsError(key, f"expected a value > 0, got {v}")
        for key, n in (("fast.resolution", self.fast.resolution),
                       ("platonerf.volume_resolution", self.platonerf.volume_resolution)):
            if n > MAX_VOXELS_PER_SIDE:      # refused up front, with the estimate, not by an out-of-memory crash
                from ..contract.units import format_bytes
                raise SettingsError(key, f"{n} voxels per side would need about {format_bytes(40.0 * n ** 3)} "
                                         f"of memory (~10 float32 per voxel); at most {MAX_VOXELS_PER_SIDE} is supported")

    @property
    def method_settings(self):
        """The settings section of this mode (the method table says which)."""
        return getattr(self, method(self.mode).section)

    @property
    def total_steps(self) -> int:
        if self.steps is not None:
            return int(self.steps)
        return self.method_settings.steps

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict, source: str = "") -> "FitConfig":
        return settings.from_dict(cls, d, source)


def override(cfg: FitConfig, assignments: list[str]) -> FitConfig:
    """Apply 'section.key=value' strings (CLI --set), each type- and range-checked."""
    return settings.with_values(cfg, settings.parse_assignments(assignments))
