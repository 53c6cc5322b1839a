"""Headless two-bounce lidar simulator (Cycles): a Blender scene -> a dataset directory.

With a Blender binary (4.2+; the scene is the opened .blend):
    blender -b scene.blend --python-exit-code 1 -P pipeline/simulate.py -- --out DIR [options]
With the bpy module (Blender as a Python module, e.g. the project's .venv):
    python pipeline/simulate.py [scene.blend] --out DIR [options]
    python pipeline/simulate.py --example cave-chair --out DIR --resolution 64

Settings, later ones winning: SimulationConfig defaults < the settings the add-on stored
in the .blend (Text datablock torch_recon.contract.simulation.CONFIG_TEXT_NAME; for --example, the
example's own) < --config FILE.json < command-line options. Options go through
SimulationConfig.validate(), so an error names the setting.

Inside Blender's own Python, OpenEXR / trimesh / scipy may be missing; then the
project's .venv site-packages (python3.11) is appended to sys.path AFTER Blender's own
paths (Blender's numpy stays first). Blender 4.2-5.0 ship Python 3.11, which the .venv
matches.

Exit status: 0 on success; 2 with a one-line 'simulate: error: ...' message on bad
input (nothing is written: the dataset at --out, if any, is left as it was).
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def _add_venv_site_packages():
    """Blender's bundled Python lacks OpenEXR/trimesh/scipy: borrow the project's .venv (appended last)."""
    import importlib.util

    if any(importlib.util.find_spec(mod) is None for mod in ("OpenEXR", "trimesh", "scipy")):
        for sp in sorted(glob.glob(str(ROOT / ".venv" / "lib" / "python3.*" / "site-packages"))):
            if sp not in sys.path:
                sys.path.append(sp)


def _argv() -> list:
    """Options after '--' (Blender binary style), else everything after the script name."""
    if "--" in sys.argv:
        return sys.argv[sys.argv.index("--") + 1:]
    return sys.argv[1:]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="platolidar simulate", description="Cycles two-bounce lidar simulator "
                                 "(defaults: the paper's 512x512 pixels, 391 bins of 128 ps, 16 spots)")
    ap.add_argument("blend", nargs="?", help="scene .blend (with a Blender binary: the file Blender opened)")
    ap.add_argument("--blender", metavar="BIN", help="(platolidar simulate only) run inside this Blender binary "
                    "instead of the bpy module")
    ap.add_argument("--out", required=True, help="dataset directory to write (replaced atomically)")
    ap.add_argument("--example", help="build an example scene instead of a .blend: "
                    "cave-chair, monkey, occluders, curved-wall, low-albedo, ambient, organic-occluded, "
                    "thin-structures, dark-room, outside-fov")
    ap.add_argument("--config", help="SimulationConfig JSON file (e.g. exported by the add-on)")
    ap.add_argument("--camera", help="camera object (default: the scene camera)")
    ap.add_argument("--resolution", type=int, help="N: an N x N sensor")
    ap.add_argument("--width", type=int)
    ap.add_argument("--height", type=int)
    ap.add_argument("--bins", type=int, help="time bins per pixel")
    bin_width = ap.add_mutually_exclusive_group()
    bin_width.add_argument("--bin-ps", type=float, help="bin width in picoseconds")
    bin_width.add_argument("--bin-m", type=float, help="bin width in metres of optical path (e.g. the paper's "
                           "0.0384); give this or --bin-ps")
    ap.add_argument("--start-m", type=float, help="optical path (m) of the first bin's start")
    ap.add_argument("--pulse-fwhm-ps", type=float, help="laser pulse width (FWHM, ps)")
    ap.add_argument("--pulse-shape", choices=("gaussian", "box"))
    ap.add_argument("--footprint-m", type=float, help="laser footprint radius (m)")
    ap.add_argument("--subpixel", type=int, help="base sub-pixel samples per pixel (a square number: 1, 4, 9, ...)")
    ap.add_argument("--adaptive", type=int, metavar="N", help="samples of a pixel at a depth, shadow or path-spread "
                    "edge (a square number; 0: every pixel gets --subpixel samples)")
    ap.add_argument("--adaptive-spread-bins", type=float, help="refine pixels whose optical path spreads over more "
                    "bins than this (default 1)")
    ap.add_argument("--shading", choices=("lambertian", "cycles"), help="per-spot light: deferred Lambertian "
                    "shading with shadow rays (default), or a Cycles render per spot (glossy materials; slower)")
    spots = ap.add_mutually_exclusive_group()
    spots.add_argument("--spots", type=int, help="K spots: K of the scene's spots (diversity heuristic), or K "
                       "of --candidates random ones when the scene has none")
    spots.add_argument("--spot-list", help="explicit laser targets 'x,y,z;x,y,z;...' (world, m); write "
                       "--spot-list=-2,3,0 when the first number is negative")
    ap.add_argument("--candidates", type=int, help="random candidate spots to choose from (default 24)")
    ap.add_argument("--photons", type=float, help="photons of the brightest two-bounce pixel (0: keep radiance units)")
    ap.add_argument("--poisson", action=argparse.BooleanOptionalAction, default=None, help="Poisson photon counts")
    ap.add_argument("--ambient", type=float, help="ambient photons per pixel per bin, before the filter")
    ap.add_argument("--wavelength-filter", type=float, help="fraction of ambient light the band-pass filter passes")
    ap.add_argument("--dark-counts", type=float, help="dark counts per pixel per bin")
    ap.add_argument("--time-gate", type=int, metavar="W", help="keep a window of W bins around the expected return")
    ap.add_argument("--bounces", type=int, choices=(2, 3), help="3 adds third-order light (slower)")
    ap.add_argument("--vpls", type=int, help="with --bounces 3: virtual point lights per spot (default 16)")
    ap.add_argument("--rgb", action="store_true", default=None, help="also RGB images (RGB-shadow baseline)")
    ap.add_argument("--test-views", help="ground-truth test views: N (split like the paper's 39 dolly : 100 "
                    "orbit) or 'D,O'; 0 for none")
    ap.add_argument("--test-view-resolution", type=int)
    ap.add_argument("--no-gt", action="store_true", help="no ground truth (depths, mesh)")
    ap.add_argument("--seed", type=int)
    ap.add_argument("--set", dest="set_values", action="append", default=[], metavar="KEY=VALUE",
                    help="any SimulationConfig setting by name, e.g. --set photons_per_pixel=500 (repeatable; "
                         "wins over the options above)")
    return ap


def _parse_test_views(text: str):
    from torch_recon.contract.simulation import ConfigError

    try:
        parts = [int(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError("--test-views", "test_views_dolly", f"expected N or 'D,O', got {text!r}") from None
    if len(parts) == 2:
        return parts[0], parts[1]
    if len(parts) != 1 or parts[0] < 0:
        raise ConfigError("--test-views", "test_views_dolly", f"expected N >= 0 or 'D,O', got {text!r}")
    n = parts[0]
    dolly = round(n * 39 / 139)
    return dolly, n - dolly


def _parse_spot_list(text: str):
    from torch_recon.contract.simulation import ConfigError, SpotConfig

    spots = []
    for i, item in enumerate(t for t in text.split(";") if t.strip()):
        try:
            xyz = [float(v) for v in item.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            raise ConfigError("--spot-list", f"spots[{i}]", f"expected 'x,y,z', got {item!r}")
        spots.append(SpotConfig(target=xyz, name=f"target_{i}"))
    if not spots:
        raise ConfigError("--spot-list", "spots", "expected at least one 'x,y,z'")
    return spots


def apply_options(cfg, args):
    """Command-line options over a SimulationConfig (validated afterwards by the caller)."""
    direct = {"camera": "camera", "width": "width", "height": "height", "bins": "bins", "bin_ps": "bin_ps",
              "start_m": "start_m", "pulse_fwhm_ps": "pulse_fwhm_ps", "pulse_shape": "pulse_shape",
              "footprint_m": "footprint_radius_m", "subpixel": "subpixel_samples", "candidates": "random_candidates",
              "adaptive": "adaptive_subpixel_samples", "adaptive_spread_bins": "adaptive_spread_bins",
              "shading": "shading", "bin_m": "bin_m",
              "photons": "photons_per_pixel", "poisson": "photon_counts", "ambient": "ambient_per_bin",
              "wavelength_filter": "wavelength_filter_factor", "dark_counts": "dark_counts_per_bin",
              "bounces": "bounces", "vpls": "third_bounce_vpls", "rgb": "rgb",
              "test_view_resolution": "test_view_resolution", "seed": "seed"}
    if args.resolution is not None:
        cfg.width = cfg.height = args.resolution
    for opt, name in direct.items():
        v = getattr(args, opt)
        if v is not None:
            setattr(cfg, name, v)
    if args.bin_ps is not None:       # the command line's unit wins over a stored bin_m
        cfg.bin_m = None
    if args.bin_m is not None:
        from torch_recon.contract.units import m_to_ps

        if args.bin_m > 0:            # else validate() names bin_m
            cfg.bin_ps = m_to_ps(args.bin_m)
    if args.spots is not None:
        cfg.random_keep = args.spots
        if args.spots > cfg.random_candidates and args.candidates is None:
            cfg.random_candidates = args.spots
    if args.spot_list is not None:
        cfg.spots = _parse_spot_list(args.spot_list)
    if args.time_gate is not None:
        cfg.time_gate = args.time_gate > 0
        if args.time_gate > 0:
            cfg.gate_window_bins = args.time_gate
    if args.test_views is not None:
        cfg.test_views_dolly, cfg.test_views_orbit = _parse_test_views(args.test_views)
    if args.no_gt:
        cfg.train_depth, cfg.gt_mesh = False, False
        cfg.test_views_dolly = cfg.test_views_orbit = 0
    return cfg


def load_config(args, bs):
    from torch_recon.contract.simulation import SimulationConfig

    cfg = bs.stored_config() or SimulationConfig()
    if args.config:
        from torch_recon.contract.settings import load_file

        file_cfg = SimulationConfig.load(args.config)          # validates, rejects unknown settings
        raw = load_file(args.config)
        merged = {**cfg.to_dict(), **{k: v for k, v in raw.items() if k != "schema_version"}}
        merged["spots"] = [vars(s) for s in file_cfg.spots] if "spots" in raw else [vars(s) for s in cfg.spots]
        cfg = SimulationConfig.from_dict(merged, args.config)
    cfg = apply_options(cfg, args)
    cfg = apply_sets(cfg, args.set_values)
    return cfg.validate("command line" if not args.config else f"command line + {args.config}")


def apply_sets(cfg, assignments):
    """--set KEY=VALUE over a SimulationConfig, each value type-checked by the shared settings mechanism."""
    from torch_recon.contract.settings import check_value, find_spec, parse_assignments
    from torch_recon.contract.errors import SettingsError

    for key, raw in parse_assignments(assignments).items():
        if key == "spots":
            raise SettingsError("spots", "set spots with --spot-list or a --config file")
        setattr(cfg, key, check_value(find_spec(type(cfg), key), raw))
    return cfg


def simulate(args) -> int:
    import bpy

    from pipeline import blender_scene as bs
    from pipeline import simulator
    from torch_recon.contract import scenes

    if args.example and args.blend:
        raise simulator.SimulationError("give either a .blend or --example, not both")
    if args.example:
        try:
            ex = scenes.example(args.example)
        except KeyError as exc:
            raise simulator.SimulationError(exc.args[0]) from None
        bs.build_example(ex)
        label = f"example:{args.example}"
    elif args.blend:
        path = os.path.abspath(args.blend)
        if not os.path.isfile(path):
            raise simulator.SimulationError(f"{args.blend}: no such .blend file")
        try:
            bpy.ops.wm.open_mainfile(filepath=path, load_ui=False)
        except RuntimeError as exc:
            msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unreadable"
            raise simulator.SimulationError(f"{args.blend}: cannot open as a .blend file ({msg})") from None
        label = os.path.basename(path)
    elif bpy.data.filepath:
        label = os.path.basename(bpy.data.filepath)   # Blender binary: the file it opened
    else:
        raise simulator.SimulationError("no scene: give a .blend file or --example NAME")
    cfg = load_config(args, bs)
    result = simulator.run(cfg, args.out, label, keep_requested=args.spots is not None)
    t = result["timings"]
    print(f"simulate: wrote {args.out}: {result['spots']} spots, {cfg.width}x{cfg.height}x{cfg.bins} bins, "
          f"{t['total_s']:.1f} s", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    args = build_parser().parse_args(_argv() if argv is None else argv)  # exits 2 with a usage line on bad options
    _add_venv_site_packages()
    from torch_recon.contract.dataset.staging import InterruptGuard
    from torch_recon.contract.errors import run_command

    InterruptGuard.install()      # Ctrl-C / SIGTERM stop the run between renders; the old dataset stays
    try:
        return run_command(simulate, args, prog="simulate",
                           interrupted="interrupted; nothing written, the dataset at --out (if any) is as it was")
    finally:
        InterruptGuard.uninstall()


if __name__ == "__main__":
    sys.exit(main())
