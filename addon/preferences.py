"""Add-on preferences: the external tools the add-on runs as subprocesses."""

import bpy
from bpy.props import StringProperty

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

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "python_path")
        layout.operator("platolidar.check_environment", icon="CHECKMARK")
        layout.prop(self, "blender_path")
        layout.prop(self, "project_dir")
        layout.prop(self, "output_dir")


def get_preferences(context=None):
    """This add-on's preferences, or None when it is registered without being enabled (scripts)."""
    context = context or bpy.context
    entry = context.preferences.addons.get(ADDON_ID)
    return entry.preferences if entry is not None else None


classes = (PLATOLIDAR_AP_preferences,)
