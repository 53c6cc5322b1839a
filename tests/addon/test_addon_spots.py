"""Spot operators on a built scene, including bad states, and the laser-ray geometry."""

import bpy
import pytest
from mathutils import Vector

from tests.support.addon_fixtures import blank, call, expect_error, room  # noqa: F401 (fixtures)

from addon import draw_spots
from addon.operators.add_spot_click import spot_from_view_ray
from addon.spot_geometry import SpotError


def test_add_spot_at_cursor_lands_on_the_box(room):
    room.cursor.location = (0.0, 0.5, 0.5)  # front face of the box is at y = 0.5
    res, err = call(bpy.ops.platolidar.add_spot_cursor)
    assert err is None and res == {"FINISHED"}
    sp = room.platolidar.spots[0]
    assert sp.enabled and sp.name == "Spot 01"
    assert sp.target[1] == pytest.approx(0.5, abs=1e-4)  # on the box face, along the laser ray
    origin = Vector((0.0, -3.0, 1.5))
    d1 = (Vector(sp.target) - origin).normalized()
    d2 = (Vector((0.0, 0.5, 0.5)) - origin).normalized()
    assert d1.dot(d2) == pytest.approx(1.0, abs=1e-6)


def test_add_spot_at_cursor_bad_states(room):
    room.cursor.location = (0.0, -10.0, 5.0)  # behind and above the camera: the ray leaves the room
    expect_error(bpy.ops.platolidar.add_spot_cursor, "hits nothing")
    room.cursor.location = room.platolidar.camera.location
    expect_error(bpy.ops.platolidar.add_spot_cursor, "coincides")
    room.platolidar.camera = None
    room.camera = None
    room.cursor.location = (0.0, 0.5, 0.5)
    expect_error(bpy.ops.platolidar.add_spot_cursor, "no lidar camera")
    assert len(room.platolidar.spots) == 0


def test_laser_object_origin_skips_its_own_mesh(room):
    from tests.support.addon_fixtures import box
    laser = box("Laser", (0.0, 0.0, 0.0), (0.05, 0.05, 0.05), room.collection)  # the laser's housing
    laser.location = (1.0, -3.0, 1.5)
    s = room.platolidar
    s.laser_mode = "OBJECT"
    s.laser_object = laser
    bpy.context.view_layer.update()
    room.cursor.location = (1.0, 3.0, 1.5)
    res, err = call(bpy.ops.platolidar.add_spot_cursor)
    assert err is None
    assert tuple(s.spots[0].target) == pytest.approx((1.0, 3.0, 1.5), abs=1e-4)
    s.laser_object = None
    expect_error(bpy.ops.platolidar.add_spot_cursor, "no laser object")


def test_click_core_and_scripted_click(room):
    cam = room.platolidar.camera
    # a view ray from the camera through the image centre hits the box front face
    sp = spot_from_view_ray(bpy.context, cam.location, (0.0, 1.0, -0.25))
    assert sp.target[1] == pytest.approx(0.5, abs=1e-4)
    res, err = call(bpy.ops.platolidar.add_spot_click, view_origin=(0, -3, 1.5), view_direction=(0, 1, 0))
    assert err is None and len(room.platolidar.spots) == 2
    expect_error(bpy.ops.platolidar.add_spot_click, "no surface", view_origin=(0, -3, 1.5),
                 view_direction=(0, -1, 0))
    expect_error(bpy.ops.platolidar.add_spot_click, "zero-length", view_origin=(0, -3, 1.5),
                 view_direction=(0, 0, 0))
    with pytest.raises(SpotError):
        spot_from_view_ray(bpy.context, (0, -3, 1.5), (0, 0, 1))


def test_remove_spot(room):
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    call(bpy.ops.platolidar.add_spot_cursor)
    assert [sp.name for sp in room.platolidar.spots] == ["Spot 01", "Spot 02"]
    room.platolidar.active_spot_index = 0
    assert call(bpy.ops.platolidar.remove_spot)[0] == {"FINISHED"}
    assert [sp.name for sp in room.platolidar.spots] == ["Spot 02"]
    call(bpy.ops.platolidar.remove_spot)
    # nothing left: the button is disabled (poll), so a script gets Blender's poll error, not a crash
    assert not bpy.ops.platolidar.remove_spot.poll()


def test_generate_spots_seeded_diverse_and_reachable(room):
    s = room.platolidar
    s.random_candidates, s.random_keep, s.seed = 24, 6, 3
    res, err = call(bpy.ops.platolidar.generate_spots)
    assert err is None and res == {"FINISHED"}
    first = [tuple(sp.target) for sp in s.spots]
    assert len(first) == 6 and len(set(first)) == 6
    call(bpy.ops.platolidar.generate_spots)
    assert [tuple(sp.target) for sp in s.spots] == first  # same seed, same spots
    s.seed = 4
    call(bpy.ops.platolidar.generate_spots)
    assert [tuple(sp.target) for sp in s.spots] != first
    # every spot lies on a surface of the room (floor, wall or box)
    for t in first:
        x, y, z = t
        on_floor, on_wall = abs(z) < 1e-4, abs(y - 3.0) < 1e-4
        on_box = max(abs(x) - 0.5, abs(y - 1.0) - 0.5, abs(z - 0.5) - 0.5) > -1e-4 and \
            max(abs(x), abs(y - 1.0), abs(z - 0.5)) < 0.5 + 1e-4
        assert on_floor or on_wall or on_box, t
    # diversity: kept spots are more spread out than the first 6 candidates would be
    pts = [Vector(t) for t in first]
    min_gap = min((a - b).length for i, a in enumerate(pts) for b in pts[i + 1:])
    assert min_gap > 0.3


