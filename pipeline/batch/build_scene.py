"""Write the .blend of a procedural scene (bpy): `python -m pipeline.batch.build_scene --seed N --blend F`.

The scene comes from torch_recon.contract.procedural (seed + settings) and is built the way the examples
are (pipeline.blender_scene.build_example: labelled objects, the sensor camera, the spots stored in the
settings). The .blend is written beside and renamed over `--blend`, so a kill leaves no half file.
"""

from __future__ import annotations

import argparse
import json
import os
import sys


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="build_scene", description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--settings", default="{}", help="ProceduralSettings as JSON")
    ap.add_argument("--blend", required=True, help=".blend file to write")
    args = ap.parse_args(argv)
    from torch_recon.contract.errors import run_command

    return run_command(_build, args, prog="build_scene")


def _build(args) -> int:
    import bpy

    from pipeline.blender_scene import build_example
    from torch_recon.contract.errors import SettingsError
    from torch_recon.contract.procedural import procedural_scene, settings_from_dict

    try:
        data = json.loads(args.settings)
    except ValueError as exc:
        raise SettingsError("settings", f"expected JSON, got {args.settings[:60]!r} ({exc})") from None
    ex = procedural_scene(args.seed, settings_from_dict(data, "--settings"))
    build_example(ex)
    target = os.path.abspath(args.blend)
    tmp = os.path.join(os.path.dirname(target), f".{os.path.basename(target)}.{os.getpid()}.blend")
    bpy.ops.wm.save_as_mainfile(filepath=tmp, compress=True)
    os.replace(tmp, target)
    print(f"build_scene: {ex.name}: {ex.description} -> {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
