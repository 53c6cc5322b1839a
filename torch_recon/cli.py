"""Command-line entry: one subcommand per stage, each defined in its own module.

A command module exposes ``register(subparsers)``, which adds its parser and sets
``func`` (taking the parsed args, returning an exit code). Errors the user can fix
(`contract.errors.PlatolidarError`: bad dataset, bad settings; and `OSError`) print one
clear line and exit 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Before any command imports torch: its OpenMP threads sleep when idle instead of spinning. On a machine where
# another process holds a core, spinning threads wait on each other: a 2-thread cave-chair fit took 69-74 s at
# load 3 against 43-52 s with this (session 20, docs/benchmarks.md "Known issues"). A user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

#: (module, what it provides) in the order shown by --help
COMMAND_MODULES = (
    "torch_recon.commands.simulate",
    "torch_recon.commands.preprocess",
    "torch_recon.commands.baseline",
    "torch_recon.commands.fit",
    "torch_recon.commands.evaluate",
    "torch_recon.commands.advise_spots",
    "torch_recon.commands.convert",
    "torch_recon.commands.batch",
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="platolidar",
                                description="Single-view two-bounce lidar (PlatoNeRF): simulate a scene, preprocess, "
                                            "reconstruct (fit, baseline), evaluate, convert datasets.")
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
    from .contract.errors import run_command

    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["simulate"]:
        # everything after 'simulate' belongs to pipeline/simulate.py (its own parser and error handling)
        from .commands.simulate import main as simulate_main
        return simulate_main(argv[1:])
    args = build_parser().parse_args(argv)
    from .contract.dataset.staging import terminate_as_interrupt

    with terminate_as_interrupt():     # SIGTERM cleans up like Ctrl-C (staging folders, temporary files)
        return run_command(args.func, args)
