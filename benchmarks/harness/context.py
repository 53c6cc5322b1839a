"""What a suite's run function gets: a cached dataset, a work folder, timing, and the real entry points.

    with ctx.timed() as t:          # in-process work
        ...
    t.wall_s, t.cpu_s, t.peak_rss_mb
    r = ctx.run_cli(["python", "-m", "torch_recon", "fit", ds, "--out", out])   # a subprocess
    r.wall_s, r.cpu_s, r.peak_rss_mb, r.stdout, r.stderr
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from benchmarks.harness import datasets

REPO_ROOT = Path(__file__).resolve().parents[2]
RESULTS_DIR = REPO_ROOT / "benchmarks" / "results"
DATA_DIR = RESULTS_DIR / "data"          # gitignored: cached datasets and work folders


class CliError(RuntimeError):
    """An entry point run by a benchmark exited non-zero (`returncode`, `last_line` of its output) or ran
    past its time limit (returncode None)."""

    def __init__(self, message: str, returncode: int | None = None, last_line: str = ""):
        super().__init__(message)
        self.returncode, self.last_line = returncode, last_line


@dataclass
class Timing:
    """Wall and CPU seconds (this process and its children) and peak resident memory in MiB."""
    wall_s: float = float("nan")
    cpu_s: float = float("nan")
    peak_rss_mb: float = float("nan")

    def times(self) -> dict:
        return {"wall_s": self.wall_s, "cpu_s": self.cpu_s, "peak_rss_mb": self.peak_rss_mb}


@dataclass
class CliRun(Timing):
    args: list = field(default_factory=list)
    returncode: int = 0
    stdout: str = ""
    stderr: str = ""


def _kib_to_mb(kib: float) -> float:
    # ru_maxrss is KiB on Linux, bytes on macOS
    return kib / (1024.0 * 1024.0) if sys.platform == "darwin" else kib / 1024.0


def _reset_peak_rss() -> bool:
    """Linux lets a process reset its own peak RSS (VmHWM) by writing 5 to clear_refs."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _own_peak_rss_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return _kib_to_mb(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)


@contextmanager
def timed():
    """Time the block: wall, CPU of this process plus children that ended in it, and the peak RSS of
    this process in the block (since a reset where the OS allows it, else since start) or of the largest
    child that ended in it, whichever is larger."""
    t = Timing()
    _reset_peak_rss()
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        yield t
    finally:
        ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t.wall_s = time.perf_counter() - w0
        t.cpu_s = (time.process_time() - c0) + (ch1.ru_utime + ch1.ru_stime) - (ch0.ru_utime + ch0.ru_stime)
        child = _kib_to_mb(ch1.ru_maxrss) if ch1.ru_maxrss > ch0.ru_maxrss else 0.0
        t.peak_rss_mb = max(_own_peak_rss_mb(), child)


def command(args) -> list[str]:
    """The argv of an entry point: 'python' means this interpreter; a .py path runs with it; other names
    are console scripts (looked up next to this interpreter first)."""
    args = [str(a) for a in args]
    if not args:
        raise ValueError("run_cli: empty command")
    if args[0] in ("python", "python3"):
        return [sys.executable, *args[1:]]
    if args[0].endswith(".py"):
        return [sys.executable, *args]
    local = Path(sys.executable).parent / args[0]
    return [str(local) if local.exists() else args[0], *args[1:]]


def run_cli(args, timeout: float | None = None, check: bool = True, cwd=REPO_ROOT) -> CliRun:
    """Run one entry point as a subprocess (its own process group): wall time, and from wait4 that
    process's own CPU time and peak RSS. Output is captured in files (no pipe can fill up)."""
    argv = command(args)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO_ROOT), os.environ.get("PYTHONPATH")]))}
    run = CliRun(args=argv)
    with open(os.devnull, "rb") as stdin, _temp_text() as out, _temp_text() as err:
        t0 = time.perf_counter()
        p = subprocess.Popen(argv, cwd=cwd, stdin=stdin, stdout=out, stderr=err, env=env, start_new_session=True)
        try:
            status, usage = _wait(p.pid, timeout)
        except (TimeoutError, KeyboardInterrupt) as exc:
            os.killpg(p.pid, signal.SIGKILL)        # the whole process group: no orphaned workers
            os.wait4(p.pid, 0)
            p.returncode = -signal.SIGKILL
            if isinstance(exc, TimeoutError):
                raise CliError(f"{' '.join(argv)}: ran past its {timeout:g} s limit (killed)") from None
            raise
        finally:
            run.wall_s = time.perf_counter() - t0
        out.seek(0), err.seek(0)
        run.stdout, run.stderr = out.read(), err.read()
    p.returncode = run.returncode = os.waitstatus_to_exitcode(status)
    run.cpu_s = usage.ru_utime + usage.ru_stime
    run.peak_rss_mb = _kib_to_mb(usage.ru_maxrss)
    if check and run.returncode != 0:
        tail = (run.stderr.strip() or run.stdout.strip())[-2000:]
        raise CliError(f"{' '.join(argv)} exited {run.returncode}:\n{tail}", run.returncode,
                       tail.splitlines()[-1] if tail else "")
    return run


def _wait(pid, timeout):
    deadline = None if timeout is None else time.monotonic() + timeout
    delay = 0.01
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            return status, usage
        if deadline is not None and time.monotonic() > deadline:
            raise TimeoutError
        time.sleep(delay)
        delay = min(delay * 2, 0.2)


def _temp_text():
    return tempfile.TemporaryFile("w+", encoding="utf-8", errors="replace")


class Context:
    """What a suite's run function gets (see the module docstring)."""

    def __init__(self, suite: str, quick: bool, data_dir: Path = DATA_DIR, log=None):
        self.suite, self.quick = suite, quick
        self.data_dir = Path(data_dir)
        self.work_dir = self.data_dir / "work" / suite
        if self.work_dir.exists():
            shutil.rmtree(self.work_dir)
        self.work_dir.mkdir(parents=True)
        self._log = log or (lambda msg: print(msg, flush=True))

    def log(self, msg: str) -> None:
        self._log(msg)

    def keep(self, row: dict) -> dict:
        """Append the row to work_dir/rows.jsonl (partial results survive an interrupted run); returns it."""
        import json
        with open(self.work_dir / "rows.jsonl", "a") as f:
            f.write(json.dumps(row) + "\n")
        return row

    @staticmethod
    def load_1min() -> float:
        """The 1-minute load average now: a wall-clock budget trains fewer steps on a busy machine."""
        return round(os.getloadavg()[0], 2)

    timed = staticmethod(timed)

    def run_cli(self, args, timeout: float | None = None, check: bool = True) -> CliRun:
        self.log("  $ " + " ".join(map(str, args)))
        return run_cli(args, timeout=timeout, check=check)

    def dataset(self, example: str, resolution: int, spots: int | None = 16, **simulate_options) -> Path:
        """A simulated dataset of the example scene, cached under data_dir by a hash of the settings;
        a cached one is validated before reuse (datasets.cached_dataset)."""
        return datasets.cached_dataset(self, example, resolution, spots, simulate_options)
