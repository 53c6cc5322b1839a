"""The one way to start the simulator as a separate process (no bpy here).

`pipeline/simulate.py` runs either inside a Blender binary (`blender -b scene.blend -P simulate.py -- ...`)
or in a Python that has the bpy module (`python simulate.py [scene.blend] ...`). Tests, benchmarks, the
examples, the add-on's Simulate job and `platolidar simulate --blender BIN` build the command here.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SIMULATE_SCRIPT = Path(__file__).resolve().with_name("simulate.py")


def simulate_command(args=(), blend=None, blender=None, python=None, script=None) -> list[str]:
    """Command line running simulate.py with `args` (e.g. ['--example', 'cave-chair', '--out', DIR]).

    blender: a Blender binary (the .blend is opened by Blender; --python-exit-code makes a Python
    error a non-zero exit, and must come before -P); else `python` (default: this interpreter) with bpy.
    """
    script = str(script or SIMULATE_SCRIPT)
    args = [str(a) for a in args]
    if blender:
        return [str(blender), "-b", *([str(blend)] if blend else []), "--python-exit-code", "1", "-P", script,
                "--", *args]
    return [str(python or sys.executable), script, *([str(blend)] if blend else []), *args]


def run_simulate(args=(), blend=None, blender=None, python=None, **subprocess_kw) -> subprocess.CompletedProcess:
    """Run simulate.py to completion (stdout/stderr captured as text unless told otherwise)."""
    subprocess_kw.setdefault("capture_output", True)
    subprocess_kw.setdefault("text", True)
    return subprocess.run(simulate_command(args, blend, blender, python), **subprocess_kw)
