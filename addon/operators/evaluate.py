"""Evaluate: `python -m torch_recon evaluate MESH --dataset DS --out DIR` in the reconstruction Python.

Afterwards the Reconstruct panel shows the key numbers (from DIR/report.json) and *Open Summary*
opens DIR/summary.html (torch_recon/evaluation/report.py: renders, error images, tables, times).
"""

import json
import os

import bpy

from .. import jobs
from ._common import NeedsLidarSettings, UserError, dataset_dir, reconstruction_python, resolve_path
from ._job_base import JobOperatorMixin

#: (report.json key, label, format) shown in the panel
KEY_NUMBERS = (("depth_l1_m", "Depth L1", "{:.4f} m"), ("depth_psnr_db", "Depth PSNR", "{:.2f} dB"),
               ("chamfer_m", "Chamfer", "{:.4f} m"), ("fscore", "F-score", "{:.3f}"))


def key_numbers(report: dict) -> list:
    """[(label, text)] of the report's key numbers (missing ones left out)."""
    out = []
    for key, label, fmt in KEY_NUMBERS:
        v = report.get(key)
        if isinstance(v, (int, float)):
            out.append((label, fmt.format(v)))
    return out


class PLATOLIDAR_OT_evaluate(NeedsLidarSettings, JobOperatorMixin, bpy.types.Operator):
    """Compare the reconstruction with the dataset's ground truth: metrics and a summary page (Esc cancels)"""

    bl_idname = "platolidar.evaluate"
    bl_label = "Evaluate"
    bl_options = {"REGISTER"}

    job_kind = "evaluation"

    def build_job(self, context):
        s = context.scene.platolidar
        python, paths = reconstruction_python(context)
        mesh = resolve_path(s.import_path, "reconstructed mesh (Import > Mesh)", context)
        if not os.path.isfile(mesh):
            raise UserError(f"Mesh '{mesh}' does not exist: reconstruct first or pick the file under Import")
        dataset = dataset_dir(context)
        self._out_dir = os.path.join(os.path.dirname(mesh), "eval")
        return jobs.Job("evaluation", jobs.evaluate_command(python, mesh, dataset, self._out_dir),
                        env=jobs.python_env(paths))

    def finish(self, context, job):
        try:
            with open(os.path.join(self._out_dir, "report.json")) as f:
                report = json.load(f)
        except (OSError, ValueError) as exc:
            raise UserError(f"The evaluation wrote no readable report.json in {self._out_dir}: {exc}") from None
        s = context.scene.platolidar
        numbers = key_numbers(report)
        s.result_numbers = json.dumps(numbers)
        summary = os.path.join(self._out_dir, "summary.html")
        s.result_summary = summary if os.path.isfile(summary) else ""
        self.report({"INFO"}, "Evaluated: " + ", ".join(f"{k} {v}" for k, v in numbers))
        return {"FINISHED"}


class PLATOLIDAR_OT_open_summary(NeedsLidarSettings, bpy.types.Operator):
    """Open the evaluation's summary page (renders, error images, metrics, times) in the web browser"""

    bl_idname = "platolidar.open_summary"
    bl_label = "Open Summary"
    bl_options = {"REGISTER"}

    def execute(self, context):
        path = context.scene.platolidar.result_summary
        if not path or not os.path.isfile(path):
            self.report({"ERROR"}, f"No summary page{' at ' + path if path else ''}: evaluate first")
            return {"CANCELLED"}
        bpy.ops.wm.url_open(url="file://" + os.path.abspath(path).replace(os.sep, "/"))
        return {"FINISHED"}
