"""Background jobs: command lines, progress parsing, cancel; simulate / reconstruct operators driven
through their blocking execute path with fake Blender and Python executables (no real Blender
binary exists here, and background mode has no window for the modal timer path)."""

import json
import sys
import time

import bpy
import pytest

from tests.support.addon_fixtures import (REPO, blank, call, env_without_torch_python, expect_error, fake_executable,  # noqa: F401
                            room, set_prefs)

from addon import jobs

FAKE_BLENDER = r'''
import json, os, sys, time
argv = sys.argv[1:]
assert argv[0] == "-b", argv
blend = argv[1]
assert argv[argv.index("--python-exit-code") + 1] == "1" and argv.index("--python-exit-code") < argv.index("-P")
script = argv[argv.index("-P") + 1]
out = argv[argv.index("--out") + 1]
assert os.path.isfile(blend) and script.endswith("simulate.py") and os.path.isfile(script)
import bpy  # read the saved copy like simulate.py would
bpy.ops.wm.open_mainfile(filepath=blend)
cfg = json.loads(bpy.data.texts["platolidar_config.json"].as_string())
for k in range(2):
    print(f"spot {k + 1}/2", end="\r", flush=True)
    time.sleep(0.05)
if os.environ.get("FAKE_FAIL"):
    print("simulate: error: setting 'bins': exceeds the scene", flush=True)
    sys.exit(2)
os.makedirs(out, exist_ok=True)
json.dump({"seen_config": cfg, "blend": blend}, open(os.path.join(out, "dataset.json"), "w"))
print("done", flush=True)
'''

FAKE_PYTHON = r'''
import os, sys
if sys.argv[1] == "-c":
    print("OK torch 2.13.0 cpu"); sys.exit(0)
assert sys.argv[1:4] == ["-m", "torch_recon", "fit"], sys.argv
sets = dict(a.split("=", 1) for a in sys.argv[sys.argv.index("--set"):] if a != "--set")
dataset, mode, out = sys.argv[4], sets["mode"], sys.argv[sys.argv.index("--out") + 1]
assert os.path.isfile(os.path.join(dataset, "dataset.json"))
for i in range(0, 101, 25):
    print(f"fit {mode}: {i}%|####| {i}/100 [00:01<00:{100 - i:02d}, 9.9step/s]", end="\r", flush=True)
os.makedirs(out, exist_ok=True)
open(os.path.join(out, "mesh.ply"), "w").write("ply\n")
'''


def test_command_lines():
    cmd = jobs.simulate_command("/opt/blender", "/tmp/a b.blend", "/x/pipeline/simulate.py", "/o")
    assert cmd == ["/opt/blender", "-b", "/tmp/a b.blend", "--python-exit-code", "1", "-P",
                   "/x/pipeline/simulate.py", "--", "--out", "/o"]
    assert jobs.reconstruct_command("py", "/d", "/o", "fast") == ["py", "-m", "torch_recon", "fit", "/d", "--out",
                                                                  "/o", "--set", "mode=fast", "--set", "device=auto"]


@pytest.mark.parametrize("mode", ["fast", "platonerf", "bflidar"])
def test_reconstruct_command_parses_with_the_real_cli(mode):
    """The panel's settings reach the method through the one settings mechanism (--set)."""
    import argparse

    from torch_recon.contract.methods import METHODS
    from torch_recon.contract.settings import from_args

    cmd = jobs.reconstruct_command("py", "/d", "/o", mode, steps=321, max_seconds=12.5, resolution=96, device="cpu")
    m = METHODS[mode]
    assert cmd[3] == m.command
    if m.command == "fit":
        from torch_recon.commands.fit import register
        from torch_recon.recon.config import FitConfig as cls
    else:
        from torch_recon.commands.baseline import BaselineCommand as cls
        from torch_recon.commands.baseline import register
    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    cfg = from_args(cls, ap.parse_args(cmd[3:]))
    section, _, field = m.grid_setting.partition(".")
    assert getattr(getattr(cfg, section), field) == 96 and cfg.device == "cpu"
    if m.command == "fit":
        assert cfg.mode == mode and cfg.steps == 321 and cfg.max_seconds == 12.5
    defaults = jobs.reconstruct_command("py", "/d", "/o", mode)
    assert not any(k in " ".join(defaults) for k in ("steps=", "max_seconds=", m.grid_setting))


