"""Small shared helpers for the benchmark scripts (stdlib + numpy only; torch optional).

    from benchmarks.common import machine_info, peak_rss_mb, timer, write_json
    with timer() as t:
        work()
    print(t.seconds, t.cpu_seconds, peak_rss_mb())
    write_json("benchmarks/results/x.json", {"machine": machine_info(), "seconds": t.seconds})

A script run by path (``python benchmarks/bench_x.py``) first puts the repository root on sys.path:

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
"""

from __future__ import annotations

import json
import os
import platform
import resource
import sys
import time
from contextlib import contextmanager
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]
RESULTS_DIR = REPO_ROOT / "benchmarks" / "results"


def machine_info() -> dict:
    """Where a number was measured: platform, CPU model and count, library versions."""
    import numpy as np

    cpu = platform.processor() or ""
    try:  # Linux: the model name is more telling than platform.processor()
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    info = {"platform": platform.platform(), "python": platform.python_version(), "cpu": cpu,
            "cpu_count": os.cpu_count(),
            "cpu_affinity": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "numpy": np.__version__,
            # other work on the machine inflates wall times: the 1-minute load average says how much
            "loadavg_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}
    try:
        import torch
        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads()
    except ImportError:
        info["torch"] = None
    return info


def machine_line(info: dict | None = None) -> str:
    """One printable line of machine_info(): what every benchmark prints before its table."""
    info = info or machine_info()
    return (f"machine: {info['cpu']}, {info['cpu_affinity']} cores usable, torch {info.get('torch')} "
            f"({info.get('torch_threads')} threads), numpy {info['numpy']}, load average {info['loadavg_1min']:.2f}")


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far, in MiB (ru_maxrss is KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (1024.0 * 1024.0) if sys.platform == "darwin" else peak / 1024.0


class _Timer:
    seconds: float = float("nan")       # wall clock
    cpu_seconds: float = float("nan")   # CPU time of this process, all threads (not children)


@contextmanager
def timer():
    """``with timer() as t: ...`` then ``t.seconds`` (wall) and ``t.cpu_seconds`` (process CPU).

    On a shared machine the CPU time is the steadier figure: wall time grows with other load.
    """
    t = _Timer()
    start, cpu = time.perf_counter(), time.process_time()
    try:
        yield t
    finally:
        t.seconds = time.perf_counter() - start
        t.cpu_seconds = time.process_time() - cpu


def write_json(path, obj) -> Path:
    """Write `obj` as indented JSON atomically (temp file + rename); creates parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=2, sort_keys=False, default=_jsonable) + "\n")
    os.replace(tmp, path)
    return path


def _jsonable(o):
    """numpy scalars/arrays and paths in JSON."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot write {type(o).__name__} as JSON")
