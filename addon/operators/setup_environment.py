"""Set up a reconstruction environment from the preferences: a venv with torch and the reconstructor.

A background job like Simulate and Reconstruct (progress from recon_setup.py's 'step k/4' lines and
pip's own output, Esc or Cancel stops it). A cancelled or failed set-up removes the folder it
created; on success the new environment's Python becomes the Reconstruction Python.
"""

import os
import shutil
from pathlib import Path

import bpy

from .. import _project, jobs
from ..preferences import default_env_dir, get_preferences
from ..recon_setup import env_python
from ._common import UserError
from ._job_base import JobOperatorMixin


class PLATOLIDAR_OT_setup_environment(JobOperatorMixin, bpy.types.Operator):
    """Create a Python environment with torch (the chosen build) and the reconstructor (Esc cancels)"""

    bl_idname = "platolidar.setup_environment"
    bl_label = "Set Up Reconstruction Environment"
    bl_options = {"REGISTER"}

    job_kind = "environment"

    @classmethod
    def poll(cls, context):
        return True

    def build_job(self, context):
        prefs = get_preferences(context)
        if prefs is None:
            raise UserError("Add-on preferences unavailable: enable the add-on in Preferences > Add-ons")
        base = bpy.path.abspath(prefs.env_base_python) if prefs.env_base_python else jobs.find_base_python()
        err = jobs.check_executable(base, "Python for the environment")
        if err:
            raise UserError(err + ": set 'Python for the Environment' (3.10 or newer) in the preferences")
        env_dir = bpy.path.abspath(prefs.env_dir) if prefs.env_dir else default_env_dir()
        if os.path.exists(env_dir) and os.listdir(env_dir):
            raise UserError(f"Environment folder '{env_dir}' exists and is not empty: pick another or delete it")
        try:
            kind, source = _project.reconstructor_source(prefs.project_dir)
        except FileNotFoundError as exc:
            raise UserError(str(exc)) from None
        self._env_dir, self._created = env_dir, not os.path.exists(env_dir)
        cmd = jobs.setup_command(base, str(_project.SETUP_SCRIPT), env_dir, prefs.env_torch, prefs.env_cuda,
                                 kind, source, _project.reconstruction_pythonpath(prefs.project_dir))
        return jobs.Job("environment", cmd, env=jobs.python_env(), progress_lines=r"^step \d+/\d+")

    def cleanup(self, context, job):
        if job is not None and not job.ok and getattr(self, "_created", False):
            shutil.rmtree(self._env_dir, ignore_errors=True)  # no half-made environment left behind

    def finish(self, context, job):
        python = str(env_python(Path(self._env_dir)))
        if not os.path.isfile(python):
            raise UserError(f"The set-up finished but {python} is missing: {job.failure_summary()}")
        prefs = get_preferences(context)
        prefs.python_path = python
        self.report({"INFO"}, f"Reconstruction environment ready in {job.elapsed:.0f} s: {python}")
        return {"FINISHED"}
