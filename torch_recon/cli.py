"""Command-line entry: one subcommand per stage, each defined in its own module.

A command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` (taking the parsed args, returning an exit code). Errors the user can fix
(bad dataset, bad settings) print one clear line and exit 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: (module, what it provides) in the order shown by --help
COMMAND_MODULES = (
    "torch_recon.commands.preprocess",
    "torch_recon.commands.baseline",
    "torch_recon.commands.fit",
    "torch_recon.commands.evaluate",
    "torch_recon.commands.convert",
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m torch_recon",
                                description="Two-bounce lidar reconstruction (PlatoNeRF method), torch, CPU or CUDA.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:  # command not built in this version
                continue
            raise
        mod.register(sub)
    return p


def main(argv=None) -> int:
    from .contract.dataset import DatasetError

    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (DatasetError, ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
