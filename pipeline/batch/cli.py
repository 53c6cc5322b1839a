"""`platolidar batch PLAN --out DIR`: run a plan file's tasks (docs/batch.md); options from BatchSettings."""

from __future__ import annotations

import argparse

BATCH_FLAGS = ("workers", "address", "threads", "task_timeout_s", "progress", "dry_run")


def register(sub) -> None:
    from torch_recon.contract.settings import add_arguments

    from .runner import BatchSettings

    p = sub.add_parser("batch", help="simulate, fit and evaluate many scenes on a Dask cluster (local by default)",
                       description="Expand a plan file (scenes x simulation grid x methods) into tasks and run "
                                   "them on Dask distributed: a local cluster with one worker per core, or the "
                                   "cluster at --address. Finished tasks (same content key) are skipped; failed "
                                   "or interrupted ones run again. Results: OUT/results.csv, results.json, "
                                   "summary.html; each task's log: OUT/tasks/<stage>/<name>/log.txt.")
    p.add_argument("plan", help="plan file (TOML or JSON; docs/batch.md)")
    p.add_argument("--out", required=True, help="output folder (tasks/, results.csv, results.json, summary.html)")
    add_arguments(p, BatchSettings, BATCH_FLAGS)
    p.set_defaults(func=run)


def run(args) -> int:
    from torch_recon.contract.settings import from_args

    from .runner import BatchSettings, run_batch

    s = from_args(BatchSettings, args)
    summary = run_batch(args.plan, args.out, s)
    c = summary["counts"]
    return 1 if c.get("failed", 0) or c.get("skipped", 0) else 0


def main(argv=None) -> int:
    from torch_recon.contract.dataset.staging import terminate_as_interrupt
    from torch_recon.contract.errors import run_command

    p = argparse.ArgumentParser(prog="python -m pipeline.batch")
    sub = p.add_subparsers(dest="command", required=True)
    register(sub)
    import sys
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(["batch", *argv])
    with terminate_as_interrupt():
        return run_command(args.func, args, prog="batch")
