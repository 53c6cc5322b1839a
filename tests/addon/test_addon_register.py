"""Register / unregister round trips and what registration provides."""

import bpy

from tests.support.addon_fixtures import ADDON, disable_addon, enable_addon

import addon
from addon import config_io, operators, panels


def _our_operator_ids():
    return [cls.bl_idname for cls in operators.classes]


def test_register_unregister_twice():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for _ in range(2):
        enable_addon()
        assert hasattr(bpy.types.Scene, "platolidar")
        assert bpy.context.scene.platolidar.bins == 391
        assert ADDON in bpy.context.preferences.addons
        for idname in _our_operator_ids():
            mod, name = idname.split(".")
            assert hasattr(getattr(bpy.ops, mod), name)
            getattr(getattr(bpy.ops, mod), name).get_rna_type()
        assert any(config_io._ours(h) for h in bpy.app.handlers.save_pre)
        disable_addon()
        assert not hasattr(bpy.types.Scene, "platolidar")
        assert not any(config_io._ours(h) for h in bpy.app.handlers.save_pre)
        for cls in panels.classes:
            assert not getattr(cls, "is_registered", False)


def test_direct_register_unregister_round_trip():
    """addon.register()/unregister() as Blender calls them, twice, leaving nothing behind."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for _ in range(2):
        addon.register()
        assert bpy.context.scene.platolidar.width == 512
        addon.unregister()
        assert not hasattr(bpy.types.Scene, "platolidar")


def test_operator_ids_are_ours_and_each_has_poll():
    ids = _our_operator_ids()
    assert len(ids) == len(set(ids))
    for cls in operators.classes:
        assert cls.bl_idname.startswith("platolidar."), cls.bl_idname
        assert not cls.bl_idname.startswith("wm."), cls.bl_idname
        assert any("poll" in vars(b) for b in cls.__mro__ if b.__module__.startswith(ADDON)), cls
    for cls in panels.classes:
        if issubclass(cls, bpy.types.Panel):
            assert cls.bl_category == "Lidar" and cls.bl_space_type == "VIEW_3D" and cls.bl_region_type == "UI"


def test_operators_on_lidar_settings_share_one_poll():
    """Every operator acting on the scene's settings polls through the one NeedsLidarSettings mixin."""
    from addon.operators._common import NeedsLidarSettings

    bpy.ops.wm.read_factory_settings(use_empty=True)
    enable_addon()
    try:
        users = [cls for cls in operators.classes if issubclass(cls, NeedsLidarSettings)]
        assert len(users) >= 10
        for cls in users:
            assert "poll" not in vars(cls), f"{cls.__name__} repeats the poll"
            assert getattr(bpy.ops.platolidar, cls.bl_idname.split(".")[1]).poll(), cls.bl_idname
    finally:
        disable_addon()