@pytest.mark.parametrize("line,stage,eta", [
    ("fit fast:  42%|####      | 84/200 [00:10<00:14, 8.1step/s]", "fit fast", 14),
    ("UV atlas:   5%|5         | 1/20 [00:00<01:02:03, ?block/s]", "UV atlas", 3723),
    (" 42%|####  | 84/200 [00:10<?, ?it/s]", None, None),
    ("spot 3/16 rendered", None, None)])
def test_parse_stage_and_eta(line, stage, eta):
    assert jobs.parse_stage(line) == (stage, eta)


def test_job_shows_stage_progress_and_eta():
    code = ("import sys\nsys.stdout.write('preprocess: 100%|##| 4/4 [00:01<00:00]\\n')\n"
            "sys.stdout.write('fit fast:  42%|####  | 84/200 [00:10<01:14, 8.1step/s]\\r')\n")
    job = jobs.Job("reconstruction", [sys.executable, "-c", code]).start()
    assert job.wait(timeout=30) == 0
    assert job.stage == "fit fast" and job.progress == pytest.approx(0.42) and job.eta_s == 74
    assert job.short_status() == "fit fast 42% ETA 1:14"
    assert "fit fast 42% ETA 1:14" in job.status_text()


@pytest.mark.parametrize("line,expected", [("spot 3/16 rendered", 3 / 16), (" 42%|####  | 84/200", 0.42),
                                           ("fit: 100.0%", 1.0), ("version 5.0.1", None), ("17/0", None),
                                           ("no numbers", None), ("20/10", None)])
def test_parse_progress(line, expected):
    got = jobs.parse_progress(line)
    assert got == (None if expected is None else pytest.approx(expected))


def test_job_progress_and_exit(tmp_path):
    code = "import sys,time\nfor i in range(1,5):\n print(f'step {i}/4', end='\\r', flush=True); time.sleep(0.02)\n" \
           "print('\\nError: last words', flush=True); sys.exit(3)"
    job = jobs.Job("t", [sys.executable, "-c", code]).start()
    assert job.wait(timeout=30) == 3
    assert job.progress == 1.0 and "step 4/4" in job.lines
    assert "last words" in job.failure_summary() and not job.ok


def test_job_progress_only_from_matching_lines():
    code = "print('spot 1/4 rendered'); print('Sample 15/16'); print('Saved: a/b')"
    job = jobs.Job("t", [sys.executable, "-c", code], progress_lines=r"^spot \d+/\d+").start()
    assert job.wait(timeout=30) == 0 and job.ok
    assert job.progress == 0.25 and job.progress_line == "spot 1/4 rendered" and job.last_line == "Saved: a/b"
    assert "spot 1/4" in job.status_text()


def test_job_cancel_stops_quickly():
    job = jobs.Job("t", [sys.executable, "-c", "import time; print('started', flush=True); time.sleep(60)"]).start()
    time.sleep(0.3)
    t = time.monotonic()
    job.cancel(grace=2.0)
    assert time.monotonic() - t < 3.0
    assert job.poll() and job.cancelled and job.returncode != 0


def test_simulate_with_fake_blender(room, tmp_path):
    blender = fake_executable(tmp_path / "blender", FAKE_BLENDER)
    set_prefs(blender_path=str(blender))
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    room.platolidar.output_dir = str(tmp_path / "dataset")
    res, err = call(bpy.ops.platolidar.simulate)
    assert err is None and res == {"FINISHED"}
    d = json.loads((tmp_path / "dataset" / "dataset.json").read_text())
    # the background Blender read exactly the panel's settings from the saved copy
    assert d["seen_config"]["width"] == 16 and d["seen_config"]["camera"] == "LidarCam"
    assert d["seen_config"]["spots"][0]["target"] == pytest.approx([0.0, 0.5, 0.5], abs=1e-4)
    assert not __import__("os").path.exists(d["blend"])  # the temporary copy is gone
    assert room.platolidar.recon_dataset_dir == str(tmp_path / "dataset")
    assert bpy.data.filepath == ""  # the open file was not re-pathed by saving the copy


