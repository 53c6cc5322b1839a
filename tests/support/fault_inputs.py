"""The fault suite's inputs: the Case record, how a case names its command, and the inputs it breaks on
purpose (tests/support/fault_cases.py holds the table; tests/test_faults.py runs it)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class Case:
    name: str
    run: object                 # ws -> ('recon' | 'sim', argv) or ('call', fn)
    rc: int = 2
    says: tuple = ()
    prepare: object = None      # (ws, monkeypatch) -> None
    after: object = None        # ws -> None (assertions); None: nothing changed
    slow: bool = False


def R(*args):
    return lambda ws: ("recon", [a(ws) if callable(a) else a for a in args])


def S(*args):
    return lambda ws: ("sim", [a(ws) if callable(a) else a for a in args])


def W(rel):
    """A workspace path (not created)."""
    return lambda ws: ws.root / rel


DS = lambda ws: ws.ds              # noqa: E731
NPZ = lambda ws: ws.npz            # noqa: E731
MESH = lambda ws: ws.mesh          # noqa: E731
FIT = lambda ws: ws.fit            # noqa: E731


# ------------------------------------------------------------------------------------------ inputs broken on purpose

def edit_manifest(fn):
    def prep(ws, mp):
        p = ws.ds / "dataset.json"
        d = json.loads(p.read_text())
        fn(d)
        p.write_text(json.dumps(d))
    return prep


def set_key(path, value):
    def fn(d):
        node = d
        keys = path.split(".")
        for k in keys[:-1]:
            node = node[k]
        if value is DELETE:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
    return fn


DELETE = object()


def break_transient(how):
    def prep(ws, mp):
        from torch_recon.contract.dataset import Transient
        from torch_recon.contract.dataset.store import write_transient_file
        f = ws.ds / "transients" / "spot_0000.exr"
        if how == "truncated":
            f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
        elif how == "nan":
            win = np.ones((16, 16, 300), np.float32)
            win[3, 3, 7] = np.nan
            write_transient_file(f, Transient(np.zeros((16, 16), np.int64), win, 300))
        elif how == "shape":
            write_transient_file(f, Transient(np.zeros((8, 16), np.int64), np.ones((8, 16, 300), np.float32), 300))
        elif how == "garbage":
            f.write_text("not an EXR")
    return prep


def write_file(rel, content):
    return lambda ws, mp: ws.write(rel, content)


def npz_of(**arrays):
    def prep(ws, mp):
        np.savez(ws.p("odd.npz"), **arrays)
    return prep


def truncate(getter, frac=0.5):
    def prep(ws, mp):
        p = getter(ws)
        p.write_bytes(p.read_bytes()[: int(p.stat().st_size * frac)])
    return prep


def fail_writes(err, inside):
    """Every file opened for writing under the workspace path `inside` fails with `err` (a read-only
    folder or a full disk, as the tests run as root where chmod cannot forbid writing)."""
    def prep(ws, mp):
        import builtins
        import io

        import numpy
        target = str(ws.root / inside)
        real_open, real_io_open, real_mkdir = builtins.open, io.open, Path.mkdir

        def guard(path, mode="r", *a, **k):
            if any(c in mode for c in "wax+") and str(Path(path).absolute()).startswith(target):
                raise OSError(err, os.strerror(err), str(path))
            return real_open(path, mode, *a, **k)

        def mkdir(self, *a, **k):
            if str(self.absolute()).startswith(target) and not self.exists():
                raise OSError(err, os.strerror(err), str(self))
            return real_mkdir(self, *a, **k)
        mp.setattr(builtins, "open", guard)
        mp.setattr(io, "open", guard)
        mp.setattr(Path, "mkdir", mkdir)
        del numpy
    return prep


def both(*preps):
    def prep(ws, mp):
        for p in preps:
            p(ws, mp)
    return prep


def npz_edit(ws, **arrays):
    z = dict(np.load(ws.npz))
    z.update(arrays)
    np.savez(ws.p("odd.npz"), **z)


def export_ours(rel):
    """The workspace dataset exported to the PlatoNeRF layout at `rel` (carries our platolidar block)."""
    def prep(ws, mp):
        from torch_recon.contract.dataset.platonerf_layout import export_platonerf
        export_platonerf(ws.ds, ws.root / rel)
    return prep


def write_image(rel, pixels):
    def prep(ws, mp):
        from skimage.io import imsave
        imsave(ws.p(rel), pixels, check_contrast=False)
    return prep


def read_rgb(rel):
    """read_rgb_luminance on a workspace file, behind the one error handler every command uses."""
    def run(ws):
        def call():
            import contextlib
            import io

            from torch_recon.contract.errors import run_command
            from torch_recon.rgb_shadow import read_rgb_luminance
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                rc = run_command(lambda: read_rgb_luminance(ws.root / rel) is None, prog="rgb_shadow")
            return rc, err.getvalue()
        return ("call", call)
    return run
