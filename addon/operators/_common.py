"""Helpers shared by the operators (not operators themselves)."""

from __future__ import annotations

import os

import bpy

from torch_recon.contract.errors import PlatolidarError

from ..preferences import get_preferences


class UserError(PlatolidarError, RuntimeError):
    """A state the user can fix; operators report it and return CANCELLED."""


def settings_of(context):
    scene = getattr(context, "scene", None)
    return None if scene is None else getattr(scene, "platolidar", None)


def has_settings(cls, context) -> bool:
    """Common poll: a scene with lidar settings (state problems are reported by execute)."""
    if settings_of(context) is None:
        cls.poll_message_set("No scene with lidar settings")
        return False
    return True


class NeedsLidarSettings:
    """Mixin (before bpy.types.Operator) of every operator that acts on the scene's lidar settings."""

    @classmethod
    def poll(cls, context):
        return has_settings(cls, context)


def resolve_path(raw: str, what: str, context=None) -> str:
    """Absolute path from a panel path; '//' paths need a saved .blend or a default output folder."""
    raw = (raw or "").strip()
    if not raw:
        raise UserError(f"No {what} given")
    if raw.startswith("//") and not bpy.data.filepath:
        prefs = get_preferences(context)
        base = bpy.path.abspath(prefs.output_dir) if prefs is not None and prefs.output_dir else ""
        if not base or base.startswith("//"):
            raise UserError(f"{what} '{raw}' is relative to the .blend, which is not saved: save the file, "
                            "choose an absolute folder, or set a Default Output Folder in the preferences")
        return os.path.normpath(os.path.join(base, raw[2:]))
    return os.path.normpath(bpy.path.abspath(raw))


def reconstruction_python(context) -> tuple[str, list]:
    """(python, PYTHONPATH entries) of the reconstruction Python from the preferences, checked to import torch_recon."""
    from .. import _project, jobs

    prefs = get_preferences(context)
    if prefs is None:
        raise UserError("Add-on preferences unavailable: enable the add-on in Preferences > Add-ons")
    python = bpy.path.abspath(prefs.python_path) if prefs.python_path else ""
    paths = _project.reconstruction_pythonpath(prefs.project_dir)
    ok, msg = jobs.check_reconstruction_python(python, paths)
    if not ok:
        raise UserError(msg)
    return python, paths


def dataset_dir(context, hint: str = "") -> str:
    """The panel's dataset folder (Reconstruct's, else the simulation output), checked to hold dataset.json."""
    s = context.scene.platolidar
    dataset = resolve_path(s.recon_dataset_dir or s.output_dir, "dataset folder", context)
    if not os.path.isfile(os.path.join(dataset, "dataset.json")):
        raise UserError(f"'{dataset}' is not a dataset (no dataset.json){hint}")
    return dataset


def validated_config(context, op=None):
    """The scene's settings as a SimulationConfig, checked for a simulation; stored in the .blend.

    Raises UserError; warnings go to `op.report` when given.
    """
    from ..config_io import ConfigError, settings_to_config, store_config_text
    from ..spot_geometry import SpotError, check_spots

    scene = context.scene
    try:
        cfg = settings_to_config(scene, strict=True)
        warnings = check_spots(scene, context.evaluated_depsgraph_get())
    except (ConfigError, SpotError) as exc:
        raise UserError(str(exc)) from None
    store_config_text(cfg)
    if op is not None:
        for w in warnings:
            op.report({"WARNING"}, w)
    return cfg
