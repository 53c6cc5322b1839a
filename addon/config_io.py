"""Panel settings <-> ``pipeline.config.SimulationConfig``, and its copy inside the .blend.

The .blend carries the settings twice: as the scene's PropertyGroup (what the panel edits)
and as JSON in the Text datablock ``CONFIG_TEXT_NAME`` (what ``pipeline/simulate.py``
reads in a headless run). The JSON is rewritten on every simulate/export and before
every save, so both always agree.
"""

from __future__ import annotations

import math
from dataclasses import fields

import bpy
from bpy.app.handlers import persistent

from . import _project

_project.ensure_importable()
from pipeline.config import CONFIG_TEXT_NAME, ConfigError, SimulationConfig, SpotConfig  # noqa: E402
from torch_recon.contract.errors import PlatolidarError  # noqa: E402,F401 - the operators catch this base
from torch_recon.contract.units import ps_to_m  # noqa: E402

from .props import ADVISED_PREFIX  # noqa: E402

SOURCE = "Lidar panel"

# Settings copied one to one between the PropertyGroup and SimulationConfig (those this config version has)
_DIRECT = tuple(n for n in (
    "width", "height", "bin_ps", "start_m", "pulse_fwhm_ps", "pulse_shape", "footprint_radius_m",
    "photon_counts", "photons_per_pixel", "ambient_per_bin", "wavelength_filter_factor", "dark_counts_per_bin",
    "time_gate", "gate_window_bins", "bounces", "third_bounce_vpls", "rgb", "train_depth", "test_views_dolly",
    "test_views_orbit", "test_view_resolution", "gt_mesh", "random_candidates", "random_keep", "seed")
    if n in {f.name for f in fields(SimulationConfig)})


def effective_bins(s) -> int:
    """Bin count, given directly or from the longest optical path (start + bins * bin width >= max path)."""
    if s.range_mode == "BINS":
        return int(s.bins)
    bin_m = ps_to_m(s.bin_ps)
    if not bin_m > 0:
        return 1
    return max(1, math.ceil((s.max_path_m - s.start_m) / bin_m - 1e-9))


def lidar_camera(scene):
    """The camera chosen in the panel, else the scene camera, else None."""
    s = scene.platolidar
    cam = s.camera or scene.camera
    return cam if cam is not None and cam.type == "CAMERA" else None


def settings_to_config(scene, strict: bool = True) -> SimulationConfig:
    """The panel's settings as a validated SimulationConfig; ConfigError names the setting.

    strict: also require what a simulation needs (a camera, enabled spots in list mode,
    a laser object when chosen); the save handler stores whatever is there.
    """
    s = scene.platolidar
    cfg = SimulationConfig(**{name: getattr(s, name) for name in _DIRECT})
    cfg.bins = effective_bins(s)
    cfg.subpixel_samples = s.subpixel_grid ** 2  # the simulator samples a square grid
    cam = lidar_camera(scene)
    if s.camera is not None and s.camera.type != "CAMERA":
        raise ConfigError(SOURCE, "camera", f"object '{s.camera.name}' is not a camera")
    cfg.camera = cam.name if cam is not None else None
    if strict and cam is None:
        raise ConfigError(SOURCE, "camera", "no lidar camera: pick one in Sensor or set the scene camera")
    if s.laser_mode == "OBJECT":
        if s.laser_object is None:
            if strict:
                raise ConfigError(SOURCE, "laser_object", "laser origin is 'Object' but no object is chosen")
        else:
            cfg.laser_object = s.laser_object.name
    if s.spot_source == "LIST":
        cfg.spots = [SpotConfig(target=[float(v) for v in sp.target], enabled=bool(sp.enabled), name=sp.name)
                     for sp in s.spots]
        if strict and not any(sp.enabled for sp in cfg.spots):
            raise ConfigError(SOURCE, "spots", "no enabled spot: add spots (Spots panel) or choose "
                                               "'Random at Simulation'")
    return cfg.validate(SOURCE)


def config_to_settings(cfg: SimulationConfig, scene) -> None:
    """Load a SimulationConfig into the panel (e.g. from an exported JSON); checks before changing anything."""
    side = math.isqrt(cfg.subpixel_samples)
    if side * side != cfg.subpixel_samples or not 1 <= side <= 8:
        raise ConfigError(SOURCE, "subpixel_samples", f"expected a square number from 1 to 64, got "
                                                      f"{cfg.subpixel_samples}")
    for i, sc in enumerate(cfg.spots):
        if sc.target is None:
            raise ConfigError(SOURCE, f"spots[{i}]", "the panel holds spots by target point; "
                                                     "this one gives only a direction")
    s = scene.platolidar
    for name in _DIRECT:
        setattr(s, name, getattr(cfg, name))
    s.range_mode, s.bins, s.subpixel_grid = "BINS", cfg.bins, side
    s.camera = bpy.data.objects.get(cfg.camera) if cfg.camera else None
    s.laser_mode = "OBJECT" if cfg.laser_object else "COLOCATED"
    s.laser_object = bpy.data.objects.get(cfg.laser_object) if cfg.laser_object else None
    s.spots.clear()
    s.spot_source = "LIST" if cfg.spots else "RANDOM"
    for i, sc in enumerate(cfg.spots):
        sp = s.spots.add()
        sp.name, sp.enabled, sp.target = sc.name or f"Spot {i + 1:02d}", sc.enabled, sc.target
        sp.advised = sp.name.startswith(ADVISED_PREFIX + " ")
    s.active_spot_index = 0


def store_config_text(cfg: SimulationConfig):
    """Write the JSON into the Text datablock ``CONFIG_TEXT_NAME`` (created when missing)."""
    text = bpy.data.texts.get(CONFIG_TEXT_NAME) or bpy.data.texts.new(CONFIG_TEXT_NAME)
    text.clear()
    text.write(cfg.to_json())
    return text


def read_config_text() -> SimulationConfig | None:
    text = bpy.data.texts.get(CONFIG_TEXT_NAME)
    if text is None:
        return None
    return SimulationConfig.from_json(text.as_string(), f"{bpy.data.filepath or '<unsaved>'}:{CONFIG_TEXT_NAME}")


def scene_is_authored(scene) -> bool:
    """Only files the panel touched get a config text (plain .blend files stay untouched)."""
    s = getattr(scene, "platolidar", None)
    return s is not None and (len(s.spots) > 0 or s.camera is not None
                              or bpy.data.texts.get(CONFIG_TEXT_NAME) is not None)


@persistent
def on_save_pre(*_args):
    """Refresh the stored JSON before every save; never raise inside a save."""
    scene = getattr(bpy.context, "scene", None)
    if scene is None or not scene_is_authored(scene):
        return
    try:
        store_config_text(settings_to_config(scene, strict=False))
    except ConfigError as exc:
        print(f"platolidar: settings not stored in {CONFIG_TEXT_NAME}: {exc}")


def _ours(handler) -> bool:
    # by name, so a reloaded module still removes the handler an older copy added
    return getattr(handler, "__name__", "") == "on_save_pre" and getattr(handler, "__module__", "") == __name__


def register_handlers():
    unregister_handlers()
    bpy.app.handlers.save_pre.append(on_save_pre)


def unregister_handlers():
    for h in [h for h in bpy.app.handlers.save_pre if _ours(h)]:
        bpy.app.handlers.save_pre.remove(h)
