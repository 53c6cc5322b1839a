"""The Makefile's torch choice (`make -n`: nothing is installed)."""
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make not installed")


def _dry(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-n", "--no-print-directory", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)


def test_default_is_cpu_with_local_wheel_first(tmp_path):
    out = _dry("torch", f"VENV={tmp_path}/venv").stdout
    assert '[ "cpu" = cpu ]' in out
    assert "--no-index" in out and "--dry-run" in out          # local wheel probed first
    assert "--index-url https://download.pytorch.org/whl/cpu" in out   # CPU index as fallback
    assert "-q " not in out and "--progress-bar on" in out


def test_cuda_uses_the_cuda_index(tmp_path):
    out = _dry("torch", "TORCH=cuda", "CUDA=cu126", f"VENV={tmp_path}/venv").stdout
    assert '[ "cuda" = cpu ]' in out                            # local CPU wheel never taken
    assert "--index-url https://download.pytorch.org/whl/cu126" in out


def test_unknown_build_is_refused(tmp_path):
    res = _dry("venv", "TORCH=rocm", f"VENV={tmp_path}/venv")
    assert res.returncode != 0 and "TORCH must be cpu or cuda" in res.stderr


def test_stamp_carries_the_build(tmp_path):
    out = _dry("venv", "TORCH=cuda", f"VENV={tmp_path}/venv").stdout
    assert f"touch {tmp_path}/venv/.installed-cuda-" in out
