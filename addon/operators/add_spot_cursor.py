"""Add a laser spot where the laser, aimed at the 3D cursor, lands on a surface."""

import bpy

from ..spot_geometry import SpotError, add_spot, aim_laser
from ._common import NeedsLidarSettings


class PLATOLIDAR_OT_add_spot_cursor(NeedsLidarSettings, bpy.types.Operator):
    """Aim the laser from its origin at the 3D cursor and add a spot on the surface it hits"""

    bl_idname = "platolidar.add_spot_cursor"
    bl_label = "Add Spot at Cursor"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        scene = context.scene
        try:
            hit = aim_laser(scene, context.evaluated_depsgraph_get(), scene.cursor.location)
        except SpotError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if hit is None:
            self.report({"ERROR"}, "The laser aimed at the 3D cursor hits nothing: place the cursor on a surface "
                                   "(Shift+right-click) in front of the laser")
            return {"CANCELLED"}
        sp = add_spot(scene, hit)
        self.report({"INFO"}, f"Added {sp.name} at ({hit.x:.3f}, {hit.y:.3f}, {hit.z:.3f})")
        return {"FINISHED"}
