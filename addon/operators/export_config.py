"""Export the spots and sensor settings as JSON for a later headless run (simulate.py --config)."""

import os

import bpy
from bpy.props import StringProperty
from bpy_extras.io_utils import ExportHelper

from ._common import NeedsLidarSettings, UserError, validated_config


class PLATOLIDAR_OT_export_config(NeedsLidarSettings, bpy.types.Operator, ExportHelper):
    """Write the spots and settings as JSON (pipeline.config.SimulationConfig) for a headless run"""

    bl_idname = "platolidar.export_config"
    bl_label = "Export Settings JSON"
    bl_options = {"REGISTER"}

    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def execute(self, context):
        try:
            if not self.filepath:
                raise UserError("No file path given")
            cfg = validated_config(context, self)
            path = bpy.path.abspath(self.filepath)
            folder = os.path.dirname(path) or "."
            if not os.path.isdir(folder):
                raise UserError(f"Folder '{folder}' does not exist")
            tmp = path + ".tmp"
            with open(tmp, "w") as f:
                f.write(cfg.to_json())
            os.replace(tmp, path)
        except UserError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except OSError as exc:
            self.report({"ERROR"}, f"Cannot write '{self.filepath}': {exc.strerror or exc}")
            return {"CANCELLED"}
        n = sum(1 for s in cfg.spots if s.enabled)
        self.report({"INFO"}, f"Wrote {path} ({n} enabled spots)")
        return {"FINISHED"}
