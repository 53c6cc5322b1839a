"""Background jobs (simulation, reconstruction, spot advice, ...) as subprocesses: command lines, progress, cancel.

No bpy here, so tests drive it with fake binaries. Operators poll a Job from a modal
timer (UI) or wait on it (scripts, background mode).
"""

from __future__ import annotations

import collections
import os
import re
import signal
import subprocess
import threading
import time
from pathlib import Path

_PERCENT = re.compile(r"(\d+(?:\.\d+)?)\s*%")
# a tqdm bar: 'fit fast:  42%|####      | 84/200 [00:10<00:14, 8.1step/s]'
_TQDM = re.compile(r"^(?:(?P<stage>[^:|]{1,60}):\s*)?\d+(?:\.\d+)?%\|.*?\[[\d:]+<(?P<eta>[\d:]+|\?)")
_FRACTION = re.compile(r"(?<![\d.])(\d+)\s*/\s*(\d+)(?![\d.])")


def parse_progress(line: str) -> float | None:
    """Fraction done read from a progress line: '42%' (tqdm) or 'spot 3/16'; None if none."""
    m = _PERCENT.search(line)
    if m:
        return min(1.0, max(0.0, float(m.group(1)) / 100.0))
    m = _FRACTION.search(line)
    if m and int(m.group(2)) > 0 and int(m.group(1)) <= int(m.group(2)):
        return int(m.group(1)) / int(m.group(2))
    return None


def parse_stage(line: str) -> tuple[str | None, float | None]:
    """(stage name, seconds left) from a tqdm bar line; (None, None) for other lines."""
    m = _TQDM.search(line.strip())
    if not m:
        return None, None
    eta = None
    if m.group("eta") != "?":
        eta = 0.0
        for part in m.group("eta").split(":"):
            eta = eta * 60 + int(part)
    return (m.group("stage") or "").strip() or None, eta


def format_eta(seconds: float | None) -> str:
    if seconds is None:
        return ""
    m, s = divmod(int(round(seconds)), 60)
    return f"ETA {m // 60}:{m % 60:02d}:{s:02d}" if m >= 60 else f"ETA {m}:{s:02d}"


def simulate_command(blender: str, blend_file: str, script: str, out_dir: str) -> list[str]:
    """Background Blender running the simulator on a saved copy of the scene (pipeline/launch.py)."""
    from pipeline.launch import simulate_command as command

    return command(["--out", out_dir], blend=blend_file, blender=blender, script=script)


def reconstruct_command(python: str, dataset: str, out_dir: str, mode: str, steps: int = 0,
                        max_seconds: float = 0.0, resolution: int = 0, device: str = "auto") -> list[str]:
    """`python -m torch_recon <fit|baseline> DATASET --out OUT --set key=value ...` for a method of the
    registry; 0 leaves the method's own default (steps, time budget, grid resolution)."""
    from torch_recon.contract.methods import method

    m = method(mode)
    sets = {"mode": mode} if m.command == "fit" else {}
    if m.command == "fit" and steps > 0:
        sets["steps"] = int(steps)
    if m.command == "fit" and max_seconds > 0:
        sets["max_seconds"] = float(max_seconds)
    if resolution > 0 and m.grid_setting:
        sets[m.grid_setting] = int(resolution)
    sets["device"] = device
    cmd = [str(python), "-m", "torch_recon", m.command, str(dataset), "--out", str(out_dir)]
    for key, value in sets.items():
        cmd += ["--set", f"{key}={value}"]
    return cmd


def evaluate_command(python: str, mesh: str, dataset: str, out_dir: str) -> list[str]:
    return [str(python), "-m", "torch_recon", "evaluate", str(mesh), "--dataset", str(dataset), "--out", str(out_dir)]


def advise_command(python: str, dataset: str, fit_dir: str, out_json: str, add: int, beyond_view_deg: float = 0.0,
                   device: str = "auto") -> list[str]:
    """`python -m torch_recon advise-spots DATASET FIT_DIR --add N --beyond-view-deg D --out JSON`."""
    return [str(python), "-m", "torch_recon", "advise-spots", str(dataset), str(fit_dir), "--add", str(int(add)),
            "--beyond-view-deg", f"{float(beyond_view_deg):g}", "--device", str(device), "--out", str(out_json)]


