"""The fault table: bad inputs and faults at every entry point, what each must answer, what it must leave.

A case runs one command the way a person would and asserts
- the exit code: 2 for bad input (or a size that cannot fit), 130 for an interrupted run, 0 where the
  command can and must do its job;
- the message: exactly one line (no traceback) containing every keyword of `says` (the file,
  field or setting, case-insensitive);
- the files left behind: by default nothing in the case's workspace changed (no file lost, none
  modified, none added, no staging leftovers); `after(ws)` replaces that check where the command
  is expected to write.

`run(ws)` returns the command: ('recon', argv) in-process `python -m torch_recon`, ('sim', argv) a
`pipeline/simulate.py` process, ('call', fn) any callable returning (rc, stderr) (signals, add-on
operators). `prepare(ws, monkeypatch)` breaks an input or injects a fault first. slow: needs renders
or a real training run (pytest -m slow).
"""

from __future__ import annotations

import errno
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tests.support.fault_workspace import FIT_FAST, ROOT, SIGINT, SIGTERM, run_signalled


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


# ------------------------------------------------------------------------------------------ checks of what is left

def only_new(*names, allow_modified=()):
    """Nothing lost, nothing modified (except allow_modified), every new file under one of `names`."""
    def check(ws):
        ch = ws.changed()
        assert not ch["lost"], ch
        assert set(ch["modified"]) <= set(allow_modified), ch
        bad = [n for n in ch["new"] if not any(n == p or n.startswith(p + "/") for p in names)]
        assert not bad, f"unexpected new files {bad}"
        assert not ws.leftovers(), ws.leftovers()
    return check


def fit_unchanged_but_checkpoint(ws):
    ch = ws.changed()
    assert not ch["lost"] and set(ch["modified"]) <= {"fit/checkpoint.pt"}, ch
    assert all(n.startswith(("fit/", "tmp/")) for n in ch["new"]) and not ws.leftovers(), ch


def old_or_new_fit(ws):
    """After a kill: the old fit complete and untouched, or a new complete one (fit.json names its mesh)."""
    from torch_recon.contract.dataset.staging import StagedDir
    ch = ws.changed()
    fit = ws.root / "fit"
    # the killed run's hidden staging folder is removed by the next run that writes there
    StagedDir(fit, "fit", marker="fit.json", keep=("checkpoint.pt",)).discard()
    assert not ws.leftovers(), ws.leftovers()
    if not (set(ch["modified"]) - {"fit/checkpoint.pt"}) and not ch["lost"]:
        return
    rep = json.loads((fit / "fit.json").read_text())
    side = json.loads((fit / "mesh.mesh.json").read_text())
    assert rep["run_seconds"] >= side["metadata"]["run_seconds"] - 1e-6, "mesh and fit.json from different runs"


def user_files_kept(*rels):
    def check(ws):
        for rel in rels:
            assert (ws.root / rel).exists(), f"{rel} was deleted"
        assert ws.before[rels[0]] == __import__("fault_workspace").tree_state(ws.root)[rels[0]]
        assert not ws.leftovers(), ws.leftovers()
    return check


# ------------------------------------------------------------------------------------------ composite runs

def fit_other_dataset(ws):
    """A checkpoint of dataset A in --out, then fit dataset B with the same settings into it."""
    ws.fit
    ws.ds_b
    ws.snapshot()
    return ("recon", ["fit", ws.ds_b, "--out", ws.fit, *FIT_FAST])


def evaluate_twice(ws):
    """An earlier evaluation with error images and a user's note in --out; again without images."""
    from torch_recon.cli import main
    out = ws.root / "eval"
    assert main(["evaluate", str(ws.mesh), "--dataset", str(ws.ds), "--out", str(out), "--samples", "500"]) == 0
    assert (out / "views").is_dir()
    (out / "notes.txt").write_text("mine")
    ws.snapshot()
    return ("recon", ["evaluate", ws.mesh, "--dataset", ws.ds, "--out", out, "--samples", "500",
                      "--error-images", "0", "--seed", "1"])


