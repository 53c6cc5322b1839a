"""Cancel the running simulation or reconstruction (same as Esc over the 3D View)."""

import bpy
from bpy.props import EnumProperty

from .. import jobs


class PLATOLIDAR_OT_cancel_job(bpy.types.Operator):
    """Stop the running background job"""

    bl_idname = "platolidar.cancel_job"
    bl_label = "Cancel"
    bl_options = {"REGISTER"}

    kind: EnumProperty(name="Job", items=(("simulation", "Simulation", ""),
                                          ("reconstruction", "Reconstruction", ""),
                                          ("evaluation", "Evaluation", ""),
                                          ("environment", "Environment set-up", "")))

    @classmethod
    def poll(cls, context):
        if all(jobs.active(k) is None for k in ("simulation", "reconstruction", "evaluation", "environment")):
            cls.poll_message_set("Nothing is running")
            return False
        return True

    def execute(self, context):
        job = jobs.active(self.kind)
        if job is None:
            self.report({"ERROR"}, f"No {self.kind} is running")
            return {"CANCELLED"}
        job.cancel()  # the job's modal operator sees it on its next timer tick and reports
        return {"FINISHED"}