def find_base_python() -> str:
    """A Python to make the reconstruction environment with: python3.11 on PATH, else python3."""
    import shutil
    for name in ("python3.11", "python3", "python"):
        found = shutil.which(name)
        if found:
            return found
    return ""


def setup_command(base_python: str, script: str, env_dir: str, torch_build: str, cuda: str, source_kind: str,
                  source: str, pythonpath=()) -> list[str]:
    """`BASE -u recon_setup.py --env DIR --torch cpu|cuda ...` (addon/recon_setup.py)."""
    cmd = [str(base_python), "-u", str(script), "--env", str(env_dir), "--torch", torch_build]
    if torch_build == "cuda":
        cmd += ["--cuda", cuda]
    cmd += ["--project" if source_kind == "project" else "--requirements", str(source)]
    if pythonpath:
        cmd += ["--pythonpath", os.pathsep.join(str(p) for p in pythonpath)]
    return cmd


def python_env(extra_paths=()) -> dict:
    """Environment for an external Python: our folders first on PYTHONPATH, Blender's own Python vars dropped."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "PYTHONPATH")}
    paths = [str(p) for p in extra_paths]
    if paths:
        env["PYTHONPATH"] = os.pathsep.join(paths)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def check_executable(path: str, what: str) -> str | None:
    """None when `path` is a runnable file, else a sentence saying what is wrong."""
    if not path:
        return f"No {what} set (Edit > Preferences > Add-ons > platolidar)"
    p = Path(os.path.expanduser(path))
    if not p.exists():
        return f"{what} '{path}' does not exist"
    if p.is_dir() or not os.access(p, os.X_OK):
        return f"{what} '{path}' is not an executable file"
    return None


_ENV_CHECKS: dict = {}
_CHECK_CODE = ("import sys\n"
               "try:\n import torch\nexcept Exception as e:\n print('NO_TORCH', e); sys.exit(3)\n"
               "try:\n import torch_recon.cli\nexcept Exception as e:\n print('NO_TORCH_RECON', e); sys.exit(4)\n"
               "print('OK torch', torch.__version__, 'cuda' if torch.cuda.is_available() else 'cpu')\n")


def check_reconstruction_python(python: str, extra_paths=(), timeout: float = 120.0) -> tuple[bool, str]:
    """Can `python` run the reconstructor? (ok, message); cached per interpreter, mtime and paths."""
    err = check_executable(python, "Reconstruction Python")
    if err:
        return False, err
    p = Path(os.path.expanduser(python))
    key = (str(p), p.stat().st_mtime, tuple(str(x) for x in extra_paths))
    if key in _ENV_CHECKS:
        return _ENV_CHECKS[key]
    try:
        r = subprocess.run([str(p), "-c", _CHECK_CODE], capture_output=True, text=True, timeout=timeout,
                           env=python_env(extra_paths))
        out = (r.stdout + r.stderr).strip()
    except (OSError, subprocess.TimeoutExpired) as exc:
        return False, f"Reconstruction Python '{python}' could not be run ({exc})"
    if r.returncode == 0 and out.startswith("OK"):
        result = (True, f"{python}: {out.splitlines()[0][3:]}")
    elif r.returncode == 3:
        result = (False, f"'{python}' cannot import torch: install torch==2.13.0 into that environment "
                         f"({out.splitlines()[0][8:] if out else 'no output'})")
    elif r.returncode == 4:
        result = (False, f"'{python}' has torch but cannot import torch_recon: pip install the project there, "
                         f"or set Project Folder in the add-on preferences")
    else:
        result = (False, f"'{python}' failed to start (exit {r.returncode}): {out[-300:]}")
    _ENV_CHECKS[key] = result
    return result


class Job:
    """A subprocess whose merged output is read on a thread; poll() from the UI, wait() in scripts."""

    def __init__(self, kind: str, cmd: list[str], cwd: str | None = None, env: dict | None = None,
                 log_lines: int = 400, progress_lines: str | None = None):
        """progress_lines: regex; only matching lines move the progress (e.g. the simulator's
        'spot k/N', not Cycles' own 'Sample k/N')."""
        self.kind, self.cmd, self.cwd, self.env = kind, [str(c) for c in cmd], cwd, env
        self.progress_re = re.compile(progress_lines) if progress_lines else None
        self.progress_line = ""
        self.lines: collections.deque = collections.deque(maxlen=log_lines)
        self.progress: float | None = None
        self.stage: str | None = None        # the running tqdm bar's name ('preprocess', 'fit fast', ...)
        self.eta_s: float | None = None      # its seconds left
        self.last_line = ""
        self.returncode: int | None = None
        self.cancelled = False
        self.started = 0.0
        self.proc: subprocess.Popen | None = None
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> "Job":
        kw = {}
        if os.name == "posix":
            kw["start_new_session"] = True  # Esc stops the whole process group, not Blender
        self.proc = subprocess.Popen(self.cmd, cwd=self.cwd, env=self.env, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, **kw)
        self.started = time.monotonic()
        self._reader = threading.Thread(target=self._read, name=f"platolidar-{self.kind}", daemon=True)
        self._reader.start()
        return self

    def _read(self):
        buf = b""
        fd = self.proc.stdout.fileno()
        while True:
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            buf += chunk
            # tqdm redraws with '\r': treat it as a line end so progress is seen live
            parts = re.split(rb"[\r\n]", buf)
            buf = parts.pop()
            for part in parts:
                self._add_line(part.decode("utf-8", "replace"))
        if buf:
            self._add_line(buf.decode("utf-8", "replace"))

    def _add_line(self, line: str):
        line = line.rstrip()
        if not line:
            return
        with self._lock:
            self.lines.append(line)
            self.last_line = line
            if self.progress_re is None or self.progress_re.search(line):
                frac = parse_progress(line)
                if frac is not None:
                    self.progress, self.progress_line = frac, line
                    stage, eta = parse_stage(line)
                    if stage is not None or eta is not None:
                        self.stage, self.eta_s = stage or self.stage, eta

    def poll(self) -> bool:
        """True once the process has exited and all its output has been read."""
        if self.proc is None:
            return False
        if self.returncode is None:
            rc = self.proc.poll()
            if rc is None:
                return False
            self._reader.join(timeout=5.0)
            self.returncode = rc
        return True

    def wait(self, timeout: float | None = None) -> int:
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.cancel()
        self.poll()
        return self.returncode

    def cancel(self, grace: float = 5.0):
        """Ask politely (SIGINT: the reconstructor keeps its last checkpoint), then terminate, then kill."""
        self.cancelled = True
        if self.proc is None or self.proc.poll() is not None:
            self.poll()
            return
        steps = ((signal.SIGINT, grace), (signal.SIGTERM, grace), (signal.SIGKILL, grace)) \
            if os.name == "posix" else ((None, grace),)
        for sig, wait_s in steps:
            try:
                if sig is None:
                    self.proc.terminate()
                else:
                    os.killpg(self.proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                pass
            try:
                self.proc.wait(timeout=wait_s)
                break
            except subprocess.TimeoutExpired:
                continue
        self.poll()

    # -- reporting --------------------------------------------------------------------------
    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.started if self.started else 0.0

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.cancelled

    def short_status(self) -> str:
        """'fit fast 42% ETA 0:14' (a tqdm stage), else the percentage and the last progress line."""
        pct = f"{100.0 * self.progress:.0f}%" if self.progress is not None else ""
        if self.stage:
            return " ".join(x for x in (self.stage, pct, format_eta(self.eta_s)) if x)
        return f"{pct}  {(self.progress_line or self.last_line)[:60]}".strip()

    def status_text(self) -> str:
        return f"{self.kind}: {self.short_status()}  ({self.elapsed:.0f} s, Esc to cancel)"

    def failure_summary(self, n: int = 6) -> str:
        """The lines most likely to say why it failed: errors first, else the tail."""
        with self._lock:
            lines = list(self.lines)
        errors = [ln for ln in lines if re.search(r"error|exception|traceback", ln, re.IGNORECASE)]
        pick = (errors or lines)[-n:]
        return " | ".join(pick) if pick else "no output"


# The one running job of each kind, for the panel (progress bar, cancel button)
_ACTIVE: dict[str, Job] = {}


def active(kind: str) -> Job | None:
    job = _ACTIVE.get(kind)
    return job if job is not None and job.returncode is None else None


def set_active(job: Job | None, kind: str):
    if job is None:
        _ACTIVE.pop(kind, None)
    else:
        _ACTIVE[kind] = job


def cancel_all():
    for job in list(_ACTIVE.values()):
        if job.returncode is None:
            job.cancel(grace=2.0)
    _ACTIVE.clear()
