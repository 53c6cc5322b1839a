"""Import the reconstructed mesh in place into the 'Reconstruction' collection, optionally error-coloured."""

import bpy

from .. import importing
from ._common import NeedsLidarSettings, UserError, resolve_path


class PLATOLIDAR_OT_import_reconstruction(NeedsLidarSettings, bpy.types.Operator):
    """Load the reconstructed mesh (.ply/.obj, world frame) into the 'Reconstruction' collection"""

    bl_idname = "platolidar.import_reconstruction"
    bl_label = "Import Reconstruction"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        s = context.scene.platolidar
        try:
            path = resolve_path(s.import_path, "mesh file", context)
            bvh = None
            if s.import_color_error:
                # check the ground truth before importing anything: nothing half-done on error
                dataset = resolve_path(s.recon_dataset_dir or s.output_dir, "dataset folder", context)
                gt = importing.dataset_gt_mesh(dataset)
                if gt is None:
                    raise UserError(f"Colour by Error needs the dataset's ground-truth mesh; '{dataset}' has "
                                    "none (dataset.json ground_truth.mesh_file): untick it or simulate with it")
            objs = importing.import_reconstruction(context.scene, path)
            if s.import_color_error:
                bvh = importing.gt_bvh(gt)
                stats = [importing.colour_by_error(o, bvh) for o in objs if o.type == "MESH"]
                if stats:
                    s.result_error_scale_m = stats[0]["scale_m"]
                    s.result_error_mean_m, s.result_error_max_m = stats[0]["mean_m"], stats[0]["max_m"]
                    self.report({"INFO"}, "Error to ground truth: mean {:.4f} m, max {:.4f} m (red = {:.4f} m)"
                                .format(stats[0]["mean_m"], stats[0]["max_m"], stats[0]["scale_m"]))
        except (UserError, importing.ImportProblem) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"Imported {', '.join(o.name for o in objs)} into '{importing.COLLECTION_NAME}'")
        return {"FINISHED"}