def test_simulate_failure_is_reported(room, tmp_path, monkeypatch):
    set_prefs(blender_path=str(fake_executable(tmp_path / "blender", FAKE_BLENDER)))
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    room.platolidar.output_dir = str(tmp_path / "dataset")
    monkeypatch.setenv("FAKE_FAIL", "1")
    err = expect_error(bpy.ops.platolidar.simulate, "exit code 2")
    assert "exceeds the scene" in err
    assert not (tmp_path / "dataset").exists()


def test_simulate_bad_states(room, tmp_path):
    s = room.platolidar
    s.output_dir = str(tmp_path / "ds")
    expect_error(bpy.ops.platolidar.simulate, "no enabled spot")
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    # bpy module: no Blender executable, none in the preferences
    expect_error(bpy.ops.platolidar.simulate, "blender binary")
    set_prefs(blender_path=str(tmp_path / "missing-blender"))
    expect_error(bpy.ops.platolidar.simulate, "does not exist")
    set_prefs(blender_path=str(tmp_path))
    expect_error(bpy.ops.platolidar.simulate, "not an executable")
    set_prefs(blender_path=str(fake_executable(tmp_path / "blender", FAKE_BLENDER)))
    s.spots[0].target = (0.0, -20.0, 8.0)
    expect_error(bpy.ops.platolidar.simulate, "aimed at nothing")
    s.spots[0].target = (0.0, 0.5, 0.5)
    s.output_dir = "//relative_dataset"  # the .blend is not saved
    expect_error(bpy.ops.platolidar.simulate, "not saved")
    s.camera = None
    room.camera = None
    expect_error(bpy.ops.platolidar.simulate, "no lidar camera")
    assert not bpy.ops.platolidar.cancel_job.poll()


def _fake_dataset(tmp_path):
    ds = tmp_path / "ds"
    ds.mkdir()
    (ds / "dataset.json").write_text("{}")
    return ds


def test_reconstruct_with_fake_python(room, tmp_path):
    py = fake_executable(tmp_path / "python", FAKE_PYTHON)
    set_prefs(python_path=str(py))
    s = room.platolidar
    s.recon_dataset_dir = str(_fake_dataset(tmp_path))
    s.recon_out_dir = str(tmp_path / "recon")
    res, err = call(bpy.ops.platolidar.reconstruct)
    assert err is None and res == {"FINISHED"}
    assert s.import_path == str(tmp_path / "recon" / "mesh.ply")


FAKE_EVAL_PYTHON = r'''
import json, os, sys
if sys.argv[1] == "-c":
    print("OK torch 2.13.0 cpu"); sys.exit(0)
assert sys.argv[1:4] == ["-m", "torch_recon", "evaluate"], sys.argv
out = sys.argv[sys.argv.index("--out") + 1]
os.makedirs(out, exist_ok=True)
json.dump({"depth_l1_m": 0.0123, "depth_psnr_db": 21.5, "chamfer_m": 0.02, "fscore": 0.9}, open(os.path.join(out, "report.json"), "w"))
open(os.path.join(out, "summary.html"), "w").write("<html></html>")
'''


