"""Check that the reconstruction Python can import torch and torch_recon."""

import bpy

from .. import _project, jobs
from ..preferences import get_preferences


class PLATOLIDAR_OT_check_environment(bpy.types.Operator):
    """Run the reconstruction Python once to check it has torch and torch_recon"""

    bl_idname = "platolidar.check_environment"
    bl_label = "Check Reconstruction Python"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return True

    def execute(self, context):
        prefs = get_preferences(context)
        if prefs is None:
            self.report({"ERROR"}, "Add-on preferences unavailable: enable the add-on in Preferences > Add-ons")
            return {"CANCELLED"}
        python = bpy.path.abspath(prefs.python_path) if prefs.python_path else ""
        ok, msg = jobs.check_reconstruction_python(python, _project.reconstruction_pythonpath(prefs.project_dir))
        self.report({"INFO"} if ok else {"ERROR"}, msg)
        return {"FINISHED"} if ok else {"CANCELLED"}
