"""Make a reconstruction environment: a venv with torch (CPU or CUDA build, chosen) and the reconstructor.

Run by the add-on's *Set Up Reconstruction Environment* (preferences) as a background job, in the
Python the person chose (standard library only here: it runs before any environment exists):

    PYTHON recon_setup.py --env DIR --torch cpu|cuda [--cuda cu128] (--project CHECKOUT | --requirements FILE)

1. `PYTHON -m venv DIR`;
2. torch==2.13.0 from the chosen build: `cuda` always from https://download.pytorch.org/whl/<cuda>;
   `cpu` as the Makefile does it: a wheel pip resolves without an index (a local cache or find-links)
   when there is one, else https://download.pytorch.org/whl/cpu (PyPI's default torch is the CUDA build
   with several GB of NVIDIA packages);
3. the reconstructor: `pip install -e CHECKOUT` (a project checkout), or the project's dependencies
   from FILE (the extension ships the reconstructor's source and puts it on PYTHONPATH);
4. a check that `import torch, torch_recon.cli` works.
Each step prints 'step k/4: ...' (the add-on's progress) and pip shows its own progress bars.
Exit 0 and a last line 'OK <python>' on success; on failure 'error: ...' and a non-zero exit.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

TORCH_VERSION = "2.13.0"
TORCH_INDEX = "https://download.pytorch.org/whl/{build}"
STEPS = 4


def env_python(env: Path) -> Path:
    return env / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def _step(k: int, text: str):
    print(f"step {k}/{STEPS}: {text}", flush=True)


def _run(cmd: list, env: dict | None = None):
    print("$ " + " ".join(str(c) for c in cmd), flush=True)
    r = subprocess.run([str(c) for c in cmd], env=env)
    if r.returncode != 0:
        raise SystemExit(f"error: {' '.join(str(c) for c in cmd[:6])} ... failed with exit code {r.returncode}")


def torch_install_args(python: Path, build: str) -> list:
    pip = [python, "-m", "pip", "install", "--disable-pip-version-check", "--progress-bar", "on"]
    pin = f"torch=={TORCH_VERSION}"
    if build == "cpu":
        probe = subprocess.run([str(python), "-m", "pip", "install", "--disable-pip-version-check", "--dry-run",
                                "--no-deps", "--no-index", "--ignore-installed", pin], capture_output=True)
        if probe.returncode == 0:
            return pip + [pin]
        return pip + ["--index-url", TORCH_INDEX.format(build="cpu"), pin]
    return pip + ["--index-url", TORCH_INDEX.format(build=build), pin]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", required=True, help="folder of the new environment")
    ap.add_argument("--torch", choices=("cpu", "cuda"), required=True, help="torch build")
    ap.add_argument("--cuda", default="cu128", help="CUDA wheel index name for --torch cuda (default cu128)")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--project", help="a project checkout: pip install -e it")
    src.add_argument("--requirements", help="requirements file of the reconstructor's dependencies")
    ap.add_argument("--pythonpath", default="", help="PYTHONPATH for the final import check")
    a = ap.parse_args(argv)
    env = Path(a.env).expanduser().resolve()
    if sys.version_info[:2] < (3, 10):
        raise SystemExit(f"error: {sys.executable} is Python {sys.version.split()[0]}; the reconstructor "
                         "needs 3.10 or newer (3.11 recommended)")
    _step(1, f"creating the environment {env} with {sys.executable} (Python {sys.version.split()[0]})")
    _run([sys.executable, "-m", "venv", env])
    py = env_python(env)
    build = "cpu" if a.torch == "cpu" else a.cuda
    _step(2, f"installing torch {TORCH_VERSION} ({build} build)")
    _run(torch_install_args(py, build))
    pip = [py, "-m", "pip", "install", "--disable-pip-version-check", "--progress-bar", "on"]
    if a.project:
        _step(3, f"installing the reconstructor from {a.project}")
        _run(pip + ["-e", a.project])
    else:
        _step(3, f"installing the reconstructor's dependencies ({a.requirements})")
        _run(pip + ["-r", a.requirements])
    _step(4, "checking that torch and torch_recon import")
    check_env = dict(os.environ, PYTHONPATH=a.pythonpath) if a.pythonpath else None
    _run([py, "-c", "import torch, torch_recon.cli; print('torch', torch.__version__, "
                    "'cuda' if torch.cuda.is_available() else 'cpu')"], env=check_env)
    print(f"OK {py}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
