"""Simulation settings: the one definition the add-on, `pipeline/simulate.py` and batch runs read (no bpy here).

The same settings travel three ways, all through this one class:
- the add-on stores them as JSON in the .blend (Text datablock ``CONFIG_TEXT_NAME``),
  so ``blender -b file.blend -P pipeline/simulate.py`` sees exactly the panel's settings;
- ``--config FILE.json`` for a later headless run (the add-on can export it);
- command-line options, which override either.
Units: metres, picoseconds (as a person types them), degrees never appear here. The bin
width is given as `bin_ps` or, exactly in metres of optical path, as `bin_m` (then
`bin_ps` follows from it; converted in torch_recon.contract.units).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field, fields

from .errors import SettingsError
from .settings import check_value, find_spec, load_file, specs
from .units import bin_widths_consistent, m_to_ps

CONFIG_SCHEMA_VERSION = "1.0"
#: Name of the Text datablock in which the add-on keeps the settings inside the .blend
CONFIG_TEXT_NAME = "platolidar_config.json"


class ConfigError(SettingsError):
    """Bad settings: names the source and the setting and says what was expected."""

    def __init__(self, source: str, setting: str, message: str):
        super().__init__(setting, message, source)
        self.setting = setting


@dataclass
class SpotConfig:
    """A laser spot: aim the laser at `target` (world point) or along `direction`."""

    target: list | None = None
    direction: list | None = None
    enabled: bool = True
    name: str = ""


@dataclass
class SimulationConfig:
    camera: str | None = None              # camera object name; None -> the scene camera
    width: int = 512                       # sensor width
    height: int = 512                      # sensor height
    bin_ps: float = 128.0                  # time bin width
    bin_m: float | None = None             # bin width as optical path; when set it defines the bin (give this
                                           # or bin_ps, e.g. the paper's 0.0384)
    bins: int = 391                        # time bins per pixel
    start_m: float = 0.0                   # optical path of the first bin's start
    pulse_fwhm_ps: float = 128.0           # laser pulse width (FWHM)
    pulse_shape: str = "gaussian"          # 'gaussian' or 'box' (single bin)
    laser_object: str | None = None        # laser object name; None -> laser co-located with the camera
    footprint_radius_m: float = 0.005      # radius of the lit spot (laser footprint)
    photon_counts: bool = False            # Poisson photon counts instead of expected values
    photons_per_pixel: float = 1000.0      # signal budget of the brightest two-bounce pixel (0: radiance units)
    ambient_per_bin: float = 0.0           # ambient photons per pixel per bin, before the filter
    wavelength_filter_factor: float = 1.0  # fraction of ambient passing the band-pass filter
    dark_counts_per_bin: float = 0.0       # dark counts per pixel per bin
    time_gate: bool = False                # keep only a window of gate_window_bins around the expected return
    gate_window_bins: int = 32             # width of the time gate's window
    bounces: int = 2                       # 2, or 3 for third-order light (costs more)
    third_bounce_vpls: int = 16            # with bounces=3: virtual point lights (one render each) per spot
    subpixel_samples: int = 4              # base samples per pixel (a square number)
    adaptive_subpixel_samples: int = 64    # samples of a pixel at a depth, shadow or path-spread edge (a square
                                           # number; 0: every pixel gets subpixel_samples)
    adaptive_spread_bins: float = 1.0      # refine a pixel whose optical path spreads over more bins than this
    shading: str = "lambertian"            # 'lambertian': passes + shadow rays; 'cycles': a Cycles render per spot
    rgb: bool = False                      # RGB images for the RGB-shadow baseline
    train_depth: bool = True               # ground truth: the training view's depth
    test_views_dolly: int = 39             # ground truth: dolly test views (0 to skip)
    test_views_orbit: int = 100            # ground truth: orbit test views (0 to skip)
    test_view_resolution: int = 128        # ground truth: test view size (N x N)
    test_view_trajectory: str = "scene"    # 'scene': dolly + orbit around the scene's objects, each camera
                                           # checked to be in free space; 'paper': the paper's 139-view preset
    gt_mesh: bool = True                   # ground truth: the scene's mesh (and one per labelled object)
    spots: list = field(default_factory=list)  # list[SpotConfig]; empty -> random spots
    random_candidates: int = 24            # random candidate spots to choose from when the scene has none
    random_keep: int = 16                  # K spots: K of the scene's spots (diversity heuristic), or K of the
                                           # random candidates
    seed: int = 0                          # seed of every random choice

    # Ranges here are inclusive (checked by contract/settings.py for the file, the flags, --set and validate());
    # widths that must be > 0 are checked in validate(). "flags": the simulator's short command-line names.
    SETTINGS_META = {
        "width": {"range": (1, None), "unit": "px"}, "height": {"range": (1, None), "unit": "px"},
        "bin_ps": {"unit": "ps"}, "bin_m": {"unit": "m"}, "bins": {"range": (1, None)},
        "start_m": {"range": (0, None), "unit": "m"}, "pulse_fwhm_ps": {"unit": "ps"},
        "pulse_shape": {"choices": ("gaussian", "box")},
        "footprint_radius_m": {"unit": "m", "flags": ("--footprint-m",)},
        "photon_counts": {"flags": ("--poisson",)},
        "photons_per_pixel": {"range": (0, None), "unit": "photons", "flags": ("--photons",)},
        "ambient_per_bin": {"range": (0, None), "unit": "photons/pixel/bin", "flags": ("--ambient",)},
        "wavelength_filter_factor": {"range": (0, 1), "flags": ("--wavelength-filter",)},
        "dark_counts_per_bin": {"range": (0, None), "unit": "counts/pixel/bin", "flags": ("--dark-counts",)},
        "gate_window_bins": {"range": (1, None), "unit": "bins"},
        "bounces": {"choices": (2, 3)},
        "third_bounce_vpls": {"range": (1, None), "flags": ("--vpls",)},
        "subpixel_samples": {"range": (1, None), "unit": "samples/pixel", "flags": ("--subpixel",)},
        "adaptive_subpixel_samples": {"range": (0, None), "unit": "samples/pixel", "flags": ("--adaptive",)},
        "adaptive_spread_bins": {"unit": "bins"},
        "shading": {"choices": ("lambertian", "cycles")},
        "test_views_dolly": {"range": (0, None)}, "test_views_orbit": {"range": (0, None)},
        "test_view_resolution": {"range": (1, None), "unit": "px"},
        "test_view_trajectory": {"choices": ("scene", "paper")},
        "random_candidates": {"range": (0, None), "flags": ("--candidates",)},
        "random_keep": {"range": (0, None), "flags": ("--spots",)},
        "seed": {"range": (0, None)},
    }

    # -- validation -----------------------------------------------------------------
    def validate(self, source: str = "settings") -> "SimulationConfig":
        def bad(name, msg):
            raise ConfigError(source, name, msg)

        for spec in specs(type(self)):       # types, choices and ranges: the shared settings mechanism
            try:
                setattr(self, spec.name, check_value(spec, getattr(self, spec.name)))
            except SettingsError as exc:
                bad(spec.name, exc.detail)
        for name in ("bin_ps", "pulse_fwhm_ps", "footprint_radius_m", "adaptive_spread_bins"):
            if getattr(self, name) <= 0:         # widths: > 0 (a settings range is inclusive)
                bad(name, f"expected a positive number, got {getattr(self, name)!r}")
        if self.bin_m is not None:
            v = self.bin_m
            if v <= 0:
                bad("bin_m", f"expected a positive finite number of metres, got {v!r}")
            if not bin_widths_consistent(v, self.bin_ps):
                bad("bin_m", f"bin_m={v} m and bin_ps={self.bin_ps} ps describe different bins ({m_to_ps(v)} ps); "
                             "give only one of them")
            self.bin_ps = float(m_to_ps(v))     # the metres define the bin; ps follows exactly
        v = self.adaptive_subpixel_samples
        if v and math.isqrt(v) ** 2 != v:
            bad("adaptive_subpixel_samples", f"expected 0 (off) or a square number (4, 16, 64, ...), got {v!r}")
        if self.time_gate and self.gate_window_bins > self.bins:
            bad("gate_window_bins", f"window of {self.gate_window_bins} bins exceeds bins={self.bins}")
        if self.random_keep > self.random_candidates:
            bad("random_keep", f"cannot keep {self.random_keep} of {self.random_candidates} candidates")
        for i, s in enumerate(self.spots):
            if (s.target is None) == (s.direction is None):
                bad(f"spots[{i}]", "give exactly one of 'target' or 'direction'")
            v = s.target if s.target is not None else s.direction
            if not (isinstance(v, (list, tuple)) and len(v) == 3
                    and all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)):
                bad(f"spots[{i}]", f"expected 3 finite numbers, got {v!r}")
            if s.direction is not None and math.sqrt(sum(x * x for x in s.direction)) < 1e-9:
                bad(f"spots[{i}].direction", "zero-length direction")
        return self

    # -- (de)serialisation ----------------------------------------------------------
    def to_dict(self) -> dict:
        return {"schema_version": CONFIG_SCHEMA_VERSION, **asdict(self)}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, d: dict, source: str = "settings") -> "SimulationConfig":
        if not isinstance(d, dict):
            raise ConfigError(source, "", "expected a JSON object")
        ver = d.get("schema_version", CONFIG_SCHEMA_VERSION)
        if ver != CONFIG_SCHEMA_VERSION:
            raise ConfigError(source, "schema_version", f"unknown version {ver!r}, expected {CONFIG_SCHEMA_VERSION!r}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known - {"schema_version"})
        if unknown:
            raise ConfigError(source, unknown[0], f"unknown setting (known: {sorted(known)})")
        kw = dict(d)
        kw.pop("schema_version", None)
        spots = kw.pop("spots", [])
        for key, value in kw.items():   # types and ranges: the shared settings mechanism
            try:
                kw[key] = check_value(find_spec(cls, key), value)
            except SettingsError as exc:
                raise ConfigError(source, key, exc.detail) from None
        if kw.get("bin_m") is not None and "bin_ps" not in kw:
            kw["bin_ps"] = m_to_ps(kw["bin_m"]) if kw["bin_m"] > 0 else 128.0   # else validate() names bin_m
        if not isinstance(spots, list):
            raise ConfigError(source, "spots", "expected a list")
        spot_keys = {f.name for f in fields(SpotConfig)}
        parsed = []
        for i, s in enumerate(spots):
            if not isinstance(s, dict) or set(s) - spot_keys:
                raise ConfigError(source, f"spots[{i}]", f"expected an object with keys from {sorted(spot_keys)}")
            parsed.append(SpotConfig(**s))
        return cls(spots=parsed, **kw).validate(source)

    def updated(self, values: dict, source: str = "settings") -> "SimulationConfig":
        """A checked copy with `values` (setting -> value or command-line text; a settings file, flags or --set)
        laid over this one. The bin width's unit follows the layer: bin_ps alone drops a stored bin_m, bin_m
        alone sets bin_ps."""
        d = {**self.to_dict(), **values}
        if "bin_m" in values and "bin_ps" not in values:
            d.pop("bin_ps")
        elif "bin_ps" in values and "bin_m" not in values:
            d["bin_m"] = None
        return type(self).from_dict(d, source)

    @classmethod
    def from_json(cls, text: str, source: str = "settings") -> "SimulationConfig":
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(source, "", f"not valid JSON ({exc})") from None
        return cls.from_dict(d, source)

    @classmethod
    def load(cls, path) -> "SimulationConfig":
        """A settings file: JSON, or TOML by suffix (the shared reader, contract/settings.py)."""
        try:
            d = load_file(path)
        except OSError as exc:
            raise ConfigError(str(path), "", f"cannot read ({exc.strerror})") from None
        except SettingsError as exc:      # not JSON/TOML, not a table: the same ConfigError as a bad value
            raise ConfigError(str(path), exc.key, exc.detail) from None
        return cls.from_dict(d, str(path))
