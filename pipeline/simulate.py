"""Headless two-bounce lidar simulator (Cycles): a Blender scene -> a dataset directory.

With a Blender binary (4.2+; the scene is the opened .blend):
    blender -b scene.blend --python-exit-code 1 -P pipeline/simulate.py -- --out DIR [options]
With the bpy module (Blender as a Python module, e.g. the project's .venv):
    python pipeline/simulate.py [scene.blend] --out DIR [options]
    python pipeline/simulate.py --example cave-chair --out DIR --resolution 64

Settings, later ones winning: SimulationConfig defaults < the settings the add-on stored
in the .blend (Text datablock torch_recon.contract.simulation.CONFIG_TEXT_NAME; for --example, the
example's own) < --config FILE (JSON, or TOML by suffix) < flags < --set KEY=VALUE. The flags are
generated from SimulationConfig (one per setting, its short aliases in SETTINGS_META, e.g. --spots for
random_keep), plus --resolution, --time-gate W, --test-views, --no-gt and --spot-list, which set several
settings at once. Every value is type- and range-checked, and an error names the setting.

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
from dataclasses import fields
import os
import sys
from pathlib import Path

# one BLAS thread (read when numpy loads; inside a Blender binary numpy is already loaded): the simulator
# runs its own spot and writer threads, and OpenBLAS's threads, which busy-wait between the small (N, 3)
# products of the hot path, only compete with them (a 139-view range-image loop: 1.7 -> 0.1 s CPU, load 7)
if "numpy" not in sys.modules:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

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


#: fields whose command-line form is a special case below (the rest get a flag from SimulationConfig):
#: time_gate is `--time-gate W` (a window in bins, 0: off); spots is `--spot-list 'x,y,z;...'`.
SPECIAL_FIELDS = ("time_gate", "spots")


def build_parser() -> argparse.ArgumentParser:
    """Flags generated from SimulationConfig (contract/settings.py: name, aliases, type, unit, default,
    help), plus the few that set several settings at once (--resolution, --time-gate, --test-views, --no-gt,
    --spot-list). Which source wins: load_config."""
    from torch_recon.contract.settings import add_arguments
    from torch_recon.contract.simulation import SimulationConfig

    d = SimulationConfig()
    ap = argparse.ArgumentParser(prog="platolidar simulate", description="Cycles two-bounce lidar simulator "
                                 "(defaults: the paper's 512x512 pixels, 391 bins of 128 ps, 16 spots)")
    ap.add_argument("blend", nargs="?", help="scene .blend (with a Blender binary: the file Blender opened)")
    ap.add_argument("--blender", metavar="BIN", help="(platolidar simulate only) run inside this Blender binary "
                    "instead of the bpy module")
    ap.add_argument("--out", required=True, help="dataset directory to write (replaced atomically)")
    ap.add_argument("--example", help="build an example scene instead of a .blend: "
                    "cave-chair, monkey, occluders, curved-wall, low-albedo, ambient, organic-occluded, "
                    "thin-structures, dark-room, outside-fov")
    ap.add_argument("--resolution", type=int, metavar="N", help=f"an N x N sensor (sets width and height) "
                    f"[default {d.width} x {d.height} px]")
    ap.add_argument("--time-gate", type=int, metavar="W", help="keep a window of W bins around the expected "
                    "return; 0: off (sets time_gate and gate_window_bins) [default off]")
    ap.add_argument("--spot-list", help="explicit laser targets 'x,y,z;x,y,z;...' (world, m); write "
                    "--spot-list=-2,3,0 when the first number is negative (sets spots) [default: the scene's "
                    "spots, else random ones]")
    ap.add_argument("--test-views", metavar="N|D,O", help="ground-truth test views: N (split like the paper's "
                    "39 dolly : 100 orbit) or 'D,O'; 0 for none (sets test_views_dolly and test_views_orbit) "
                    f"[default {d.test_views_dolly},{d.test_views_orbit}]")
    ap.add_argument("--no-gt", action="store_true", help="no ground truth: no depths, mesh or test views")
    names = [f.name for f in fields(SimulationConfig) if f.name not in SPECIAL_FIELDS]
    add_arguments(ap, SimulationConfig, names)
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
    from torch_recon.contract.simulation import ConfigError

    spots = []
    for i, item in enumerate(t for t in text.split(";") if t.strip()):
        try:
            xyz = [float(v) for v in item.split(",")]
        except ValueError:
            xyz = []
        if len(xyz) != 3:
            raise ConfigError("--spot-list", f"spots[{i}]", f"expected 'x,y,z', got {item!r}")
        spots.append({"target": xyz, "name": f"target_{i}"})
    if not spots:
        raise ConfigError("--spot-list", "spots", "expected at least one 'x,y,z'")
    return spots


def flag_values(args, cfg) -> dict:
    """The settings the command-line flags give (setting -> value or text), over `cfg` (the layers below)."""
    given = {key: getattr(args, dest) for dest, key in args._settings_flags.items()
             if getattr(args, dest, None) is not None}
    values = {}
    if args.resolution is not None:
        values["width"] = values["height"] = args.resolution
    values.update(given)                # --width/--height win over --resolution
    if "random_keep" in given and "random_candidates" not in given:
        from torch_recon.contract.settings import check_value, find_spec

        keep = check_value(find_spec(type(cfg), "random_keep"), given["random_keep"])
        if keep > cfg.random_candidates:    # --spots K with fewer candidates: draw K
            values["random_candidates"] = keep
    if args.spot_list is not None:
        values["spots"] = _parse_spot_list(args.spot_list)
    if args.time_gate is not None:
        values["time_gate"] = args.time_gate > 0
        if args.time_gate > 0:
            values["gate_window_bins"] = args.time_gate
    if args.test_views is not None:
        values["test_views_dolly"], values["test_views_orbit"] = _parse_test_views(args.test_views)
    if args.no_gt:
        values.update(train_depth=False, gt_mesh=False, test_views_dolly=0, test_views_orbit=0)
    return values


def check_options(args) -> None:
    """Each flag's and --set value's type and range, before a scene is built (relations: load_config)."""
    from torch_recon.contract.settings import check_value, find_spec, parse_assignments
    from torch_recon.contract.simulation import SimulationConfig

    for key, raw in {**flag_values(args, SimulationConfig()), **parse_assignments(args.set_values)}.items():
        if key != "spots":
            check_value(find_spec(SimulationConfig, key), raw)


def spots_requested(args) -> bool:
    """--spots K given: keep K of the scene's own spots too (not only of random ones)."""
    return any(key == "random_keep" and getattr(args, d) is not None for d, key in args._settings_flags.items())