def test_generate_spots_bad_states(room):
    s = room.platolidar
    s.random_candidates, s.random_keep = 4, 8
    expect_error(bpy.ops.platolidar.generate_spots, "cannot keep")
    s.random_keep = 2
    cam = s.camera
    cam.location = (0.0, -4.9, 1.5)
    cam.rotation_euler = (1.5707963, 0.0, 3.14159265)  # looking along -Y, out of the open room
    bpy.context.view_layer.update()
    expect_error(bpy.ops.platolidar.generate_spots, "no surface")
    s.camera = None
    room.camera = None
    expect_error(bpy.ops.platolidar.generate_spots, "no lidar camera")


def test_ray_segments_for_drawing(room):
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    room.cursor.location = (1.0, 3.0, 1.0)
    call(bpy.ops.platolidar.add_spot_cursor)
    room.platolidar.spots[0].enabled = False
    segs = draw_spots.ray_segments(room)
    # spot 2 is active (just added); spot 1 disabled; each: 1 ray + 3 cross lines = 8 vertices
    assert len(segs["active"]) == 8 and len(segs["disabled"]) == 8 and segs["enabled"] == []
    assert segs["active"][0] == pytest.approx((0.0, -3.0, 1.5))
    assert segs["active"][1] == pytest.approx(tuple(room.platolidar.spots[1].target))
    assert draw_spots._handle is None  # background mode: no draw handler registered


def _fake_view(cam, width=200, height=100, x=10, y=20):
    """A 3D View whose viewport looks through `cam` (what view3d_utils reads from a real one)."""
    from types import SimpleNamespace as NS
    depsgraph = bpy.context.evaluated_depsgraph_get()
    view = cam.matrix_world.inverted()
    proj = cam.calc_matrix_camera(depsgraph, x=width, y=height)
    rv3d = NS(is_perspective=True, view_matrix=view, perspective_matrix=proj @ view)
    region = NS(type="WINDOW", x=x, y=y, width=width, height=height, data=rv3d)
    sidebar = NS(type="UI", x=x + width, y=y, width=50, height=height, data=None)
    return NS(type="VIEW_3D", regions=[sidebar, region]), region


def test_view_region_under_mouse(room):
    from addon.operators.add_spot_click import view_region_under_mouse
    area, region = _fake_view(room.platolidar.camera)
    assert view_region_under_mouse([area], 110, 70) == (region, (100, 50))
    assert view_region_under_mouse([area], 215, 70) == (None, None)  # on the sidebar
    assert view_region_under_mouse([area], 5, 70) == (None, None)    # outside


def test_click_modal_adds_the_spot_under_the_mouse(room):
    """The modal handler with a recorded window: a click at the viewport centre adds a spot straight
    ahead of the camera (the wall at y = 3); Esc ends it."""
    from types import SimpleNamespace as NS
    from addon.operators.add_spot_click import PLATOLIDAR_OT_add_spot_click as Op
    area, region = _fake_view(room.platolidar.camera)
    calls = []
    window = NS(screen=NS(areas=[area]), cursor_modal_restore=lambda: calls.append("restore"))
    ctx = NS(window=window, area=NS(header_text_set=lambda t: calls.append(("header", t))), scene=room,
             evaluated_depsgraph_get=bpy.context.evaluated_depsgraph_get)
    op = NS(_added=0, reports=[])
    op.report = lambda kind, msg: op.reports.append(msg)
    op._end = lambda context: Op._end(op, context)
    click = NS(type="LEFTMOUSE", value="PRESS", mouse_x=110, mouse_y=70)
    assert Op.modal(op, ctx, click) == {"RUNNING_MODAL"}
    assert tuple(room.platolidar.spots[0].target) == pytest.approx((0.0, 3.0, 1.5), abs=1e-4)
    assert Op.modal(op, ctx, NS(type="LEFTMOUSE", value="PRESS", mouse_x=215, mouse_y=70)) == {"PASS_THROUGH"}
    assert Op.modal(op, ctx, NS(type="MOUSEMOVE", value="NOTHING", mouse_x=0, mouse_y=0)) == {"PASS_THROUGH"}
    assert Op.modal(op, ctx, NS(type="ESC", value="PRESS", mouse_x=0, mouse_y=0)) == {"FINISHED"}
    assert ("header", None) in calls and "restore" in calls and len(room.platolidar.spots) == 1


def test_generate_spots_equals_the_simulators_random_spots(room):
    """Same seed, same spots: the panel's "Generate Spots" and random spots at simulation (one recipe)."""
    import numpy as np

    from addon.config_io import settings_to_config
    from pipeline import blender_scene as bs
    from pipeline.simulator import plan_spots, sensor_spec

    s = room.platolidar
    s.random_candidates, s.random_keep, s.seed = 12, 4, 7
    res, err = call(bpy.ops.platolidar.generate_spots)
    assert err is None and res == {"FINISHED"}
    panel = np.array([tuple(sp.target) for sp in s.spots])
    s.spots.clear()
    s.spot_source = "RANDOM"
    cfg = settings_to_config(room)
    assert cfg.spots == []
    cam = bs.sensor_camera(room, cfg.camera)
    fov, axis = bs.camera_fov(cam, cfg.width, cfg.height)
    c2w = bs.rigid_c2w(cam)
    sensor = sensor_spec(cfg, c2w, fov, axis, c2w[:3, 3])
    plans = plan_spots(cfg, room, bpy.context.evaluated_depsgraph_get(), sensor, keep_requested=False)
    sim = np.array([p.first_bounce for p in plans])
    np.testing.assert_allclose(sim, panel, atol=1e-4)
