"""Fixtures and helpers for the add-on tests (tests/addon/test_addon_*.py): a reset Blender with the
add-on enabled, a small room scene, a recording UILayout stub, and operator-call helpers."""

from __future__ import annotations

import math
import os
import stat
import sys
from pathlib import Path

import bpy
import pytest

REPO = Path(__file__).resolve().parents[2]

import addon_utils  # noqa: E402

ADDON = "addon"  # the package name in a checkout (installed: bl_ext.<repo>.platolidar)


def enable_addon():
    mod = addon_utils.enable(ADDON, default_set=True)
    assert mod is not None, "the add-on failed to enable"
    return mod


def disable_addon():
    addon_utils.disable(ADDON, default_set=True)


@pytest.fixture
def blank():
    """Factory-empty Blender with the add-on enabled."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    enable_addon()
    yield bpy.context.scene
    disable_addon()


def _mesh_object(name, verts, faces, coll):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.update()
    obj = bpy.data.objects.new(name, me)
    coll.objects.link(obj)
    return obj


def box(name, centre, half, coll):
    cx, cy, cz = centre
    hx, hy, hz = half
    v = [(cx + sx * hx, cy + sy * hy, cz + sz * hz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return _mesh_object(name, v, f, coll)


def build_room(scene):
    """Floor (z=0), back wall (y=3), a 1 m box at (0, 1, 0.5); a camera at (0, -3, 1.5) looking along +Y."""
    coll = scene.collection
    _mesh_object("Floor", [(-4, -5, 0), (4, -5, 0), (4, 3, 0), (-4, 3, 0)], [(0, 1, 2, 3)], coll)
    _mesh_object("Wall", [(-4, 3, 0), (4, 3, 0), (4, 3, 4), (-4, 3, 4)], [(0, 1, 2, 3)], coll)
    box("Box", (0.0, 1.0, 0.5), (0.5, 0.5, 0.5), coll)
    cam = bpy.data.objects.new("LidarCam", bpy.data.cameras.new("LidarCam"))
    cam.location = (0.0, -3.0, 1.5)
    cam.rotation_euler = (math.radians(90.0), 0.0, 0.0)
    coll.objects.link(cam)
    scene.camera = cam
    bpy.context.view_layer.update()
    return cam


@pytest.fixture
def room(blank):
    """The room scene with the add-on enabled; the lidar camera chosen in the panel."""
    scene = blank
    cam = build_room(scene)
    scene.platolidar.camera = cam
    s = scene.platolidar
    s.width = s.height = 16
    return scene


def call(op, **kw):
    """Run an operator: (result set, error text or None). A Python traceback fails the test."""
    try:
        return op(**kw), None
    except RuntimeError as exc:
        msg = str(exc)
        assert "Traceback" not in msg, f"unhandled exception in the operator:\n{msg}"
        return {"CANCELLED"}, msg


def expect_error(op, fragment: str, **kw):
    """The operator reports an error containing `fragment` (CANCELLED), never a traceback."""
    res, err = call(op, **kw)
    assert err is not None, f"expected an error report containing {fragment!r}, got {res}"
    assert fragment.lower() in err.lower(), err
    return err


def set_prefs(**values):
    prefs = bpy.context.preferences.addons[ADDON].preferences
    for k, v in values.items():
        setattr(prefs, k, v)
    return prefs


def fake_executable(path: Path, body: str) -> Path:
    """A runnable script (this Python) standing in for Blender or an external Python."""
    path.write_text(f"#!{sys.executable}\n{body}")
    path.chmod(path.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)
    return path


# -- recording layout --------------------------------------------------------------------------


def _operator_rna(idname):
    """The operator's RNA type; bpy.ops makes a stub for any name, so ask for the registered type."""
    mod, name = idname.split(".")
    try:
        return getattr(getattr(bpy.ops, mod), name).get_rna_type()
    except KeyError:
        raise AssertionError(f"no operator {idname}") from None


