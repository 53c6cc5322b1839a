"""Panel settings -> SimulationConfig -> the .blend's Text datablock; save/reload; export/load JSON."""

import json

import bpy
import pytest

from tests.support.addon_fixtures import blank, call, expect_error, room  # noqa: F401 (fixtures)

from pipeline.config import CONFIG_TEXT_NAME, SimulationConfig
from torch_recon.contract.units import ps_to_m


def _author(scene):
    s = scene.platolidar
    s.width, s.height = 48, 32
    s.bin_ps = 64.0
    s.range_mode, s.max_path_m, s.start_m = "RANGE", 12.0, 1.0
    s.pulse_fwhm_ps, s.pulse_shape = 90.0, "box"
    s.photon_counts, s.photons_per_pixel, s.ambient_per_bin = True, 500.0, 0.25
    s.wavelength_filter_factor, s.dark_counts_per_bin = 0.1, 0.01
    s.time_gate, s.gate_window_bins = True, 20
    s.subpixel_grid, s.seed = 3, 7
    scene.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    scene.cursor.location = (1.5, 3.0, 2.0)
    call(bpy.ops.platolidar.add_spot_cursor)
    s.spots[1].enabled = False
    s.spots[1].name = "wall spot"


def test_settings_become_the_config(room):
    from addon.config_io import settings_to_config
    _author(room)
    cfg = settings_to_config(room)
    assert (cfg.width, cfg.height, cfg.bin_ps, cfg.camera) == (48, 32, 64.0, "LidarCam")
    # 11 m of path after the 1 m start in bins of 64 ps (1.92 cm): ceil(11 / 0.019186) = 574
    assert cfg.bins == 574 and cfg.start_m + cfg.bins * ps_to_m(64.0) >= 12.0
    assert cfg.start_m + (cfg.bins - 1) * ps_to_m(64.0) < 12.0
    assert cfg.subpixel_samples == 9 and cfg.pulse_shape == "box" and cfg.time_gate
    assert [s.enabled for s in cfg.spots] == [True, False] and cfg.spots[1].name == "wall spot"
    assert cfg.spots[0].target == pytest.approx([0.0, 0.5, 0.5], abs=1e-4)
    assert cfg.laser_object is None


def test_export_writes_parseable_json_and_the_text_datablock(room, tmp_path):
    _author(room)
    out = tmp_path / "settings.json"
    res, err = call(bpy.ops.platolidar.export_config, filepath=str(out))
    assert err is None and res == {"FINISHED"}
    cfg = SimulationConfig.load(out)
    text = bpy.data.texts[CONFIG_TEXT_NAME].as_string()
    assert SimulationConfig.from_json(text).to_dict() == cfg.to_dict()
    assert cfg.bins == 574 and len(cfg.spots) == 2


def test_export_bad_states(room, tmp_path):
    out = str(tmp_path / "s.json")
    expect_error(bpy.ops.platolidar.export_config, "no enabled spot", filepath=out)
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    room.platolidar.spots[0].target = (0.0, -20.0, 8.0)  # behind the camera, towards the sky
    expect_error(bpy.ops.platolidar.export_config, "aimed at nothing", filepath=out)
    room.platolidar.spots[0].target = (0.0, 0.5, 0.5)
    expect_error(bpy.ops.platolidar.export_config, "does not exist", filepath=str(tmp_path / "no" / "s.json"))
    room.platolidar.time_gate, room.platolidar.gate_window_bins, room.platolidar.bins = True, 50, 40
    expect_error(bpy.ops.platolidar.export_config, "gate_window_bins", filepath=out)
    room.platolidar.time_gate = False
    room.platolidar.camera = None
    room.camera = None
    expect_error(bpy.ops.platolidar.export_config, "no lidar camera", filepath=out)
    assert not (tmp_path / "s.json").exists()


def test_settings_survive_save_and_reload(room, tmp_path):
    _author(room)
    blend = tmp_path / "authored.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    before = {k: getattr(room.platolidar, k) for k in ("width", "height", "bin_ps", "range_mode", "max_path_m",
                                                       "pulse_fwhm_ps", "time_gate", "gate_window_bins", "seed")}
    spots = [(sp.name, sp.enabled, tuple(sp.target)) for sp in room.platolidar.spots]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    from tests.support.addon_fixtures import enable_addon
    enable_addon()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    s = bpy.context.scene.platolidar
    assert {k: getattr(s, k) for k in before} == before
    assert [(sp.name, sp.enabled, tuple(sp.target)) for sp in s.spots] == spots
    assert s.camera is not None and s.camera.name == "LidarCam"
    # the save handler stored the same settings for the headless simulator
    from addon.config_io import read_config_text, settings_to_config
    cfg = read_config_text()
    assert cfg is not None and cfg.to_dict() == settings_to_config(bpy.context.scene).to_dict()


def test_save_handler_refreshes_stale_text_and_skips_untouched_files(blank, tmp_path):
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "plain.blend"))
    assert CONFIG_TEXT_NAME not in bpy.data.texts  # a file the panel never touched stays clean
    from tests.support.addon_fixtures import build_room
    cam = build_room(blank)
    blank.platolidar.camera = cam
    blank.platolidar.width = 40
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "a.blend"))
    assert json.loads(bpy.data.texts[CONFIG_TEXT_NAME].as_string())["width"] == 40
    blank.platolidar.width = 41
    bpy.ops.wm.save_mainfile()
    assert json.loads(bpy.data.texts[CONFIG_TEXT_NAME].as_string())["width"] == 41


def test_load_config_round_trip_and_bad_files(room, tmp_path):
    _author(room)
    out = tmp_path / "settings.json"
    call(bpy.ops.platolidar.export_config, filepath=str(out))
    original = SimulationConfig.load(out).to_dict()
    room.platolidar.spots.clear()
    room.platolidar.width = 5
    res, err = call(bpy.ops.platolidar.load_config, filepath=str(out))
    assert err is None
    from addon.config_io import settings_to_config
    assert settings_to_config(room).to_dict() == original
    bad = tmp_path / "bad.json"
    bad.write_text('{"width": -3}')
    expect_error(bpy.ops.platolidar.load_config, "width", filepath=str(bad))
    expect_error(bpy.ops.platolidar.load_config, "cannot read", filepath=str(tmp_path / "missing.json"))
    d = dict(original, subpixel_samples=5)
    bad.write_text(json.dumps(d))
    expect_error(bpy.ops.platolidar.load_config, "square", filepath=str(bad))
    assert room.platolidar.width == 48  # a refused file changes nothing


def test_panel_defaults_are_the_simulators(blank):
    """One source of defaults: an untouched panel gives SimulationConfig() (camera and spots aside)."""
    from addon.config_io import settings_to_config

    cfg = settings_to_config(bpy.context.scene, strict=False).to_dict()
    ref = SimulationConfig().to_dict()
    for key in ("camera", "spots"):
        cfg.pop(key), ref.pop(key)
    assert cfg.keys() == ref.keys()
    for key, want in ref.items():   # Blender stores FloatProperty in float32
        assert cfg[key] == (pytest.approx(want, rel=1e-6) if isinstance(want, float) else want), key
