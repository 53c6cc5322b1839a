"""Add laser spots by clicking surfaces in the 3D View (modal), or from a given view ray (scripts)."""

import bpy
from bpy.props import FloatVectorProperty
from bpy_extras import view3d_utils

from ..spot_geometry import SpotError, add_spot, aim_laser, cast

HEADER = "Click a surface to add a laser spot  |  Esc / right-click: done"


def spot_from_view_ray(context, origin, direction):
    """Non-interactive core: the surface under a view ray, then where the laser aimed there lands.

    Returns the new spot; raises SpotError when the view ray or the laser hits nothing.
    """
    scene = context.scene
    depsgraph = context.evaluated_depsgraph_get()
    if direction is None or sum(c * c for c in direction) < 1e-18:
        raise SpotError("Zero-length view ray")
    under = cast(scene, depsgraph, origin, direction)
    if under is None:
        raise SpotError("No surface under the mouse")
    hit = aim_laser(scene, depsgraph, under[0])
    if hit is None:
        raise SpotError("The laser aimed at that point hits nothing")
    return add_spot(scene, hit)


def view_region_under_mouse(areas, mouse_x: int, mouse_y: int):
    """(region, (x, y) in region pixels) of the 3D viewport region under the window-space mouse.

    The operator starts from a sidebar button, so the event's own region is the sidebar; the
    click must be mapped to the 3D View's main ('WINDOW') region it lands in, if any.
    """
    for area in areas:
        if area.type != "VIEW_3D":
            continue
        for region in area.regions:
            if region.type == "WINDOW" and region.x <= mouse_x < region.x + region.width \
                    and region.y <= mouse_y < region.y + region.height:
                return region, (mouse_x - region.x, mouse_y - region.y)
    return None, None


class PLATOLIDAR_OT_add_spot_click(bpy.types.Operator):
    """Click surfaces in the 3D View to add laser spots (Esc or right-click when done)"""

    bl_idname = "platolidar.add_spot_click"
    bl_label = "Add Spots by Clicking"
    bl_options = {"REGISTER", "UNDO"}

    view_origin: FloatVectorProperty(name="View Origin", size=3, options={"SKIP_SAVE", "HIDDEN"})
    view_direction: FloatVectorProperty(name="View Direction", size=3, options={"SKIP_SAVE", "HIDDEN"})

    @classmethod
    def poll(cls, context):
        if getattr(context.scene, "platolidar", None) is None:
            cls.poll_message_set("No scene with lidar settings")
            return False
        return True

    def execute(self, context):
        # scripted use: the view ray is given as properties
        try:
            sp = spot_from_view_ray(context, self.view_origin, self.view_direction)
        except SpotError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Added {sp.name}")
        return {"FINISHED"}

    def invoke(self, context, event):
        if context.area is None or context.area.type != "VIEW_3D":
            self.report({"ERROR"}, "Run this from a 3D View (the Lidar tab of its sidebar)")
            return {"CANCELLED"}
        self._added = 0
        context.area.header_text_set(HEADER)
        context.window.cursor_modal_set("CROSSHAIR")
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context):
        context.area.header_text_set(None)
        context.window.cursor_modal_restore()
        return {"FINISHED"} if self._added else {"CANCELLED"}

    def modal(self, context, event):
        if event.type in {"ESC", "RIGHTMOUSE"} and event.value == "PRESS":
            return self._end(context)
        if event.type == "LEFTMOUSE" and event.value == "PRESS":
            region, coord = view_region_under_mouse(context.window.screen.areas, event.mouse_x, event.mouse_y)
            if region is None or region.data is None:
                return {"PASS_THROUGH"}  # a click on a header, the sidebar or another editor
            origin = view3d_utils.region_2d_to_origin_3d(region, region.data, coord)
            direction = view3d_utils.region_2d_to_vector_3d(region, region.data, coord)
            try:
                sp = spot_from_view_ray(context, origin, direction)
                self._added += 1
                self.report({"INFO"}, f"Added {sp.name}")
            except SpotError as exc:
                self.report({"WARNING"}, str(exc))
            return {"RUNNING_MODAL"}
        return {"PASS_THROUGH"}
