"""Draw N random candidate spots the camera sees and the laser reaches; keep K spread-out ones."""

import bpy
from bpy.props import BoolProperty

from ..spot_geometry import SpotError, add_spot, generate_spots
from ._common import NeedsLidarSettings


class PLATOLIDAR_OT_generate_spots(NeedsLidarSettings, bpy.types.Operator):
    """Random candidate spots in the camera's view (seeded), narrowed to the most spread-out ones"""

    bl_idname = "platolidar.generate_spots"
    bl_label = "Generate Spots"
    bl_options = {"REGISTER", "UNDO"}

    replace: BoolProperty(name="Replace", default=True, description="Replace the listed spots")

    def execute(self, context):
        scene = context.scene
        s = scene.platolidar
        if s.random_keep > s.random_candidates:
            self.report({"ERROR"}, f"Cannot keep {s.random_keep} of {s.random_candidates} candidates")
            return {"CANCELLED"}
        try:
            kept, found = generate_spots(scene, context.evaluated_depsgraph_get(), s.random_candidates,
                                         s.random_keep, s.seed)
        except SpotError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if not kept:
            self.report({"ERROR"}, "No surface in the camera's view that the laser can reach")
            return {"CANCELLED"}
        if self.replace:
            s.spots.clear()
        for p in kept:
            add_spot(scene, p)
        msg = f"Kept {len(kept)} of {found} candidate spots (seed {s.seed})"
        if found < s.random_candidates:
            self.report({"WARNING"}, msg + f"; only {found} of {s.random_candidates} candidates hit a "
                                           "surface the laser reaches")
        else:
            self.report({"INFO"}, msg)
        return {"FINISHED"}