class _OpProps:
    """What layout.operator() returns: setting a property checks that the operator has it."""

    def __init__(self, idname, log):
        self._idname, self._log = idname, log
        self._props = set(_operator_rna(idname).properties.keys())

    def __setattr__(self, key, value):
        if key.startswith("_"):
            return object.__setattr__(self, key, value)
        assert key in self._props, f"operator {self._idname} has no property {key!r}"
        self._log.append(("op_prop", self._idname, key))


def _check_call(method: str, kw: dict):
    """Keyword arguments and icon names as the real UILayout method accepts them (a bad icon is a
    TypeError in Blender's draw, which leaves the panel empty)."""
    fn = bpy.types.UILayout.bl_rna.functions[method]
    params = set(fn.parameters.keys())
    assert set(kw) <= params, f"UILayout.{method}() has no argument(s) {sorted(set(kw) - params)}"
    if "icon" in kw:
        icons = fn.parameters["icon"].enum_items.keys()
        assert kw["icon"] in icons, f"unknown icon {kw['icon']!r}"


class RecordingLayout:
    """A UILayout stand-in: records prop/operator/label calls and checks names exist on the data."""

    _ATTRS = {"use_property_split", "use_property_decorate", "active", "enabled", "alert", "scale_x",
              "scale_y", "alignment", "operator_context", "emboss"}

    def __init__(self, log=None):
        object.__setattr__(self, "log", [] if log is None else log)

    def __setattr__(self, key, value):
        assert key in self._ATTRS, f"UILayout has no attribute {key!r}"
        object.__setattr__(self, key, value)

    def row(self, **kw):
        _check_call("row", kw)
        return RecordingLayout(self.log)

    def column(self, **kw):
        _check_call("column", kw)
        return RecordingLayout(self.log)

    def box(self):
        return RecordingLayout(self.log)

    def split(self, **kw):
        _check_call("split", kw)
        return RecordingLayout(self.log)

    def prop(self, data, prop, **kw):
        _check_call("prop", kw)
        assert data is not None, f"prop({prop!r}) drawn from None"
        assert prop in data.bl_rna.properties.keys(), f"{data.bl_rna.identifier} has no property {prop!r}"
        self.log.append(("prop", data.bl_rna.identifier, prop))

    def operator(self, idname, **kw):
        _check_call("operator", kw)
        _operator_rna(idname)
        self.log.append(("operator", idname))
        if not getattr(self, "enabled", True):  # greyed out (layout.enabled = False)
            self.log.append(("disabled", idname))
        return _OpProps(idname, self.log)

    def label(self, text="", **kw):
        _check_call("label", kw)
        assert isinstance(text, str)
        self.log.append(("label", text))

    def separator(self, **kw):
        _check_call("separator", kw)
        self.log.append(("separator",))

    def progress(self, factor=0.0, type="BAR", text=""):
        assert type in bpy.types.UILayout.bl_rna.functions["progress"].parameters["type"].enum_items.keys()
        assert 0.0 <= factor <= 1.0
        self.log.append(("progress", factor, text))

    def template_list(self, listtype, list_id, dataptr, propname, active_dataptr, active_propname, **kw):
        _check_call("template_list", kw)
        assert hasattr(bpy.types, listtype), f"no UIList {listtype}"
        for data, name in ((dataptr, propname), (active_dataptr, active_propname)):
            assert name in data.bl_rna.properties.keys(), f"{data.bl_rna.identifier} has no property {name!r}"
        self.log.append(("template_list", listtype, propname))


def draw_panel(panel_cls, context=None):
    """Run a Panel's draw() against a RecordingLayout; returns the log."""
    from types import SimpleNamespace

    layout = RecordingLayout()
    panel_cls.draw(SimpleNamespace(layout=layout), context or bpy.context)
    return layout.log


def env_without_torch_python() -> str | None:
    """A Python on this machine that has no torch (the system one), for the bad-environment test."""
    import subprocess
    for cand in ("/usr/bin/python3", "/usr/local/bin/python3"):
        if os.path.isfile(cand):
            r = subprocess.run([cand, "-c", "import torch"], capture_output=True)
            if r.returncode != 0:
                return cand
    return None