def test_evaluate_shows_key_numbers_and_the_summary(room, tmp_path):
    set_prefs(python_path=str(fake_executable(tmp_path / "python", FAKE_EVAL_PYTHON)))
    s = room.platolidar
    s.recon_dataset_dir = str(_fake_dataset(tmp_path))
    expect_error(bpy.ops.platolidar.open_summary, "evaluate first")
    s.import_path = str(tmp_path / "recon" / "mesh.ply")
    expect_error(bpy.ops.platolidar.evaluate, "does not exist")
    (tmp_path / "recon").mkdir()
    (tmp_path / "recon" / "mesh.ply").write_text("ply")
    res, err = call(bpy.ops.platolidar.evaluate)
    assert err is None and res == {"FINISHED"}, err
    assert json.loads(s.result_numbers) == [["Depth L1", "0.0123 m"], ["Depth PSNR", "21.50 dB"],
                                            ["Chamfer", "0.0200 m"], ["F-score", "0.900"]]
    assert s.result_summary == str(tmp_path / "recon" / "eval" / "summary.html")


def test_reconstruct_bad_environments(room, tmp_path):
    s = room.platolidar
    s.recon_dataset_dir = str(_fake_dataset(tmp_path))
    s.recon_out_dir = str(tmp_path / "recon")
    expect_error(bpy.ops.platolidar.reconstruct, "no reconstruction python")
    set_prefs(python_path=str(tmp_path / "nowhere" / "python"))
    expect_error(bpy.ops.platolidar.reconstruct, "does not exist")
    expect_error(bpy.ops.platolidar.check_environment, "does not exist")
    no_torch = env_without_torch_python()
    if no_torch is not None:
        set_prefs(python_path=no_torch)
        expect_error(bpy.ops.platolidar.reconstruct, "cannot import torch")
        expect_error(bpy.ops.platolidar.check_environment, "cannot import torch")
    # an interpreter that dies on start
    set_prefs(python_path=str(fake_executable(tmp_path / "broken", "import sys; sys.exit(1)")))
    expect_error(bpy.ops.platolidar.reconstruct, "failed to start")
    # a working interpreter (the fake) but no dataset there
    set_prefs(python_path=str(fake_executable(tmp_path / "python", FAKE_PYTHON)))
    s.recon_dataset_dir = str(tmp_path / "empty")
    expect_error(bpy.ops.platolidar.reconstruct, "not a dataset")


def test_real_python_environment_check(room):
    """This venv's Python has torch, and torch_recon from the checkout: the check passes."""
    set_prefs(python_path=sys.executable)
    res, err = call(bpy.ops.platolidar.check_environment)
    assert err is None and res == {"FINISHED"}


class _Recorder:
    def __init__(self):
        self.status, self.timers_removed = [], 0

    def status_text_set(self, text):
        self.status.append(text)

    def event_timer_remove(self, timer):
        self.timers_removed += 1


def _modal_op(cmd, finish_result=frozenset({"FINISHED"})):
    """The modal plumbing of the job operators, on a plain object (no window exists in background mode)."""
    from addon.operators._job_base import JobOperatorMixin

    class FakeJobOperator(JobOperatorMixin):
        job_kind = "simulation"

        def __init__(self):
            self.reports, self.cleaned = [], 0

        def report(self, kind, msg):
            self.reports.append((next(iter(kind)), msg))

        def build_job(self, context):
            return jobs.Job("simulation", cmd, progress_lines=r"^spot")

        def finish(self, context, job):
            return set(finish_result)

        def cleanup(self, context, job):
            self.cleaned += 1

    rec = _Recorder()
    ctx = type("Ctx", (), {"workspace": rec, "window_manager": rec})()
    op = FakeJobOperator()
    op._job = op._prepare(ctx)
    op._timer = object()
    return op, ctx, rec


def _event(kind, value="NOTHING"):
    return type("Event", (), {"type": kind, "value": value})()


def test_modal_timer_polls_until_done(blank):
    code = "import time\nfor i in range(1, 4):\n print(f'spot {i}/3', flush=True); time.sleep(0.1)"
    op, ctx, rec = _modal_op([sys.executable, "-c", code])
    assert jobs.active("simulation") is op._job
    result, t0 = {"PASS_THROUGH"}, time.monotonic()
    while result == {"PASS_THROUGH"} and time.monotonic() - t0 < 30:
        assert op.modal(ctx, _event("MOUSEMOVE")) == {"PASS_THROUGH"}  # the user keeps working
        result = op.modal(ctx, _event("TIMER"))
        time.sleep(0.05)
    assert result == {"FINISHED"}
    assert any(t and "spot" in t and "Esc to cancel" in t for t in rec.status)
    assert rec.status[-1] is None and rec.timers_removed == 1 and op.cleaned == 1
    assert jobs.active("simulation") is None