def after_evaluate_twice(ws):
    out = ws.root / "eval"
    assert (out / "notes.txt").read_text() == "mine"
    assert not (out / "views").exists(), "old view images left beside the new report"
    assert json.loads((out / "report.json").read_text())["settings"]["seed"] == 1
    assert not ws.leftovers()


def killed_during_mesh_export(ws):
    """fit into a folder holding an earlier fit, killed (os._exit, no clean-up) after the first mesh file."""
    import subprocess
    import sys
    ws.fit
    ws.snapshot()
    code = ("import sys, os, torch_recon.mesh_export as me\n"
            "real = me.trimesh_export if hasattr(me, 'trimesh_export') else None\n"
            "import trimesh\n"
            "orig = trimesh.Trimesh.export\n"
            "def export(self, *a, **k):\n"
            "    r = orig(self, *a, **k)\n"
            "    os._exit(137)\n"
            "trimesh.Trimesh.export = export\n"
            "from torch_recon.cli import main\n"
            f"sys.exit(main(sys.argv[1:]))\n")
    proc = subprocess.run([sys.executable, "-c", code, "fit", str(ws.npz), "--out", str(ws.fit), *FIT_FAST,
                           "--no-resume", "--seed", "3"], capture_output=True, text=True, timeout=300)
    return ("done", proc.returncode, "error: killed\n")


def simulate_into_dataset_with_user_files(ws):
    ws.ds
    ws.write("ds/notes.txt", "my notes")
    ws.write("ds/fit/fit.json", "{}")
    ws.snapshot()
    return ("sim", [*SIM_SMALL, "--out", ws.ds])


def after_sim_user_files(ws):
    assert (ws.root / "ds/notes.txt").read_text() == "my notes"
    assert (ws.root / "ds/fit/fit.json").read_text() == "{}"
    man = json.loads((ws.root / "ds/dataset.json").read_text())
    assert man["sensor"]["width"] == 8
    assert not ws.leftovers()


SIM_SMALL = ["--example", "cave-chair", "--resolution", "8", "--spots", "2", "--test-views", "0"]


def simulate_reuse_truncated(ws):
    """A dataset simulated once, then a transient truncated: the re-run must render it again."""
    from tests.support.fault_workspace import run_simulate
    rc, err = run_simulate([*SIM_SMALL, "--out", ws.root / "sim"])
    assert rc == 0, err
    f = sorted((ws.root / "sim/transients").glob("spot_*.exr"))[0]
    f.write_bytes(f.read_bytes()[:100])
    ws.snapshot()
    rc, err = run_simulate([*SIM_SMALL, "--out", ws.root / "sim"])
    spot_id = int(f.stem.split("_")[1])
    line = next((ln for ln in err.splitlines() if f"(id {spot_id}," in ln), "")
    assert line and "unchanged, reused" not in line, err
    return ("done", rc, err)


def after_reuse_truncated(ws):
    from torch_recon.contract.dataset import load_dataset
    ds = load_dataset(ws.root / "sim")
    for s in ds.manifest.spots:
        ds.read_transient(s.id)
    assert not ws.leftovers()


def signal_simulate(sig, when):
    def run(ws):
        ws.ds
        (ws.root / "tmp").mkdir()
        ws.snapshot()
        rc, err = run_signalled(["simulate", "--example", "cave-chair", "--resolution", "48", "--spots", "6",
                                 "--test-views", "0", "--out", ws.ds], sig, when, tmpdir=ws.root / "tmp")
        return ("done", rc, err)
    return run


def after_signal_simulate(ws):
    ch = ws.changed()
    assert not ch["lost"] and not ch["modified"], ch
    left = [n for n in ch["new"]]
    assert not left, f"left behind: {left[:5]}"
    assert not ws.leftovers()
    assert not any((ws.root / "tmp").iterdir()), list((ws.root / "tmp").iterdir())