def load_config(args, base=None):
    """Settings, later ones winning: SimulationConfig defaults < `base` (the settings stored in the .blend)
    < --config FILE < flags < --set KEY=VALUE. Each layer is type- and range-checked naming the setting."""
    from torch_recon.contract.errors import SettingsError
    from torch_recon.contract.settings import load_file, parse_assignments
    from torch_recon.contract.simulation import ConfigError, SimulationConfig

    cfg = base if base is not None else SimulationConfig()
    if args.config:
        try:
            raw = load_file(args.config)
        except OSError as exc:
            raise ConfigError(str(args.config), "", f"cannot read ({exc.strerror})") from None
        cfg = cfg.updated(raw, str(args.config))
    values = flag_values(args, cfg)
    sets = parse_assignments(args.set_values)
    if "spots" in sets:
        raise SettingsError("spots", "set spots with --spot-list or a --config file")
    values.update(sets)                 # --set last: it wins over the flags
    return cfg.updated(values, "command line" if not args.config else f"command line + {args.config}")


def simulate(args) -> int:
    import bpy

    from pipeline import blender_scene as bs
    from pipeline import simulator
    from torch_recon.contract import scenes

    check_options(args)
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
    cfg = load_config(args, bs.stored_config())
    result = simulator.run(cfg, args.out, label, keep_requested=spots_requested(args))
    t = result["timings"]
    print(f"simulate: wrote {args.out}: {result['spots']} spots, {cfg.width}x{cfg.height}x{cfg.bins} bins, "
          f"{t['total_s']:.1f} s", file=sys.stderr)
    return 0


def parse_args(argv) -> argparse.Namespace:
    """The options (exit 2 with a usage line on a bad one, as argparse does)."""
    ap = build_parser()
    args = ap.parse_args(argv)
    dest = {key: d for d, key in args._settings_flags.items()}
    if getattr(args, dest["bin_ps"]) is not None and getattr(args, dest["bin_m"]) is not None:
        ap.error("argument --bin-m: not allowed with argument --bin-ps")     # one unit for the bin width
    if getattr(args, dest["random_keep"]) is not None and args.spot_list is not None:
        ap.error("argument --spot-list: not allowed with argument --spots")
    return args


def main(argv=None) -> int:
    args = parse_args(_argv() if argv is None else argv)
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
    status = main()
    # leave without Blender's own shutdown (add-ons unregistered, every datablock freed: 0.3 s of a 128 x 128
    # run): the dataset is committed, the render's temporary folder removed and every thread joined by now
    # Blender's session temporary folder (bpy.app.tempdir) is one thing that shutdown removes: do it here
    _bpy = sys.modules.get("bpy")
    if _bpy is not None and _bpy.app.tempdir:
        import shutil

        shutil.rmtree(_bpy.app.tempdir, ignore_errors=True)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)
