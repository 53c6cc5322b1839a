"""Cancel a running background job: simulation, reconstruction, ... (same as Esc over the 3D View)."""

import bpy
from bpy.props import EnumProperty

from .. import jobs

#: the job operators' `job_kind`s and their names
KINDS = (("simulation", "Simulation"), ("reconstruction", "Reconstruction"), ("evaluation", "Evaluation"),
         ("advice", "Spot advice"), ("environment", "Environment set-up"))


class PLATOLIDAR_OT_cancel_job(bpy.types.Operator):
    """Stop the running background job"""

    bl_idname = "platolidar.cancel_job"
    bl_label = "Cancel"
    bl_options = {"REGISTER"}

    kind: EnumProperty(name="Job", items=[(k, label, "") for k, label in KINDS])

    @classmethod
    def poll(cls, context):
        if all(jobs.active(k) is None for k, _ in KINDS):
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
