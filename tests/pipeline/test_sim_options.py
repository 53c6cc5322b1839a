"""pipeline/simulate.py's command line is generated from SimulationConfig (no bpy needed: parsing only)."""

from __future__ import annotations

import json
from dataclasses import fields

import pytest

from pipeline.simulate import SPECIAL_FIELDS, build_parser, check_options, load_config, parse_args
from torch_recon.contract.errors import SettingsError
from torch_recon.contract.settings import specs
from torch_recon.contract.simulation import SimulationConfig

#: the flags of the settings that have no flag of their own name
SPECIAL_FLAGS = {"time_gate": "--time-gate", "spots": "--spot-list"}


def _cfg(*argv, base=None):
    return load_config(parse_args(["--out", "x", *map(str, argv)]), base)


def _options():
    return {s: a for a in build_parser()._actions for s in a.option_strings}


def test_every_setting_has_a_flag_whose_help_shows_its_default():
    options = _options()
    assert set(SPECIAL_FIELDS) == set(SPECIAL_FLAGS)
    for spec in specs(SimulationConfig):
        flag = SPECIAL_FLAGS.get(spec.name, "--" + spec.name.replace("_", "-"))
        assert flag in options, f"{spec.name}: no {flag}"
        if spec.name not in SPECIAL_FLAGS:
            assert spec.default == getattr(SimulationConfig(), spec.name)
            assert f"[default {spec.default}; setting {spec.name}]" in options[flag].help, spec.name
            if spec.unit:
                assert f"({spec.unit})" in options[flag].help


def test_no_flag_means_the_dataclass_defaults():
    assert _cfg() == SimulationConfig().validate()
    args = parse_args(["--out", "x"])
    assert all(getattr(args, dest) is None for dest in args._settings_flags)   # defaults live in the dataclass


def _other_value(spec, default):
    if spec.kind is bool:
        return not default
    if spec.choices:
        return next(c for c in spec.choices if c != default)
    if spec.kind is str:
        return "Other"
    if spec.name == "bin_m":
        return 0.05
    if spec.name in ("subpixel_samples", "adaptive_subpixel_samples"):
        return 16 if default != 16 else 9
    if spec.name == "wavelength_filter_factor":
        return 0.5
    return type(default)(default + 3) if isinstance(default, (int, float)) else 3


@pytest.mark.parametrize("spec", [s for s in specs(SimulationConfig) if s.name not in SPECIAL_FIELDS],
                         ids=lambda s: s.name)
def test_each_flag_and_alias_sets_its_setting(spec):
    value = _other_value(spec, spec.default)
    for flag in ("--" + spec.name.replace("_", "-"), *spec.flags):
        argv = [f"--{'no-' if not value else ''}{flag[2:]}"] if spec.kind is bool else [flag, value]
        if spec.name == "random_keep":
            argv += ["--candidates", 30]
        got = getattr(_cfg(*argv), spec.name)
        assert got == pytest.approx(value) if isinstance(value, float) else got == value, (flag, got)


def test_documented_short_flags():
    c = _cfg("--resolution", 64, "--height", 32, "--spots", 30, "--time-gate", 8, "--test-views", 10,
             "--photons", 50, "--poisson", "--footprint-m", 0.01, "--subpixel", 9, "--adaptive", 0)
    assert (c.width, c.height, c.random_keep, c.random_candidates) == (64, 32, 30, 30)   # --spots K draws K
    assert (c.time_gate, c.gate_window_bins, c.test_views_dolly, c.test_views_orbit) == (True, 8, 3, 7)
    assert (c.photons_per_pixel, c.photon_counts, c.footprint_radius_m) == (50.0, True, 0.01)
    assert (c.subpixel_samples, c.adaptive_subpixel_samples) == (9, 0)
    c = _cfg("--no-gt", "--spot-list=-2,3,0;1,2,0", "--time-gate", 0)
    assert (c.train_depth, c.gt_mesh, c.test_views_dolly, c.test_views_orbit, c.time_gate) == (False,) * 2 + (0, 0, False)
    assert [s.target for s in c.spots] == [[-2.0, 3.0, 0.0], [1.0, 2.0, 0.0]]


def test_layers_blend_then_config_then_flags_then_set(tmp_path):
    stored = SimulationConfig().updated({"bins": 100, "width": 40, "height": 40, "seed": 5, "bin_m": 0.05,
                                         "spots": [{"target": [0, 3, 0]}]})
    cfg = tmp_path / "sim.toml"
    cfg.write_text("bins = 200\nwidth = 30\nphotons_per_pixel = 10.0\n")
    c = _cfg("--config", cfg, "--bins", 300, "--photons", 20, "--set", "bins=400", base=stored)
    assert (c.bins, c.width, c.height, c.seed, c.photons_per_pixel) == (400, 30, 40, 5, 20.0)
    assert c.bin_m == 0.05 and len(c.spots) == 1       # untouched by later layers
    c = _cfg("--config", cfg, "--bin-ps", 100, base=stored)   # the flag's unit wins over the stored bin_m
    assert (c.bin_m, c.bin_ps) == (None, 100.0)
    (tmp_path / "sim.json").write_text(json.dumps({"bin_m": 0.0384}))     # bin_ps follows a file's bin_m
    assert _cfg("--config", tmp_path / "sim.json").bin_ps == pytest.approx(128.0886, abs=1e-4)


@pytest.mark.parametrize("argv,says", [
    (["--bins", "abc"], "setting bins: expected an integer, got 'abc'"),
    (["--photons", "-1"], "setting photons_per_pixel: expected a value >= 0"),
    (["--wavelength-filter", "2"], "setting wavelength_filter_factor: expected a value in [0, 1]"),
    (["--bounces", "4"], "setting bounces: expected one of 2, 3"),
    (["--shading", "toon"], "setting shading: expected one of lambertian, cycles"),
    (["--adaptive", "8"], "setting adaptive_subpixel_samples: expected 0 (off) or a square number"),
    (["--footprint-m", "0"], "setting footprint_radius_m: expected a positive number"),
    (["--set", "colour=red"], "setting colour: unknown setting"),
    (["--set", "spots=[]"], "setting spots: set spots with --spot-list"),
    (["--spots", "40"], "setting random_keep"),
    (["--set", "random_keep=40"], "setting random_keep: cannot keep 40 of 24"),
])
def test_bad_values_name_the_setting(argv, says):
    with pytest.raises(SettingsError) as exc:
        _cfg(*argv, "--candidates", "24") if argv[0] == "--spots" else _cfg(*argv)
    assert says in str(exc.value)


@pytest.mark.parametrize("argv", [["--bin-m", "0.0384", "--bin-ps", "128"], ["--spots", "3", "--spot-list", "0,3,0"],
                                  ["--frobnicate"]])
def test_contradicting_or_unknown_flags_exit_2(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        parse_args(["--out", "x", *argv])
    assert exc.value.code == 2 and "error:" in capsys.readouterr().err


def test_values_are_checked_before_a_scene_is_built():
    for argv in (["--bins", "abc"], ["--set", "bins=0"], ["--set", "colour=red"], ["--adaptive", "x"]):
        with pytest.raises(SettingsError):
            check_options(parse_args(["--out", "x", *argv]))
    check_options(parse_args(["--out", "x", "--spots", "40", "--set", "seed=2"]))   # relations: later
