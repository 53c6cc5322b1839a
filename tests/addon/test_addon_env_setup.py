"""Set Up Reconstruction Environment (preferences): command lines, the job with a stand-in Python
(progress, success sets the Reconstruction Python, cancel removes the half-made folder, bad states are
error reports), and (slow) the real addon/recon_setup.py making a venv with torch from this machine."""

import os
import subprocess
import sys
import threading
import time

import bpy
import pytest

from tests.support.addon_fixtures import REPO, blank, call, expect_error, fake_executable, set_prefs  # noqa: F401 (fixtures)

from addon import _project, jobs, preferences

FAKE_BASE_PYTHON = r'''
import os, sys, time
a = sys.argv[1:]
env = a[a.index("--env") + 1]
os.makedirs(os.path.join(env, "bin"))
for k in range(1, 5):
    print(f"step {k}/4: doing {k}", flush=True)
    time.sleep(float(os.environ.get("FAKE_STEP_S", "0")))
open(os.path.join(env, "bin", "python"), "w").write("")
print("OK", flush=True)
'''


def test_setup_command_lines():
    cmd = jobs.setup_command("/usr/bin/python3.11", "/x/recon_setup.py", "/e", "cpu", "cu128", "requirements",
                             "/x/_reconstructor/requirements.txt", ["/x/_reconstructor"])
    assert cmd == ["/usr/bin/python3.11", "-u", "/x/recon_setup.py", "--env", "/e", "--torch", "cpu",
                   "--requirements", "/x/_reconstructor/requirements.txt", "--pythonpath", "/x/_reconstructor"]
    cmd = jobs.setup_command("py", "s.py", "/e", "cuda", "cu126", "project", "/checkout")
    assert cmd[cmd.index("--torch") + 1:] == ["cuda", "--cuda", "cu126", "--project", "/checkout"]


def test_torch_comes_from_the_chosen_build():
    from addon import recon_setup
    cuda = recon_setup.torch_install_args(sys.executable, "cu126")
    assert cuda[-3:] == ["--index-url", "https://download.pytorch.org/whl/cu126", "torch==2.13.0"]
    assert "--progress-bar" in cuda and cuda[cuda.index("--progress-bar") + 1] == "on"
    cpu = recon_setup.torch_install_args(sys.executable, "cpu")
    # a local CPU wheel when pip resolves one without an index (as on this machine), else the CPU index
    assert cpu[-1] == "torch==2.13.0" and ("--index-url" not in cpu or "whl/cpu" in cpu[cpu.index("--index-url") + 1])


def test_checkout_installs_the_project():
    assert _project.reconstructor_source("") == ("project", str(REPO))


def test_setup_with_a_stand_in_python_sets_the_reconstruction_python(blank, tmp_path):
    base = fake_executable(tmp_path / "python3", FAKE_BASE_PYTHON)
    set_prefs(env_base_python=str(base), env_dir=str(tmp_path / "env"), env_torch="cuda", env_cuda="cu126")
    res, err = call(bpy.ops.platolidar.setup_environment)
    assert err is None and res == {"FINISHED"}, err
    prefs = set_prefs()
    assert prefs.python_path == str(tmp_path / "env" / "bin" / "python")
    assert jobs.active("environment") is None


def test_cancel_removes_the_half_made_environment(blank, tmp_path, monkeypatch):
    monkeypatch.setenv("FAKE_STEP_S", "30")
    base = fake_executable(tmp_path / "python3", FAKE_BASE_PYTHON)
    set_prefs(env_base_python=str(base), env_dir=str(tmp_path / "env"), python_path="")
    seen = {}

    def cancel_soon():
        t0 = time.monotonic()
        while time.monotonic() - t0 < 20:
            job = jobs.active("environment")
            if job is not None and job.progress:
                seen["progress"], seen["status"] = job.progress, job.short_status()
                seen["env_existed"] = (tmp_path / "env").is_dir()
                job.cancel(grace=2.0)  # Job is bpy-free: safe from a thread
                return
            time.sleep(0.05)

    t = threading.Thread(target=cancel_soon)
    t.start()
    res, err = call(bpy.ops.platolidar.setup_environment)
    t.join()
    assert res == {"CANCELLED"}
    assert seen["progress"] == 0.25 and "step 1/4" in seen["status"] and seen["env_existed"]
    assert not (tmp_path / "env").exists()
    assert set_prefs().python_path == ""


def test_setup_bad_states_are_error_reports(blank, tmp_path):
    set_prefs(env_base_python=str(tmp_path / "nope"), env_dir=str(tmp_path / "env"))
    expect_error(bpy.ops.platolidar.setup_environment, "does not exist")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    set_prefs(env_base_python=sys.executable, env_dir=str(tmp_path / "full"))
    expect_error(bpy.ops.platolidar.setup_environment, "not empty")


def test_preferences_show_the_setup_and_its_progress(blank):
    from tests.support.addon_fixtures import RecordingLayout
    prefs = set_prefs(env_torch="cuda")
    layout = RecordingLayout()
    preferences.PLATOLIDAR_AP_preferences.draw(_proxy(prefs, layout), bpy.context)
    props = {e[2] for e in layout.log if e[0] == "prop"}
    assert {"env_base_python", "env_dir", "env_torch", "env_cuda"} <= props
    assert ("operator", "platolidar.setup_environment") in layout.log
    job = jobs.Job("environment", ["true"])
    job.progress, job.progress_line = 0.5, "step 2/4: installing torch 2.13.0 (cpu build)"
    jobs.set_active(job, "environment")
    try:
        layout = RecordingLayout()
        preferences.PLATOLIDAR_AP_preferences.draw(_proxy(prefs, layout), bpy.context)
    finally:
        jobs.set_active(None, "environment")
    assert any(e[0] == "progress" and e[1] == 0.5 and "installing torch" in e[2] for e in layout.log), layout.log
    assert ("op_prop", "platolidar.cancel_job", "kind") in layout.log


class _proxy:
    """The preferences' draw() with a recording layout, reading the real preference values."""

    def __init__(self, prefs, layout):
        self._prefs, self.layout, self.bl_rna = prefs, layout, prefs.bl_rna

    def __getattr__(self, name):
        return getattr(self._prefs, name)


@pytest.mark.slow
def test_real_setup_makes_a_working_environment(tmp_path):
    """recon_setup.py with this machine's Python 3.11: venv, torch (local CPU wheel or the CPU index),
    the reconstructor's requirements as the zip ships them; torch_recon then imports from PYTHONPATH."""
    sys.path.insert(0, str(REPO / "addon"))
    import build_zip
    req = tmp_path / "requirements.txt"
    req.write_text(build_zip.reconstructor_requirements())
    base = "/usr/bin/python3.11" if os.path.isfile("/usr/bin/python3.11") else jobs.find_base_python()
    env = tmp_path / "env"
    r = subprocess.run([base, "-u", str(REPO / "addon" / "recon_setup.py"), "--env", str(env), "--torch", "cpu",
                        "--requirements", str(req), "--pythonpath", str(REPO)],
                       capture_output=True, text=True, timeout=1800)
    if r.returncode != 0 and ("No matching distribution" in r.stdout + r.stderr
                              or "connection" in (r.stdout + r.stderr).lower()):
        pytest.skip("packages cannot be downloaded here")
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == f"OK {env / 'bin' / 'python'}"
    assert [ln[:8] for ln in r.stdout.splitlines() if ln.startswith("step ")] == [f"step {k}/4" for k in range(1, 5)]
    ok, msg = jobs.check_reconstruction_python(str(env / "bin" / "python"), [str(REPO)])
    assert ok and "2.13.0" in msg, msg
