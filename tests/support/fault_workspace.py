"""The fault suite's machinery (tests/test_faults.py runs the table in tests/support/fault_cases.py).

- `FaultData`: tiny inputs built once per session: an analytic dataset (16 x 16 pixels, 4 spots,
  2 test views), one without ground truth, its measurements .npz and a short fit (mesh, volume,
  fit.json, checkpoint).
- `Workspace`: one case's own folder with fresh copies of those inputs (copied on first use), and
  a record of every file in it before the case ran, so the case can check what it left behind.
- `run_case`: runs one entry point the way a user would (in-process `python -m torch_recon` main,
  a `pipeline/simulate.py` subprocess, or an add-on operator) and returns (exit code, stderr).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PY = sys.executable
#: a small, fast fit (the settings every fit case starts from)
FIT_FAST = ["--steps", "4", "--no-uv", "--quiet", "--threads", "1", "--set", "fast.resolution=16",
            "--set", "fast.coarse_resolution=8", "--set", "fast.rays_per_batch=256"]


class FaultData:
    """Inputs shared by every case (never modified: cases work on copies)."""

    def __init__(self, root: Path):
        from torch_recon.contract import synthetic as sy
        from torch_recon.cli import main
        from torch_recon.contract.frames import paper_test_view_cameras

        self.root = Path(root)
        mesh = sy.box_room_scene()
        dirs = sy.paper_laser_directions()[:4]
        cams = paper_test_view_cameras(dolly_count=1, orbit_count=1)
        self.dataset, _ = sy.write_analytic_dataset(self.root / "ds", mesh, sy.default_sensor(16, 16, bins=300),
                                                    dirs, test_cameras=cams, test_size=(16, 16))
        self.dataset_b, _ = sy.write_analytic_dataset(self.root / "ds_b", sy.plane_scene(),
                                                      sy.default_sensor(16, 16, bins=300), dirs,
                                                      test_cameras=cams, test_size=(16, 16))
        self.dataset_nogt = self.root / "ds_nogt"
        shutil.copytree(self.dataset, self.dataset_nogt)
        man = (self.dataset_nogt / "dataset.json")
        import json
        d = json.loads(man.read_text())
        d["ground_truth"] = {}
        man.write_text(json.dumps(d))
        shutil.rmtree(self.dataset_nogt / "ground_truth")
        self.measurements = self.root / "m.npz"
        assert main(["preprocess", str(self.dataset), "--out", str(self.measurements)]) == 0
        self.fit = self.root / "fit"
        assert main(["fit", str(self.measurements), "--out", str(self.fit), *FIT_FAST]) == 0
        assert (self.fit / "mesh.ply").is_file()


def tree_state(root: Path) -> dict:
    """relative path -> sha256 of every file under root (hidden ones included)."""
    out = {}
    for p in sorted(Path(root).rglob("*")):
        if p.is_file() and not p.is_symlink():
            out[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


class Workspace:
    """One case's folder. `ws.ds`, `ws.npz`, `ws.fit`, ... are fresh copies made on first use."""

    def __init__(self, root: Path, data: FaultData):
        self.root, self.data = Path(root), data
        self.root.mkdir(parents=True, exist_ok=True)
        self.before: dict = {}

    def _copy(self, src: Path, name: str) -> Path:
        dst = self.root / name
        if not dst.exists():
            (shutil.copytree if src.is_dir() else shutil.copy2)(src, dst)
        return dst

    # fresh copies of the shared inputs (FaultData), made in this folder on first use
    ds = property(lambda self: self._copy(self.data.dataset, "ds"))
    ds_b = property(lambda self: self._copy(self.data.dataset_b, "ds_b"))
    ds_nogt = property(lambda self: self._copy(self.data.dataset_nogt, "ds_nogt"))
    npz = property(lambda self: self._copy(self.data.measurements, "m.npz"))
    fit = property(lambda self: self._copy(self.data.fit, "fit"))

    @property
    def mesh(self) -> Path:
        return self.fit / "mesh.ply"

    def p(self, rel: str) -> Path:
        """A path in the workspace (parent folders created)."""
        q = self.root / rel
        q.parent.mkdir(parents=True, exist_ok=True)
        return q

    def write(self, rel: str, content) -> Path:
        q = self.p(rel)
        (q.write_bytes if isinstance(content, bytes) else q.write_text)(content)
        return q

    def snapshot(self):
        self.before = tree_state(self.root)

    def changed(self) -> dict:
        """{'lost': [...], 'modified': [...], 'new': [...]} relative to the snapshot."""
        now = tree_state(self.root)
        return {"lost": sorted(set(self.before) - set(now)),
                "modified": sorted(k for k in self.before if k in now and now[k] != self.before[k]),
                "new": sorted(set(now) - set(self.before))}

    def leftovers(self) -> list:
        """Staging or temporary files a run left behind."""
        return sorted(str(p.relative_to(self.root)) for p in self.root.rglob("*")
                      if ".partial-" in p.name or ".old-" in p.name or p.name.endswith((".tmp", ".tmp.npz")))


