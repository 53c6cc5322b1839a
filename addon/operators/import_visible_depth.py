"""Import the closed-form visible depth of a measurements .npz as a point cloud."""

import bpy
from bpy.props import FloatProperty

from .. import importing
from ._common import NeedsLidarSettings, UserError, resolve_path


class PLATOLIDAR_OT_import_visible_depth(NeedsLidarSettings, bpy.types.Operator):
    """Show the visible depth (measurements .npz from torch_recon) as points in the 'Reconstruction' collection"""

    bl_idname = "platolidar.import_visible_depth"
    bl_label = "Import Visible Depth"
    bl_options = {"REGISTER", "UNDO"}

    radius: FloatProperty(name="Point Radius", default=0.005, min=1e-5, subtype="DISTANCE", unit="LENGTH")

    def execute(self, context):
        s = context.scene.platolidar
        try:
            path = resolve_path(s.measurements_path, "measurements file", context)
            pts, conf = importing.visible_depth_points(path)
            if len(pts) == 0:
                raise UserError(f"'{path}': no pixel has a visible depth")
            obj = importing.points_object(context.scene, pts, conf, self.radius)
        except (UserError, importing.ImportProblem) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Imported {len(pts)} points as '{obj.name}'")
        return {"FINISHED"}
