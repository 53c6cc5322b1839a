"""Simulate: run pipeline/simulate.py in a background Blender on a saved copy of this scene."""

import os
import shutil
import tempfile

import bpy

from .. import _project, jobs
from ..preferences import get_preferences
from ._common import NeedsLidarSettings, UserError, resolve_path, validated_config
from ._job_base import JobOperatorMixin


def blender_binary(context) -> str:
    """The preference's Blender, else the running one (empty when Blender runs as the bpy module)."""
    prefs = get_preferences(context)
    if prefs is not None and prefs.blender_path:
        return bpy.path.abspath(prefs.blender_path)
    return bpy.app.binary_path or ""


class PLATOLIDAR_OT_simulate(NeedsLidarSettings, JobOperatorMixin, bpy.types.Operator):
    """Write the lidar dataset: pipeline/simulate.py in a background Blender (Esc cancels)"""

    bl_idname = "platolidar.simulate"
    bl_label = "Simulate Dataset"
    bl_options = {"REGISTER"}

    job_kind = "simulation"

    def build_job(self, context):
        s = context.scene.platolidar
        validated_config(context, self)  # also stores the JSON the background run reads
        binary = blender_binary(context)
        err = jobs.check_executable(binary, "Blender binary")
        if err:
            raise UserError(err + ": set Blender Binary in the add-on preferences "
                                  "(running as the bpy module there is no Blender executable)")
        prefs = get_preferences(context)
        script = _project.script_path(_project.SIMULATE_SCRIPT, prefs.project_dir if prefs else "")
        if script is None:
            raise UserError(f"{_project.SIMULATE_SCRIPT} not found in the extension or the Project Folder")
        out_dir = resolve_path(s.output_dir, "dataset folder", context)
        if os.path.exists(out_dir) and not os.path.isdir(out_dir):
            raise UserError(f"Dataset folder '{out_dir}' is a file")
        # the background Blender reads a saved copy: the open file and its path stay untouched
        self._tmp = tempfile.mkdtemp(prefix="platolidar_sim_")
        blend = os.path.join(self._tmp, os.path.basename(bpy.data.filepath) or "scene.blend")
        try:
            bpy.ops.wm.save_as_mainfile(filepath=blend, copy=True, check_existing=False)
        except RuntimeError as exc:
            raise UserError(f"Could not save a copy of the scene to {blend}: {exc}") from None
        self._out_dir = out_dir
        return jobs.Job("simulation", jobs.simulate_command(binary, blend, script, out_dir), cwd=self._tmp,
                        progress_lines=r"^spot \d+/\d+")

    def cleanup(self, context, job):
        tmp = getattr(self, "_tmp", None)
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
            self._tmp = None

    def finish(self, context, job):
        manifest = os.path.join(self._out_dir, "dataset.json")
        if not os.path.isfile(manifest):
            raise UserError(f"The simulator exited without writing {manifest}: {job.failure_summary()}")
        s = context.scene.platolidar
        if not s.recon_dataset_dir:
            s.recon_dataset_dir = s.output_dir
        self.report({"INFO"}, f"Dataset written to {self._out_dir} in {job.elapsed:.0f} s")
        return {"FINISHED"}
