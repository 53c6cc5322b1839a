"""The fault suite's composite runs (state built first, then the command), the checks of what a run
leaves behind, and the add-on operator runs (tests/support/fault_cases.py holds the table)."""

from __future__ import annotations

import json

from tests.support.fault_workspace import FIT_FAST, run_signalled


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


def set_props(**props):
    def setup(scene, ws):
        for k, v in props.items():
            setattr(scene.platolidar, k, v(ws) if callable(v) else v)
    return setup


def file_op(**kw):
    def setup(scene, ws):
        return {k: str(v(ws)) if callable(v) else v for k, v in kw.items()}
    return setup


def with_prefs(**values):
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
