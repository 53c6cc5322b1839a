"""Run a plan's tasks on Dask distributed: an embedded local cluster by default, or an existing one.

- Local: `distributed.LocalCluster`, one single-threaded worker process per core (each stage is itself a
  subprocess of its worker). Existing cluster: `address` of its scheduler (dask-jobqueue on Slurm,
  dask-kubernetes on Kubernetes, `dask scheduler` / `dask worker` by hand; docs/batch.md).
- Tasks already finished (their record says done under the same content key) are not submitted; the rest
  are submitted with their input tasks as Dask dependencies, so the engine orders and places them.
- A worker that dies mid-task (killed, out of memory, node lost) is the engine's business: the scheduler
  resubmits its task elsewhere, up to `allowed_failures` times. A stage that fails is recorded as failed
  (its dependants are skipped) and is tried again by the next run.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

from .execute import finished, run_task, write_json_atomic
from .plan import code_version, expand
from .results import write_results


@dataclass
class BatchSettings:
    """Settings of `platolidar batch` (the plan file says what to run; these say how)."""

    workers: int | None = None           # local workers (None: one per core); ignored with an address
    address: str | None = None           # scheduler of an existing Dask cluster, e.g. tcp://10.0.0.5:8786
    threads: int = 1                     # CPU threads each stage may use (torch, OpenMP)
    task_timeout_s: float | None = None  # a stage running longer is stopped and its task counts as failed
    allowed_failures: int = 3            # times a task may lose its worker (killed, node lost) before it fails
    python: str | None = None            # interpreter the stages run in (None: the worker's own)
    blender: str | None = None           # a Blender binary for simulate (None: the bpy module of `python`)
    progress: bool = True                # a progress bar over tasks
    dry_run: bool = False                # list the tasks and which are finished; run nothing

    SETTINGS_META = {"workers": {"range": (1, 1024)}, "threads": {"range": (1, 1024)},
                     "task_timeout_s": {"range": (1, None), "unit": "s"}, "allowed_failures": {"range": (0, 100)}}


def local_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


@contextmanager
def dask_client(s: BatchSettings):
    """A Dask client: of the cluster at `s.address`, or of a local cluster started (and stopped) here."""
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.scheduler.allowed-failures": s.allowed_failures,
                          "distributed.worker.daemon": False}):      # workers start stage subprocesses
        if s.address:
            with Client(s.address, timeout="30s") as client:
                yield client
            return
        n = s.workers or local_cores()
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                          memory_limit=0, silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
            yield client


def _options(s: BatchSettings) -> dict:
    return {"threads": s.threads, "task_timeout_s": s.task_timeout_s, "python": s.python, "blender": s.blender}


def run_batch(plan_path, out, s: BatchSettings, log=print) -> dict:
    """Expand the plan, run what is not finished, write the results; returns the run's summary."""
    from distributed import as_completed

    t0 = time.time()
    out = Path(out).absolute()
    version = code_version()
    tasks = expand(plan_path, version)
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "plan.json", {"plan": str(Path(plan_path).absolute()), "code_version": version,
                                          "tasks": [t.to_dict() for t in tasks]})
    records = {t.key: r for t in tasks if (r := finished(out, t.to_dict()))}
    todo = [t for t in tasks if t.key not in records]
    by_stage = {st: sum(1 for t in tasks if t.stage == st) for st in ("simulate", "fit", "evaluate")}
    log(f"batch: {len(tasks)} tasks ({', '.join(f'{k} {v}' for k, v in by_stage.items() if v)}), "
        f"{len(records)} finished earlier, {len(todo)} to run -> {out}")
    summary = {"plan": str(plan_path), "out": str(out), "code_version": version, "workers": 0,
               "counts": {"cached": len(records)}, "wall_s": 0.0, "scenes_per_hour": None}
    if s.dry_run:
        for t in tasks:
            log(f"  {'done' if t.key in records else 'todo'}  {t.stage:8s} {t.label}  {t.key[:12]}")
        return summary
    ran = {}
    if todo:
        with dask_client(s) as client:
            if not s.address:
                client.wait_for_workers(s.workers or local_cores(), timeout=120)
            summary["workers"] = len(client.nthreads())
            futures = {}
            opts = _options(s)
            for t in todo:     # dependency order: a task's inputs are futures or finished records
                deps = [futures[k] if k in futures else records[k] for k in t.deps]
                futures[t.key] = client.submit(run_task, t.to_dict(), str(out), opts, *deps,
                                               key=f"{t.stage}-{t.key}", pure=False)
            by_future = {f.key: t for t, f in zip(todo, futures.values())}
            bar = _progress(len(todo), s.progress)
            for fut in as_completed(list(futures.values())):
                t = by_future[fut.key]
                try:
                    rec = fut.result()
                except Exception as exc:       # the engine gave up (worker lost too often) or an input erred
                    rec = {"key": t.key, "stage": t.stage, "label": t.label, "status": "failed",
                           "error": f"{type(exc).__name__}: {exc}"[:300]}
                ran[t.key] = rec
                bar.update(1)
                if rec.get("status") == "failed":
                    bar.write(f"failed: {t.stage} {t.label}: {rec.get('error', '')}")
            bar.close()
    records.update(ran)
    wall = time.time() - t0
    counts = {"cached": summary["counts"]["cached"]}
    for rec in ran.values():
        st = "run" if rec.get("status") == "done" else rec.get("status", "failed")
        counts[st] = counts.get(st, 0) + 1
    scenes = sum(1 for t in tasks if t.stage == "simulate" and ran.get(t.key, {}).get("status") == "done")
    summary.update(counts=counts, wall_s=round(wall, 2),
                   scenes_per_hour=round(3600.0 * scenes / wall, 1) if scenes else None)
    paths = write_results(out, tasks, records, summary)
    log(f"batch: {', '.join(f'{k} {v}' for k, v in counts.items())} in {wall:.1f} s; "
        f"results -> {paths['csv']}, {paths['html']}")
    return summary


def _progress(total: int, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc="batch", unit="task", disable=not enabled, file=sys.stderr)


def settings_dict(s: BatchSettings) -> dict:
    return asdict(s)
