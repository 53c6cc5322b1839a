"""Add-on preferences: the external tools the add-on runs as subprocesses."""

import os

import bpy
from bpy.props import EnumProperty, StringProperty

from . import jobs

# The add-on's package name: 'addon' in a checkout, 'bl_ext.<repo>.platolidar' when installed
ADDON_ID = __package__


class PLATOLIDAR_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    python_path: StringProperty(
        name="Reconstruction Python", subtype="FILE_PATH", default="",
        description="Python interpreter with torch and torch_recon installed (torch is not bundled into Blender)")
    blender_path: StringProperty(
        name="Blender Binary", subtype="FILE_PATH", default="",
        description="Blender used for background simulation (empty: the running Blender)")
    project_dir: StringProperty(
        name="Project Folder", subtype="DIR_PATH", default="",
        description="Optional checkout of the project: its pipeline/simulate.py and torch_recon are used first")
    output_dir: StringProperty(
        name="Default Output Folder", subtype="DIR_PATH", default="",
        description="Base folder for datasets and reconstructions when a scene's folder is relative and "
                    "the .blend is not saved")

    env_base_python: StringProperty(
        name="Python for the Environment", subtype="FILE_PATH", default="",
        description="Python (3.10 or newer; 3.11 recommended) the new environment is made with "
                    "(empty: python3.11 or python3 on PATH)")
    env_dir: StringProperty(
        name="Environment Folder", subtype="DIR_PATH", default="",
        description="Where the new environment goes (empty: the add-on's user folder)")
    env_torch: EnumProperty(
        name="Torch Build", default="cpu", items=[
            ("cpu", "CPU", "torch's CPU build (about 200 MB)"),
            ("cuda", "CUDA", "torch's CUDA build for an NVIDIA GPU (several GB with the NVIDIA libraries)")])
    env_cuda: StringProperty(
        name="CUDA Index", default="cu128",
        description="download.pytorch.org wheel index of the CUDA build (match your driver: cu126, cu128, ...)")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "python_path")
        layout.operator("platolidar.check_environment", icon="CHECKMARK")
        box = layout.box()
        box.label(text="New reconstruction environment (venv + torch + reconstructor):")
        box.prop(self, "env_base_python")
        box.prop(self, "env_dir")
        box.prop(self, "env_torch")
        if self.env_torch == "cuda":
            box.prop(self, "env_cuda")
        job = jobs.active("environment")
        if job is None:
            box.operator("platolidar.setup_environment", icon="CONSOLE")
        else:
            row = box.row(align=True)
            row.progress(factor=job.progress or 0.0, type="BAR", text=job.short_status()[:60])
            row.operator("platolidar.cancel_job", text="", icon="CANCEL").kind = "environment"
        layout.prop(self, "blender_path")
        layout.prop(self, "project_dir")
        layout.prop(self, "output_dir")


def default_env_dir() -> str:
    """The add-on's own user folder (extension: its user directory; legacy add-on: Blender's datafiles)."""
    try:
        return os.path.join(bpy.utils.extension_path_user(ADDON_ID, path="", create=True), "recon_env")
    except (ValueError, AttributeError):
        return bpy.utils.user_resource("DATAFILES", path=os.path.join("platolidar", "recon_env"))


def get_preferences(context=None):
    """This add-on's preferences, or None when it is registered without being enabled (scripts)."""
    context = context or bpy.context
    entry = context.preferences.addons.get(ADDON_ID)
    return entry.preferences if entry is not None else None


classes = (PLATOLIDAR_AP_preferences,)
