"""Reconstruct: `python -m torch_recon fit` in the external Python from the preferences."""

import json
import os

import bpy

from .. import jobs
from ._common import NeedsLidarSettings, UserError, dataset_dir, reconstruction_python, resolve_path
from ._job_base import JobOperatorMixin

MESH_EXTENSIONS = (".ply", ".obj", ".glb")  # preference order when written together


def newest_mesh(folder: str) -> str | None:
    """The most recently written mesh under `folder` (the reconstructor's output); .ply first on ties."""
    found = []
    for root, _dirs, files in os.walk(folder):
        for name in files:
            ext = os.path.splitext(name)[1].lower()
            if ext in MESH_EXTENSIONS and not name.startswith("."):  # dot-files: partial writes
                p = os.path.join(root, name)
                found.append((round(os.path.getmtime(p), 1), -MESH_EXTENSIONS.index(ext), p))
    return max(found)[2] if found else None


def reported_mesh(folder: str) -> str | None:
    """The mesh named in the reconstructor's fit.json (a .ply when there is one), else the newest mesh."""
    try:
        with open(os.path.join(folder, "fit.json")) as f:
            files = [str(v) for v in (json.load(f).get("mesh_files") or {}).values()]
    except (OSError, ValueError, AttributeError):
        files = []
    files = [p if os.path.isabs(p) else os.path.join(folder, p) for p in files]
    files = sorted((p for p in files if os.path.isfile(p)),
                   key=lambda p: os.path.splitext(p)[1].lower() != ".ply")
    return files[0] if files else newest_mesh(folder)


class PLATOLIDAR_OT_reconstruct(NeedsLidarSettings, JobOperatorMixin, bpy.types.Operator):
    """Fit geometry to the dataset with torch_recon in the external Python (Esc cancels)"""

    bl_idname = "platolidar.reconstruct"
    bl_label = "Reconstruct"
    bl_options = {"REGISTER"}

    job_kind = "reconstruction"

    def build_job(self, context):
        s = context.scene.platolidar
        python, paths = reconstruction_python(context)
        dataset = dataset_dir(context, ": simulate first or pick the folder")
        out_dir = resolve_path(s.recon_out_dir, "reconstruction output folder", context)
        self._out_dir = out_dir
        fit_budget = {"steps": s.recon_steps} if s.recon_budget == "STEPS" else {"max_seconds": s.recon_max_seconds}
        cmd = jobs.reconstruct_command(python, dataset, out_dir, s.recon_mode, resolution=s.recon_resolution,
                                       device=s.recon_device, **fit_budget)
        return jobs.Job("reconstruction", cmd, env=jobs.python_env(paths))

    def finish(self, context, job):
        mesh = reported_mesh(self._out_dir) if os.path.isdir(self._out_dir) else None
        if mesh is None:
            raise UserError(f"The reconstructor finished but wrote no .ply/.obj under {self._out_dir}")
        context.scene.platolidar.import_path = mesh
        self.report({"INFO"}, f"Reconstructed in {job.elapsed:.0f} s: {mesh} (Import to load it)")
        return {"FINISHED"}
