"""Load settings and spots from a JSON file (an exported SimulationConfig) into the panel."""

import bpy
from bpy.props import StringProperty
from bpy_extras.io_utils import ImportHelper

from ..config_io import PlatolidarError, SimulationConfig, config_to_settings
from ._common import NeedsLidarSettings


class PLATOLIDAR_OT_load_config(NeedsLidarSettings, bpy.types.Operator, ImportHelper):
    """Replace the panel's settings and spots with those of a settings JSON file"""

    bl_idname = "platolidar.load_config"
    bl_label = "Load Settings JSON"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context):
        try:
            cfg = SimulationConfig.load(bpy.path.abspath(self.filepath))
            config_to_settings(cfg, context.scene)
        except PlatolidarError as exc:     # ConfigError, a SettingsError of the shared settings reader, ...
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except OSError as exc:
            self.report({"ERROR"}, f"Cannot read '{self.filepath}': {exc.strerror or exc}")
            return {"CANCELLED"}
        missing = [n for n in (cfg.camera, cfg.laser_object) if n and n not in bpy.data.objects]
        if missing:
            self.report({"WARNING"}, f"Objects not in this file: {', '.join(missing)}")
        self.report({"INFO"}, f"Loaded {len(cfg.spots)} spots and settings")
        return {"FINISHED"}