def test_modal_escape_cancels_and_reports(blank):
    op, ctx, rec = _modal_op([sys.executable, "-c", "import time; time.sleep(60)"])
    # a second job of the same kind is refused while one runs
    with pytest.raises(Exception, match="already running"):
        op._prepare(ctx)
    assert op.modal(ctx, _event("TIMER")) == {"PASS_THROUGH"}
    t0 = time.monotonic()
    assert op.modal(ctx, _event("ESC", "PRESS")) == {"CANCELLED"}
    assert time.monotonic() - t0 < 6.0
    assert op.reports[-1][0] == "WARNING" and "cancelled" in op.reports[-1][1]
    assert op._job.returncode is not None and jobs.active("simulation") is None and op.cleaned == 1


def test_modal_failure_is_an_error_report(blank):
    op, ctx, rec = _modal_op([sys.executable, "-c", "import sys; print('Error: no camera'); sys.exit(2)"])
    result, t0 = {"PASS_THROUGH"}, time.monotonic()
    while result == {"PASS_THROUGH"} and time.monotonic() - t0 < 30:
        result = op.modal(ctx, _event("TIMER"))
        time.sleep(0.05)
    assert result == {"CANCELLED"}
    assert op.reports[-1][0] == "ERROR" and "exit code 2" in op.reports[-1][1] and "no camera" in op.reports[-1][1]


def test_reconstruction_output_mesh_choice(tmp_path):
    from addon.operators.reconstruct import reported_mesh
    assert reported_mesh(str(tmp_path)) is None
    (tmp_path / "a.obj").write_text("o")
    assert reported_mesh(str(tmp_path)) == str(tmp_path / "a.obj")
    (tmp_path / ".partial.ply").write_text("p")  # a write in progress is never picked
    assert reported_mesh(str(tmp_path)) == str(tmp_path / "a.obj")
    for name in ("mesh.glb", "mesh.obj", "mesh.ply"):
        (tmp_path / name).write_text("m")
    (tmp_path / "fit.json").write_text(json.dumps({"mesh_files": {"glb": str(tmp_path / "mesh.glb"),
                                                                  "ply": "mesh.ply", "obj": "mesh.obj"}}))
    assert reported_mesh(str(tmp_path)) == str(tmp_path / "mesh.ply")


def test_cancel_button_operator(blank):
    job = jobs.Job("simulation", [sys.executable, "-c", "import time; time.sleep(60)"]).start()
    jobs.set_active(job, "simulation")
    try:
        assert bpy.ops.platolidar.cancel_job.poll()
        expect_error(bpy.ops.platolidar.cancel_job, "no reconstruction is running", kind="reconstruction")
        res, err = call(bpy.ops.platolidar.cancel_job, kind="simulation")
        assert err is None and res == {"FINISHED"}
        assert job.cancelled and job.returncode is not None
    finally:
        job.cancel(grace=1.0)
        jobs.set_active(None, "simulation")


def test_failed_simulate_leaves_no_temporary_copy(room, tmp_path, monkeypatch):
    import glob
    import tempfile
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    set_prefs(blender_path=str(fake_executable(tmp_path / "blender", FAKE_BLENDER)))
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    (tmp_path / "file").write_text("x")
    room.platolidar.output_dir = str(tmp_path / "file")  # a file where the dataset folder should go
    expect_error(bpy.ops.platolidar.simulate, "is a file")
    room.platolidar.output_dir = str(tmp_path / "ds")
    monkeypatch.setenv("FAKE_FAIL", "1")
    expect_error(bpy.ops.platolidar.simulate, "exit code 2")
    assert glob.glob(str(tmp_path / "platolidar_sim_*")) == []