# ------------------------------------------------------------------------------------------ runners

def message_lines(stderr: str) -> list:
    """What a person reads on stderr: progress bars and simulator log lines left out."""
    out = []
    for ln in stderr.replace("\r", "\n").splitlines():
        s = ln.strip()
        if not s or "%|" in s or s.startswith(("simulate: spot", "simulate: note", "simulate: timings",
                                                 "Fra:", "Blender", "Read blend", "Warning")):
            continue
        out.append(s)
    return out


def run_recon(argv, capsys) -> tuple:
    """`python -m torch_recon ARGV` in-process: (exit code, stderr)."""
    from torch_recon.cli import main
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as exc:       # argparse's usage errors
        rc = exc.code if isinstance(exc.code, int) else 2
    cap = capsys.readouterr()
    return rc, cap.err


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def run_simulate(argv, timeout=300) -> tuple:
    """`python pipeline/simulate.py ARGV` in a subprocess: (exit code, stderr)."""
    proc = subprocess.run([PY, str(ROOT / "pipeline" / "simulate.py"), *map(str, argv)], capture_output=True,
                          text=True, cwd=ROOT, env=_env(), timeout=timeout)
    return proc.returncode, proc.stderr


def run_module(argv, timeout=300) -> tuple:
    """`python -m torch_recon ARGV` in a subprocess (when a real process is needed)."""
    proc = subprocess.run([PY, "-m", "torch_recon", *map(str, argv)], capture_output=True, text=True, cwd=ROOT,
                          env=_env(), timeout=timeout)
    return proc.returncode, proc.stderr


def run_signalled(cmd, sig, when, timeout=300, tmpdir=None) -> tuple:
    """Start `cmd` (a list; 'simulate' or 'torch_recon' first), send `sig` once `when(stderr_so_far)` is
    true (or a number of seconds passed), wait: (exit code, stderr)."""
    head = ([PY, str(ROOT / "pipeline" / "simulate.py")] if cmd[0] == "simulate" else [PY, "-m", "torch_recon"])
    env = _env()
    if tmpdir is not None:
        env["TMPDIR"] = str(tmpdir)
    log = Path(tmpdir or "/tmp") / f"signalled-{os.getpid()}-{time.monotonic_ns()}.log"
    with open(log, "w") as f:
        proc = subprocess.Popen(head + [str(a) for a in cmd[1:]], stdout=subprocess.DEVNULL, stderr=f, cwd=ROOT,
                                env=env)
        t0 = time.monotonic()
        sent = False
        while proc.poll() is None and time.monotonic() - t0 < timeout:
            text = log.read_text()
            due = when(text) if callable(when) else time.monotonic() - t0 >= when
            if due and not sent:
                proc.send_signal(sig)
                sent = True
            time.sleep(0.05)
        if proc.poll() is None:
            proc.kill()
        proc.wait()
    err = log.read_text()
    log.unlink()
    assert sent, f"the signal was never sent; the run ended first:\n{err[-2000:]}"
    return proc.returncode, err


SIGINT, SIGTERM, SIGKILL = signal.SIGINT, signal.SIGTERM, signal.SIGKILL


_BATCH = r"""
import contextlib, io, json, sys
sys.argv = ["simulate.py"]
from pipeline.simulate import main
out = []
for argv in json.loads(sys.stdin.read()):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except SystemExit as exc:          # argparse's usage errors
            rc = exc.code if isinstance(exc.code, int) else 2
    out.append([rc, err.getvalue()])
print("\n@@RESULTS@@" + json.dumps(out))
"""


def run_simulate_batch(argvs, timeout=600) -> list:
    """Many `pipeline/simulate.py ARGV` runs in ONE process (bpy is imported once): [(exit code, stderr)]."""
    import json
    proc = subprocess.run([PY, "-c", _BATCH], input=json.dumps([[str(a) for a in v] for v in argvs]),
                          capture_output=True, text=True, cwd=ROOT, env=_env(), timeout=timeout)
    if "@@RESULTS@@" not in proc.stdout:
        raise AssertionError(f"simulate batch died (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    return [tuple(r) for r in json.loads(proc.stdout.rsplit("@@RESULTS@@", 1)[1])]
