"""Laser rays in the 3D View: laser origin -> each spot, with a cross at the spot (gpu module).

Nothing is drawn or registered in background mode (no GPU context there); the geometry
(``ray_segments``) is plain Python so tests check it without a GPU.
"""

from __future__ import annotations

import bpy
from mathutils import Vector

from .spot_geometry import SpotError, laser_origin

COLOURS = {"active": (1.0, 0.85, 0.1, 1.0), "enabled": (1.0, 0.15, 0.1, 0.9), "advised": (0.1, 0.75, 1.0, 0.9),
           "disabled": (0.55, 0.55, 0.55, 0.5)}
CROSS_FRACTION = 0.015  # cross half-size as a fraction of the ray length: visible at any scene scale

_handle = None


def ray_segments(scene) -> dict[str, list[tuple]]:
    """Line-segment vertex lists (pairs) per style: 'active', 'enabled', 'advised' (enabled, from Advise Spots),
    'disabled'."""
    s = scene.platolidar
    out = {k: [] for k in COLOURS}
    if not len(s.spots):
        return out
    origin = laser_origin(scene)
    for i, sp in enumerate(s.spots):
        style = "active" if i == s.active_spot_index else (
            "disabled" if not sp.enabled else "advised" if sp.advised else "enabled")
        t = Vector(sp.target)
        r = max(1e-3, CROSS_FRACTION * (t - origin).length)
        segs = [origin, t]
        for axis in (Vector((r, 0, 0)), Vector((0, r, 0)), Vector((0, 0, r))):
            segs += [t - axis, t + axis]
        out[style].extend(tuple(v) for v in segs)
    return out


def _draw():
    import gpu
    from gpu_extras.batch import batch_for_shader

    context = bpy.context
    s = getattr(context.scene, "platolidar", None)
    if s is None or not s.show_rays or not len(s.spots):
        return
    try:
        groups = ray_segments(context.scene)
    except SpotError:
        return  # no camera / laser object yet: nothing to draw from
    shader = gpu.shader.from_builtin("POLYLINE_UNIFORM_COLOR")
    region = context.region
    shader.uniform_float("viewportSize", (region.width, region.height))
    shader.uniform_float("lineWidth", 2.0)
    gpu.state.blend_set("ALPHA")
    gpu.state.depth_test_set("LESS_EQUAL")
    for style in ("disabled", "enabled", "advised", "active"):
        coords = groups[style]
        if coords:
            shader.uniform_float("color", COLOURS[style])
            batch_for_shader(shader, "LINES", {"pos": coords}).draw(shader)
    gpu.state.depth_test_set("NONE")
    gpu.state.blend_set("NONE")


def register_drawing():
    global _handle
    if bpy.app.background or _handle is not None:
        return
    _handle = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")


def unregister_drawing():
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, "WINDOW")
        _handle = None
