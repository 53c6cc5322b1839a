"""`simulate`: a Blender scene or an example -> dataset directory (the Cycles simulator, pipeline/simulate.py).

Every option after `simulate` goes to pipeline/simulate.py (`platolidar simulate -h` lists them). Without
--blender it runs in this Python (which needs the bpy module); with `--blender BIN` it runs inside that
Blender binary, which opens the .blend itself.
"""

from __future__ import annotations

import argparse


def register(sub) -> None:
    # listed in `platolidar -h`; the options themselves are parsed by pipeline/simulate.py (see main)
    p = sub.add_parser("simulate", help="Cycles two-bounce lidar simulator: scene -> dataset", add_help=False)
    p.add_argument("options", nargs=argparse.REMAINDER)


def main(argv: list[str]) -> int:
    argv = list(argv)
    blender = None
    for i, a in enumerate(argv):
        if a == "--blender" and i + 1 < len(argv):
            blender = argv[i + 1]
            del argv[i:i + 2]
            break
        if a.startswith("--blender="):
            blender = a.split("=", 1)[1]
            del argv[i]
            break
    if blender:
        from pipeline.launch import run_simulate

        blend = argv.pop(0) if argv and not argv[0].startswith("-") else None
        return run_simulate(argv, blend=blend, blender=blender, capture_output=False).returncode
    from pipeline.simulate import main as simulate_main

    return simulate_main(argv)
