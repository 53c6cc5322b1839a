"""platolidar: author, simulate, reconstruct and import single-view two-bounce lidar in Blender.

Extension main module (manifest: blender_manifest.toml at the repository root; the zip
is built by addon/build_zip.py). Classes are registered from each module's ``classes``
tuple, in order; unregistered in reverse.
"""

from __future__ import annotations

import bpy

from . import _project

_project.ensure_importable()  # pipeline.config and torch_recon.contract.units, vendored or from the checkout

from . import config_io, draw_spots, jobs, operators, panels, preferences, props  # noqa: E402

_CLASSES = (*props.classes, *preferences.classes, *operators.classes, *panels.classes)


def register():
    for cls in _CLASSES:
        bpy.utils.register_class(cls)
    props.register_properties()
    config_io.register_handlers()
    draw_spots.register_drawing()


def unregister():
    jobs.cancel_all()  # no orphaned background Blender or Python when the add-on goes away
    draw_spots.unregister_drawing()
    config_io.unregister_handlers()
    props.unregister_properties()
    for cls in reversed(_CLASSES):
        bpy.utils.unregister_class(cls)
