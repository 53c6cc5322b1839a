"""Advise Spots: `python -m torch_recon advise-spots DATASET FIT_DIR --out FIT_DIR/advice.json` as a job,
then the advised points become spot targets, aimed like *Add Spot at Cursor* and marked as advised.

The advisor (torch_recon/recon/spot_advice.py) reads the last fast fit (the Reconstruct output folder)
and its dataset (Reconstruct's dataset, else the simulation's) and picks the spots whose light would
cross the space that only shadows bound. The user re-simulates with the longer list.
"""

import json
import math
import os

import bpy
from mathutils import Vector

from .. import jobs
from ..spot_geometry import SpotError, add_spot, aim_laser
from ._common import NeedsLidarSettings, UserError, dataset_dir, reconstruction_python, resolve_path
from ._job_base import JobOperatorMixin

ADVICE_FILE = "advice.json"   # written into the fit folder (replaced on every run)
FIT_FILES = ("fit.json", "volume.npz")


def fit_problem(fit_dir: str) -> str | None:
    """None when `fit_dir` holds a fast fit (what the advisor reads), else what is missing and what to do."""
    missing = [n for n in FIT_FILES if not os.path.isfile(os.path.join(fit_dir, n))]
    if missing:
        return (f"No fast fit in '{fit_dir}' (no {' or '.join(missing)}): Reconstruct with Mode Fast first, "
                "or set the Reconstruct Output Folder to a fit's folder")
    try:
        with open(os.path.join(fit_dir, "fit.json")) as f:
            mode = (json.load(f).get("settings") or {}).get("mode")
    except (OSError, ValueError, AttributeError) as exc:
        return f"'{os.path.join(fit_dir, 'fit.json')}' is unreadable ({exc}): Reconstruct with Mode Fast again"
    if mode != "fast":
        return (f"The fit in '{fit_dir}' is mode {mode!r}: Advise Spots needs a Fast fit "
                "(Reconstruct with Mode Fast)")
    return None


def last_fit_dir(context) -> str | None:
    """The Reconstruct output folder when it holds a fast fit (for the panel: never raises)."""
    try:
        fit_dir = resolve_path(context.scene.platolidar.recon_out_dir, "reconstruction output folder", context)
    except UserError:
        return None
    return fit_dir if fit_problem(fit_dir) is None else None


def _point(value, where: str) -> tuple:
    if not (isinstance(value, list) and len(value) == 3 and all(isinstance(v, (int, float)) for v in value)
            and all(math.isfinite(v) for v in value)):
        raise ValueError(f"{where}: expected [x, y, z] finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def read_advice(path: str) -> dict:
    """{'advised': [(x, y, z), ...], 'existing': [...], 'voxel_m': float, 'notes': [str]} from the advisor's
    JSON (Advice.to_json); UserError naming the file and the first bad entry."""
    try:
        with open(path) as f:
            raw = json.load(f)
        if not isinstance(raw, dict) or not isinstance(raw.get("advised"), list):
            raise ValueError("expected an object with an 'advised' list")
        advised = [_point(a.get("point") if isinstance(a, dict) else None, f"advised[{i}].point")
                   for i, a in enumerate(raw["advised"])]
        existing = [_point(p, f"existing[{i}]") for i, p in enumerate(raw.get("existing") or [])]
        voxel_m = float(raw.get("voxel_m") or 0.0)
        notes = [str(n) for n in raw.get("notes") or []]
    except OSError as exc:
        raise UserError(f"The advisor wrote no readable {path}: {exc.strerror or exc}") from None
    except (ValueError, TypeError, AttributeError) as exc:
        raise UserError(f"'{path}' is not the advice JSON of advise-spots: {exc}") from None
    return {"advised": advised, "existing": existing, "voxel_m": voxel_m, "notes": notes}


class PLATOLIDAR_OT_advise_spots(NeedsLidarSettings, JobOperatorMixin, bpy.types.Operator):
    """Add laser spots where the last fast fit says new light is most needed: their light would cross space
    that only shadows bound (advise-spots in the reconstruction Python; Esc cancels). Re-simulate afterwards"""

    bl_idname = "platolidar.advise_spots"
    bl_label = "Advise Spots"
    bl_options = {"REGISTER", "UNDO"}

    job_kind = "advice"

    def build_job(self, context):
        s = context.scene.platolidar
        if jobs.active("reconstruction") is not None:  # it rewrites the fit the advisor would read
            raise UserError("A reconstruction is running: advise spots once it has finished")
        fit_dir = resolve_path(s.recon_out_dir, "reconstruction output folder", context)
        problem = fit_problem(fit_dir)
        if problem:
            raise UserError(problem)
        dataset = dataset_dir(context, ": Advise Spots needs the dataset the fit was made from")
        python, paths = reconstruction_python(context)
        self._advice = os.path.join(fit_dir, ADVICE_FILE)
        try:
            if os.path.isfile(self._advice):
                os.remove(self._advice)  # an older advice must never be read as this run's
        except OSError as exc:
            raise UserError(f"Cannot replace the earlier advice {self._advice}: {exc.strerror or exc}") from None
        cmd = jobs.advise_command(python, dataset, fit_dir, self._advice, s.advise_add, s.advise_beyond_view_deg,
                                  s.recon_device)
        return jobs.Job("advice", cmd, env=jobs.python_env(paths))

    def finish(self, context, job):
        advice = read_advice(self._advice)
        if not advice["advised"]:
            raise UserError("No spot advised: " + ("; ".join(advice["notes"]) or "the advisor found none"))
        scene = context.scene
        s = scene.platolidar
        # spots drawn at random by the simulator are listed too, so the re-simulation keeps them
        keep = advice["existing"] if s.spot_source == "RANDOM" else []
        wanted = [(False, p) for p in keep] + [(True, p) for p in advice["advised"]]
        depsgraph = context.evaluated_depsgraph_get()
        try:   # every ray first: nothing is added when the laser origin is missing
            hits = [aim_laser(scene, depsgraph, p) for _, p in wanted]
        except SpotError as exc:
            raise UserError(str(exc)) from None
        if all(h is None for (advised, _), h in zip(wanted, hits) if advised):
            raise UserError(f"The laser aimed at the {len(advice['advised'])} advised point(s) hits nothing in "
                            "this scene: did the scene change since the simulation?")
        far = max(0.01, 2.0 * advice["voxel_m"])   # the fit's surface lies about a voxel from the true one
        added = []
        for (advised, p), hit in zip(wanted, hits):
            what = "Advised point" if advised else "Dataset spot"
            if hit is None:
                self.report({"WARNING"}, f"{what} ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) skipped: the laser aimed "
                                         "at it hits nothing in this scene")
                continue
            sp = add_spot(scene, hit, advised=advised)
            miss = (hit - Vector(p)).length
            if advised:
                added.append(sp.name)
            if miss > far:
                self.report({"WARNING"}, f"{sp.name}: the laser lands {miss:.3f} m from the {what.lower()} "
                                         "(the fit's surface is off there, or the scene changed)")
        if keep:
            s.spot_source = "LIST"
            self.report({"INFO"}, f"Listed the dataset's {len(keep)} random spots, so the re-simulation keeps them")
        self.report({"INFO"}, f"Added {len(added)} advised spots ({', '.join(added)}) in {job.elapsed:.0f} s: "
                              "simulate again to measure them")
        return {"FINISHED"}
