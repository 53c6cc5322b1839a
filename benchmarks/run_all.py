"""Run every benchmark quickly, in sequence (`make bench`): each benchmarks/bench_*.py, then the stress suite.

    python benchmarks/run_all.py [--full] [--skip NAME ...] [--list]

A script that accepts --quick gets it; the others get the small settings listed in FALLBACK_QUICK
(their own options), or none. --full runs every script with its defaults (long: the paper-scale
runs take tens of minutes on 2 cores). One failing script does not stop the others; the exit status
is 1 if any failed. At the end: each script's status and time, and the result files written.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"

#: quick settings of scripts without a --quick flag (their own options)
FALLBACK_QUICK = {
    "bench_gating.py": ["--resolution", "128", "--sbr-pixels", "64"],
    "bench_measurements.py": ["--skip-512", "--test-res", "64"],
    "bench_simulate.py": ["--resolutions", "128"],
    "bench_chain.py": ["--resolutions", "128"],
}


def scripts() -> list:
    return sorted(HERE.glob("bench_*.py")) + [HERE / "stress.py"]


def quick_args(path: Path) -> list:
    if "--quick" in path.read_text():
        return ["--quick"]
    return list(FALLBACK_QUICK.get(path.name, []))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="default (full) settings instead of the quick ones")
    ap.add_argument("--skip", nargs="*", default=[], help="script names to skip, e.g. bench_recon.py")
    ap.add_argument("--list", action="store_true", help="print the commands and exit")
    a = ap.parse_args(argv)
    plan = [(p, [] if a.full else quick_args(p)) for p in scripts() if p.name not in a.skip]
    if a.list:
        for p, args in plan:
            print(" ".join(["python", f"benchmarks/{p.name}", *args]))
        return 0
    start = time.time()
    status = []
    for p, args in plan:
        cmd = [sys.executable, str(p), *args]
        print(f"\n=== {' '.join(['python', 'benchmarks/' + p.name, *args])}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=HERE.parent).returncode
        status.append((p.name, rc, time.perf_counter() - t0))
    print("\n=== summary")
    for name, rc, s in status:
        print(f"  {name:28s} {'ok' if rc == 0 else f'FAILED (exit {rc})':16s} {s:7.1f} s")
    written = sorted(f for f in RESULTS.glob("*") if f.is_file() and f.stat().st_mtime >= start)
    print(f"results written to {RESULTS}:")
    for f in written:
        print(f"  {f.relative_to(HERE.parent)}")
    return 0 if all(rc == 0 for _, rc, _ in status) else 1


if __name__ == "__main__":
    sys.exit(main())
