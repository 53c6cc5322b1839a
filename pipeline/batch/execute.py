"""One task on a worker: run its stage as a subprocess, then record it (the record is what counts).

A task's folder, `OUT/tasks/<stage>/<label>-<key>/`:
    output/     what the stage wrote (a dataset, a fit, an evaluation), through the stage's own StagedDir:
                a stage killed at any moment leaves the previous complete output or none
    scene.blend procedural scenes only: the Blender scene that was simulated
    log.txt     every attempt's command line, stdout and stderr, appended
    task.json   the record, written last and atomically: status done / failed, key, timings, metrics

A task counts as finished only when task.json says `done` under the same key; anything else (no record,
a failed one, a worker killed mid-task) is run again. The stage runs in its own process, which dies with
the worker process that started it (Linux PR_SET_PDEATHSIG), so a killed worker leaves no stage running.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

RECORD = "task.json"
LOG = "log.txt"
OUTPUT = "output"
PROJECT_ROOT = Path(__file__).resolve().parents[2]


def task_dir(root, task: dict) -> Path:
    return Path(root) / "tasks" / task["stage"] / f"{task['label']}-{task['key'][:12]}"


def write_json_atomic(path: Path, data) -> None:
    """Write beside, flush to disk, rename over: readers see the old file or the new one, never half."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=1, default=str)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_record(folder: Path, key: str) -> dict | None:
    """The task's record if it is complete and belongs to `key` (else None)."""
    try:
        rec = json.loads((Path(folder) / RECORD).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("key") == key else None


def finished(root, task: dict) -> dict | None:
    rec = read_record(task_dir(root, task), task["key"])
    return rec if rec and rec.get("status") == "done" else None


# -- stage command lines ---------------------------------------------------------------------------------
def _text(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if v is None:
        return "none"
    if isinstance(v, (list, tuple, dict)):
        return json.dumps(v)
    return str(v)


def _sets(settings: dict) -> list:
    out = []
    for k, v in settings.items():
        out += ["--set", f"{k}={_text(v)}"]
    return out


def simulate_args(settings: dict) -> list:
    from .plan import SIMULATE_FLAGS

    out = []
    for k, v in settings.items():
        out += [SIMULATE_FLAGS[k], _text(v)] if k in SIMULATE_FLAGS else ["--set", f"{k}={_text(v)}"]
    return out


def stage_commands(task: dict, folder: Path, deps: dict, opts: dict) -> list:
    """The command line(s) of a task's stage (run in order; each must exit 0)."""
    from pipeline.launch import simulate_command

    python = opts.get("python") or sys.executable
    spec, out = task["spec"], folder / OUTPUT
    if task["stage"] == "simulate":
        scene, args = spec["scene"], simulate_args(spec["settings"])
        if scene["kind"] == "example":
            return [simulate_command(["--example", scene["name"], "--out", out, *args], python=python,
                                     blender=opts.get("blender"))]
        if scene["kind"] == "blend":
            return [simulate_command(["--out", out, *args], blend=scene["path"], python=python,
                                     blender=opts.get("blender"))]
        blend = folder / "scene.blend"     # procedural: build the .blend from the seed, then simulate it
        build = [python, "-m", "pipeline.batch.build_scene", "--seed", str(scene["seed"]),
                 "--settings", json.dumps(scene["settings"]), "--blend", str(blend)]
        return [build, simulate_command(["--out", out, *args], blend=blend, python=python,
                                        blender=opts.get("blender"))]
    platolidar = [python, "-m", "torch_recon"]
    if task["stage"] == "fit":
        from torch_recon.contract.methods import method

        m = method(spec["method"])
        dataset = deps[task["deps"][0]]["output"]
        settings = dict(spec["settings"])
        if m.command == "fit":
            settings.setdefault("threads", opts.get("threads", 1))
            return [[*platolidar, "fit", dataset, "--out", str(out), "--mode", m.name, "--quiet", "--no-uv",
                     *_sets(settings)]]
        settings.setdefault("threads", opts.get("threads", 1))
        return [[*platolidar, m.command, dataset, "--out", str(out), *_sets(settings)]]
    fit, sim = (deps[k] for k in task["deps"])
    return [[*platolidar, "evaluate", str(Path(fit["output"]) / "mesh.glb"), "--dataset", sim["output"],
             "--out", str(out), *_sets(spec["settings"])]]


# -- running ---------------------------------------------------------------------------------------------------
def _die_with_parent():
    """In the child: get SIGKILL when the worker thread that started it dies (Linux only)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))     # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _child_env(opts: dict) -> dict:
    env = dict(os.environ)
    n = str(opts.get("threads", 1))
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        env[var] = n       # one worker per core: each stage keeps to its share
    paths = [str(PROJECT_ROOT)] + [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]
    env["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _run(cmd: list, log, env: dict, timeout: float | None) -> int:
    log.write(f"$ {subprocess.list2cmdline([str(c) for c in cmd])}\n")
    log.flush()
    proc = subprocess.Popen([str(c) for c in cmd], stdout=log, stderr=subprocess.STDOUT, env=env,
                            cwd=str(PROJECT_ROOT), preexec_fn=_die_with_parent if os.name == "posix" else None)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        log.write(f"timed out after {timeout} s\n")
        return 124
    except BaseException:
        proc.kill()
        proc.wait()
        raise


ATTEMPT_HEADER = "=== attempt "


def _attempts(log_path: Path) -> int:
    try:
        return sum(1 for ln in log_path.read_text(errors="replace").splitlines() if ln.startswith(ATTEMPT_HEADER))
    except OSError:
        return 0


def _last_line(log_path: Path) -> str:
    try:
        lines = [ln for ln in log_path.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    errs = [ln for ln in lines if "error" in ln.lower()]
    return (errs or lines or [""])[-1][:300]


def run_task(task: dict, root: str, opts: dict, *dep_records: dict) -> dict:
    """Run one task (or return its finished record); never raises for a failed stage."""
    from .results import stage_metrics

    folder = task_dir(root, task)
    rec = read_record(folder, task["key"])
    if rec and rec.get("status") == "done":
        return {**rec, "cached": True}
    base = {"key": task["key"], "stage": task["stage"], "label": task["label"], "deps": task["deps"],
            "output": str(folder / OUTPUT), "folder": str(folder)}
    deps = {r["key"]: r for r in dep_records}
    missing = [k for k in task["deps"] if deps.get(k, {}).get("status") != "done"]
    if missing:       # nothing recorded: the task runs when a later run has its inputs
        return {**base, "status": "skipped", "error": f"input task {missing[0][:12]} not done", "cached": False}
    folder.mkdir(parents=True, exist_ok=True)
    for stale in [*folder.glob(".*.tmp"), *folder.glob(".scene.blend.*")]:   # half files of a killed attempt
        stale.unlink(missing_ok=True)
    attempt = _attempts(folder / LOG) + 1      # the log counts attempts a killed worker could not record
    env = _child_env(opts)
    t0, c0 = time.time(), os.times()
    code = 0
    with open(folder / LOG, "a", encoding="utf-8") as log:
        log.write(f"\n{ATTEMPT_HEADER}{attempt} on {socket.gethostname()} pid {os.getpid()} "
                  f"{time.strftime('%Y-%m-%d %H:%M:%S')} ===\n")
        log.flush()
        for cmd in stage_commands(task, folder, deps, opts):
            code = _run(cmd, log, env, opts.get("task_timeout_s"))
            if code != 0:
                break
    c1 = os.times()
    rec = {**base, "status": "done" if code == 0 else "failed", "exit_code": code, "attempt": attempt,
           "wall_s": round(time.time() - t0, 3),
           "cpu_s": round((c1.children_user - c0.children_user) + (c1.children_system - c0.children_system), 3),
           "host": socket.gethostname(), "finished": time.strftime("%Y-%m-%dT%H:%M:%S")}
    if code == 0:
        try:
            rec["metrics"] = stage_metrics(task["stage"], folder / OUTPUT)
        except (OSError, ValueError, KeyError) as exc:     # an output that is not what the stage promises
            rec.update(status="failed", error=f"output unreadable: {exc}")
    else:
        rec["error"] = _last_line(folder / LOG)
    write_json_atomic(folder / RECORD, rec)
    return {**rec, "cached": False}