def signal_fit(sig):
    def run(ws):
        ws.fit
        ws.npz
        (ws.root / "tmp").mkdir()
        ws.snapshot()
        rc, err = run_signalled(["torch_recon", "fit", ws.npz, "--out", ws.fit, "--steps", "100000", "--threads", "1",
                                 "--set", "fast.resolution=16", "--set", "fast.coarse_resolution=8",
                                 "--no-resume", "--seed", "5"],
                                sig, lambda text: "step/s" in text or "s/step" in text, tmpdir=ws.root / "tmp")
        return ("done", rc, err)
    return run


# ------------------------------------------------------------------------------------------ add-on operators

def addon_op(op, setup, says_path=True):
    """Run an add-on operator on the room scene after `setup(scene, ws)`: (rc, the ERROR report)."""
    def run(ws):
        def call():
            import bpy
            from tests.support.addon_fixtures import build_room, enable_addon
            bpy.ops.wm.read_factory_settings(use_empty=True)
            enable_addon()
            scene = bpy.context.scene
            cam = build_room(scene)
            scene.platolidar.camera = cam
            kw = setup(scene, ws) or {}
            ws.snapshot()
            try:
                res = getattr(bpy.ops.platolidar, op)(**kw)
            except RuntimeError as exc:
                msg = str(exc)
                assert "Traceback" not in msg, msg
                return 2, "error: " + msg.replace("Error: ", "").strip()
            return (0 if res == {"FINISHED"} else 1), ""
        return ("call", call)
    return run


def _set(**props):
    def setup(scene, ws):
        for k, v in props.items():
            setattr(scene.platolidar, k, v(ws) if callable(v) else v)
    return setup


def _file_op(**kw):
    def setup(scene, ws):
        return {k: str(v(ws)) if callable(v) else v for k, v in kw.items()}
    return setup


def _prefs(**values):
    def setup(scene, ws):
        from tests.support.addon_fixtures import set_prefs
        set_prefs(**{k: v(ws) for k, v in values.items()})
    return setup


def both_setup(*setups):
    def setup(scene, ws):
        kw = {}
        for s in setups:
            kw.update(s(scene, ws) or {})
        return kw
    return setup


# ------------------------------------------------------------------------------------------ the table

