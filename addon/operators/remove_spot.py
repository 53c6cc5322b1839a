"""Remove the active laser spot."""

import bpy

from ._common import settings_of


class PLATOLIDAR_OT_remove_spot(bpy.types.Operator):
    """Remove the active laser spot from the list"""

    bl_idname = "platolidar.remove_spot"
    bl_label = "Remove Spot"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        s = settings_of(context)
        if s is None or not len(s.spots):
            cls.poll_message_set("No spot to remove")
            return False
        return True

    def execute(self, context):
        s = context.scene.platolidar
        i = s.active_spot_index
        if not 0 <= i < len(s.spots):
            self.report({"ERROR"}, f"No active spot (index {i} of {len(s.spots)} spots)")
            return {"CANCELLED"}
        s.spots.remove(i)
        s.active_spot_index = min(i, max(0, len(s.spots) - 1))
        return {"FINISHED"}