CASES = [
    # --- preprocess: the dataset and the settings
    Case("pre-missing-dataset", R("preprocess", W("nothing"), "--out", W("m.npz")), says=("nothing",)),
    Case("pre-empty-folder", R("preprocess", W("empty"), "--out", W("m.npz")), says=("dataset.json",),
         prepare=lambda ws, mp: ws.p("empty/").mkdir()),
    Case("pre-manifest-bad-json", R("preprocess", DS, "--out", W("m.npz")), says=("dataset.json", "json"),
         prepare=write_file("ds/dataset.json", '{"sensor": ')),
    Case("pre-manifest-no-sensor", R("preprocess", DS, "--out", W("m.npz")), says=("dataset.json", "sensor"),
         prepare=edit_manifest(set_key("sensor", DELETE))),
    Case("pre-manifest-bins-mismatch", R("preprocess", DS, "--out", W("m.npz")), says=("bins",),
         prepare=edit_manifest(set_key("sensor.bins", 150))),
    Case("pre-manifest-width-string", R("preprocess", DS, "--out", W("m.npz")), says=("sensor.width",),
         prepare=edit_manifest(set_key("sensor.width", "sixteen"))),
    Case("pre-manifest-1e12-pixels", R("preprocess", DS, "--out", W("m.npz")), says=("sensor", "pixels"),
         prepare=edit_manifest(lambda d: d["sensor"].update(width=1_000_000, height=1_000_000))),
    Case("pre-manifest-huge-bins", R("preprocess", DS, "--out", W("m.npz")), says=("sensor.bins",),
         prepare=edit_manifest(set_key("sensor.bins", 10 ** 12))),
    Case("pre-manifest-no-spots", R("preprocess", DS, "--out", W("m.npz")), says=("spots",),
         prepare=edit_manifest(set_key("spots", []))),
    Case("pre-transient-missing", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0001.exr", "missing"),
         prepare=lambda ws, mp: (ws.ds / "transients/spot_0001.exr").unlink()),
    Case("pre-transient-truncated", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr",),
         prepare=break_transient("truncated")),
    Case("pre-transient-garbage", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr",),
         prepare=break_transient("garbage")),
    Case("pre-transient-nan", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr", "nan"),
         prepare=break_transient("nan")),
    Case("pre-transient-wrong-shape", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr", "16x16"),
         prepare=break_transient("shape")),
    Case("pre-gt-depth-missing", R("preprocess", DS, "--out", W("m.npz")), says=("train_depth.exr",),
         prepare=lambda ws, mp: (ws.ds / "ground_truth/train_depth.exr").unlink()),
    Case("pre-out-not-npz", R("preprocess", DS, "--out", W("m.txt")), says=("out", ".npz")),
    Case("pre-out-is-folder", R("preprocess", DS, "--out", W("dir.npz")), says=("dir.npz",),
         prepare=lambda ws, mp: ws.p("dir.npz/x").write_text("x")),
    Case("pre-device-unknown", R("preprocess", DS, "--out", W("m.npz"), "--device", "tpu"), says=("device", "tpu")),
    Case("pre-threads-zero", R("preprocess", DS, "--out", W("m.npz"), "--threads", "0"), says=("threads",)),
    Case("pre-shadow-threshold-range", R("preprocess", DS, "--out", W("m.npz"), "--shadow-threshold", "2"),
         says=("shadow_threshold",)),
    Case("pre-refine-unknown", R("preprocess", DS, "--out", W("m.npz"), "--refine", "cubic"), says=("refine", "cubic")),
    Case("pre-out-read-only", R("preprocess", DS, "--out", W("ro/m.npz")), says=("ro", "read-only"),
         prepare=fail_writes(errno.EROFS, "ro")),
    Case("pre-disk-full", R("preprocess", DS, "--out", W("full/m.npz")), says=("full", "no space left"),
         prepare=both(lambda ws, mp: ws.p("full/").mkdir(), fail_writes(errno.ENOSPC, "full"))),
    Case("pre-existing-npz-replaced-whole", R("preprocess", DS, "--out", NPZ), says=("spot_0000.exr",),
         prepare=break_transient("nan")),

    # --- fit: settings, measurements files, outputs, checkpoints, interrupts
    Case("fit-missing-source", R("fit", W("nothing"), "--out", W("out")), says=("nothing",)),
    Case("fit-steps-negative", R("fit", NPZ, "--out", W("out"), "--steps", "-3"), says=("steps",)),
    Case("fit-max-seconds-negative", R("fit", NPZ, "--out", W("out"), "--max-seconds", "-1"), says=("max_seconds",)),
    Case("fit-threads-zero", R("fit", NPZ, "--out", W("out"), "--threads", "0"), says=("threads",)),
    Case("fit-set-wrong-type", R("fit", NPZ, "--out", W("out"), "--set", "fast.resolution=abc"),
         says=("fast.resolution",)),
    Case("fit-set-float-for-int", R("fit", NPZ, "--out", W("out"), "--set", "fast.steps=2.5"), says=("fast.steps",)),
    Case("fit-set-unknown-key", R("fit", NPZ, "--out", W("out"), "--set", "fast.nosuch=1"), says=("nosuch",)),
    Case("fit-set-no-equals", R("fit", NPZ, "--out", W("out"), "--set", "seed"), says=("key=value",)),
    Case("fit-set-device-unknown", R("fit", NPZ, "--out", W("out"), "--set", "device=tpu"), says=("device", "tpu")),
    Case("fit-set-voxels-huge", R("fit", NPZ, "--out", W("out"), "--set", "fast.resolution=100000"),
         says=("fast.resolution", "need")),
    Case("fit-set-lr-negative", R("fit", NPZ, "--out", W("out"), "--set", "fast.lr=-1"), says=("fast.lr",)),
    Case("fit-config-missing", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("cfg.json",)),
    Case("fit-config-bad-json", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("cfg.json", "json"),
         prepare=write_file("cfg.json", "{seed: 1")),
    Case("fit-config-not-object", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("config",),
         prepare=write_file("cfg.json", "[1, 2]")),
    Case("fit-config-wrong-type", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")),
         says=("threads",), prepare=write_file("cfg.json", '{"threads": "two"}')),
    Case("fit-npz-truncated", R("fit", NPZ, "--out", W("out")), says=("m.npz",), prepare=truncate(NPZ)),
    Case("fit-npz-garbage", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz",),
         prepare=write_file("odd.npz", "not a zip")),
    Case("fit-npz-foreign-arrays", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz",),
         prepare=npz_of(x=np.zeros(3))),
    Case("fit-npz-nan-camera", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz", "camera_to_world"),
         prepare=lambda ws, mp: _npz_edit(ws, camera_to_world=np.full((4, 4), np.nan))),
    Case("fit-npz-huge-claim", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz", "pixels"),
         prepare=lambda ws, mp: _npz_edit(ws, meta_i=np.array([10 ** 6, 10 ** 6]))),
    Case("fit-out-is-file", R("fit", NPZ, "--out", W("out")), says=("out",), prepare=write_file("out", "x")),
    Case("fit-out-foreign-folder", R("fit", NPZ, "--out", W("photos"), *FIT_FAST), says=("photos", "not empty"),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("fit-checkpoint-other-data", fit_other_dataset, says=("checkpoint", "--no-resume")),
    Case("fit-out-read-only", R("fit", NPZ, "--out", W("ro/out"), *FIT_FAST), says=("ro", "read-only"),
         prepare=fail_writes(errno.EROFS, "ro")),
    Case("fit-killed-during-mesh-export", killed_during_mesh_export, rc=137, says=("killed",), after=old_or_new_fit,
         slow=True),
    Case("fit-sigint", signal_fit(SIGINT), rc=130, says=("interrupted",), after=fit_unchanged_but_checkpoint,
         slow=True),
    Case("fit-sigterm", signal_fit(SIGTERM), rc=130, says=("interrupted",), after=fit_unchanged_but_checkpoint,
         slow=True),

    # --- baseline
    Case("base-voxels-huge", R("baseline", DS, "--out", W("out"), "--voxels", "100000"), says=("voxels", "need")),
    Case("base-voxels-zero", R("baseline", DS, "--out", W("out"), "--voxels", "0"), says=("voxels",)),
    Case("base-occupancy-range", R("baseline", DS, "--out", W("out"), "--occupancy-threshold", "1.5"),
         says=("occupancy",)),
    Case("base-measurements-garbage", R("baseline", DS, "--out", W("out"), "--measurements", W("bad.npz")),
         says=("bad.npz",), prepare=write_file("bad.npz", "zzz")),
    Case("base-measurements-other-dataset", R("baseline", lambda ws: ws.ds_b, "--out", W("out"), "--measurements", NPZ),
         says=("m.npz", "dataset")),
    Case("base-grid-search-no-gt", R("baseline", lambda ws: ws.ds_nogt, "--out", W("out"), "--grid-search"),
         says=("test_views",)),
    Case("base-device-unknown", R("baseline", DS, "--out", W("out"), "--device", "gpu0"), says=("device", "gpu0")),
    Case("base-out-foreign-folder", R("baseline", DS, "--out", W("photos"), "--voxels", "16"), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),

    # --- evaluate
    Case("eval-no-ground-truth", R("evaluate", MESH, "--dataset", lambda ws: ws.ds_nogt, "--out", W("ev")),
         says=("ground truth",)),
    Case("eval-mesh-missing", R("evaluate", W("none.ply"), "--dataset", DS, "--out", W("ev")), says=("none.ply",)),
    Case("eval-mesh-garbage", R("evaluate", W("bad.ply"), "--dataset", DS, "--out", W("ev")), says=("bad.ply",),
         prepare=write_file("bad.ply", "ply\nformat nonsense\n")),
    Case("eval-mesh-empty", R("evaluate", W("empty.obj"), "--dataset", DS, "--out", W("ev")), says=("empty.obj",),
         prepare=write_file("empty.obj", "# nothing\n")),
    Case("eval-mesh-unknown-suffix", R("evaluate", W("mesh.xyz"), "--dataset", DS, "--out", W("ev")),
         says=("mesh.xyz",), prepare=write_file("mesh.xyz", "1 2 3\n")),
    Case("eval-gt-mesh-corrupt", R("evaluate", MESH, "--dataset", DS, "--out", W("ev")), says=("mesh.ply",),
         prepare=write_file("ds/ground_truth/mesh.ply", "garbage")),
    Case("eval-test-depth-truncated", R("evaluate", MESH, "--dataset", DS, "--out", W("ev")), says=("test_depth.exr",),
         prepare=truncate(lambda ws: ws.ds / "ground_truth/test_depth.exr", 0.3)),
    Case("eval-samples-zero", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--samples", "0"),
         says=("n_surface_samples",)),
    Case("eval-fscore-negative", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--fscore-threshold", "-1"),
         says=("fscore_threshold_m",)),
    Case("eval-object-settings-unknown-key", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--config",
                                               W("c.json")), says=("c.json", "object_metric_settings.nokey"),
         prepare=write_file("c.json", '{"object_metric_settings": {"nokey": 1}}')),
    Case("eval-object-threshold-negative", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--config",
                                             W("c.json")), says=("object_metric_settings.thresholds_m",),
         prepare=write_file("c.json", '{"object_metric_settings": {"thresholds_m": [-0.01]}}')),
    Case("eval-out-foreign-folder", R("evaluate", MESH, "--dataset", DS, "--out", W("photos")), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("eval-replaces-old-report-whole", evaluate_twice, rc=0, after=after_evaluate_twice),
    Case("eval-disk-full", R("evaluate", MESH, "--dataset", DS, "--out", W("full/ev"), "--samples", "500"),
         says=("no space left",), prepare=both(lambda ws, mp: ws.p("full/").mkdir(), fail_writes(errno.ENOSPC, "full"))),

    # --- convert
    Case("conv-from-missing", R("convert", "from-platonerf", W("nothing"), W("out")), says=("nothing",)),
    Case("conv-from-empty", R("convert", "from-platonerf", W("src"), W("out")), says=("transforms_train.json",),
         prepare=lambda ws, mp: ws.p("src/").mkdir()),
    Case("conv-from-bad-json", R("convert", "from-platonerf", W("src"), W("out")), says=("transforms_train.json",),
         prepare=write_file("src/transforms_train.json", "{")),
    Case("conv-from-bin-negative", R("convert", "from-platonerf", W("src"), W("out"), "--bin-ps", "-5"),
         says=("bin",), prepare=write_file("src/transforms_train.json", "{}")),
    Case("conv-to-missing-dataset", R("convert", "to-platonerf", W("nothing"), W("out")), says=("nothing",)),
    Case("conv-to-foreign-folder", R("convert", "to-platonerf", DS, W("photos")), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("conv-to-broken-dataset", R("convert", "to-platonerf", DS, W("out")), says=("spot_0000.exr",),
         prepare=break_transient("truncated")),

    # --- command line
    Case("cli-unknown-command", R("reconstruct", DS), says=("reconstruct",)),
    Case("cli-unknown-option", R("fit", NPZ, "--out", W("out"), "--fast"), says=("--fast",)),

    # --- simulate (pipeline/simulate.py, a process each)
    Case("sim-zero-bins", S("--example", "cave-chair", "--bins", "0", "--out", W("sim")), says=("bins",)),
    Case("sim-resolution-huge", S("--example", "cave-chair", "--resolution", "100000", "--out", W("sim")),
         says=("width", "would need")),
    Case("sim-bins-huge", S("--example", "cave-chair", "--bins", "100000000", "--out", W("sim")), says=("bins", "need")),
    Case("sim-unknown-example", S("--example", "nosuch", "--out", W("sim")), says=("nosuch",)),
    Case("sim-blend-garbage", S(W("x.blend"), "--out", W("sim")), says=("x.blend",),
         prepare=write_file("x.blend", "not a blend")),
    Case("sim-blend-missing", S(W("y.blend"), "--out", W("sim")), says=("y.blend",)),
    Case("sim-unknown-option", S("--example", "cave-chair", "--warp", "--out", W("sim")), says=("--warp",)),
    Case("sim-config-bad-json", S("--example", "cave-chair", "--config", W("c.json"), "--out", W("sim")),
         says=("c.json",), prepare=write_file("c.json", "{")),
    Case("sim-config-wrong-type", S("--example", "cave-chair", "--config", W("c.json"), "--out", W("sim")),
         says=("bins",), prepare=write_file("c.json", '{"bins": "many"}')),
    Case("sim-spot-list-bad", S("--example", "cave-chair", "--spot-list", "1,2", "--out", W("sim")),
         says=("--spot-list",)),
    Case("sim-test-views-bad", S("--example", "cave-chair", "--test-views", "x", "--out", W("sim")),
         says=("--test-views",)),
    Case("sim-photons-negative", S("--example", "cave-chair", "--photons", "-1", "--out", W("sim")), says=("photons",)),
    Case("sim-out-foreign-folder", S(*SIM_SMALL, "--out", W("photos")), says=("photos", "not empty"),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("sim-out-is-file", S(*SIM_SMALL, "--out", W("file")), says=("file",), prepare=write_file("file", "x")),
    Case("sim-spots-outside-view", S("--example", "cave-chair", "--width", "20", "--height", "10", "--spots", "4",
                                     "--test-views", "0", "--out", W("sim")), says=("spot", "view")),
    Case("sim-keeps-user-files", simulate_into_dataset_with_user_files, rc=0, after=after_sim_user_files),
    Case("sim-rerun-validates-reused", simulate_reuse_truncated, rc=0, after=after_reuse_truncated, slow=True),
    Case("sim-sigint-during-render", signal_simulate(SIGINT, lambda t: "spot 1/" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),
    Case("sim-sigterm-during-render", signal_simulate(SIGTERM, lambda t: "spot 1/" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),
    Case("sim-sigint-at-start", signal_simulate(SIGINT, lambda t: "geometry" in t or "spot" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),

    # --- add-on operators (one line in the ERROR report, CANCELLED, nothing touched)
    Case("addon-import-mesh-missing", addon_op("import_reconstruction", _set(import_path=lambda ws: str(ws.root / "no.ply"))),
         says=("no.ply",)),
    Case("addon-import-mesh-garbage", addon_op("import_reconstruction",
                                               _set(import_path=lambda ws: str(ws.write("bad.ply", "zz")))),
         says=("bad.ply",)),
    Case("addon-import-depth-garbage", addon_op("import_visible_depth",
                                                _set(measurements_path=lambda ws: str(ws.write("bad.npz", "zz")))),
         says=("bad.npz",)),
    Case("addon-import-depth-foreign-npz", addon_op("import_visible_depth", _set(
        measurements_path=lambda ws: (np.savez(ws.p("odd.npz"), x=np.zeros(2)), str(ws.root / "odd.npz"))[1])),
        says=("odd.npz",)),
    Case("addon-load-config-bad-json", addon_op("load_config", _file_op(filepath=lambda ws: ws.write("c.json", "{"))),
         says=("c.json",)),
    Case("addon-load-config-wrong-type", addon_op("load_config", _file_op(
        filepath=lambda ws: ws.write("c.json", '{"bins": "many"}'))), says=("bins",)),
    Case("addon-export-config-no-folder", addon_op("export_config", both_setup(
        _set(spot_source="RANDOM"), _file_op(filepath=W("nodir/c.json")))), says=("nodir",)),
    Case("addon-reconstruct-not-a-dataset", addon_op("reconstruct", both_setup(
        _prefs(python_path=lambda ws: sys.executable, project_dir=lambda ws: str(ROOT)),
        _set(recon_dataset_dir=lambda ws: str(ws.p("e/x").parent)))), says=("dataset.json",)),
]


def _npz_edit(ws, **arrays):
    z = dict(np.load(ws.npz))
    z.update(arrays)
    np.savez(ws.p("odd.npz"), **z)
