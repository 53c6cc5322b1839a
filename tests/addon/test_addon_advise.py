"""Advise Spots in the add-on: the advise-spots job on the scene's last fast fit, its advice turned into
spot targets marked as advised; bad states and bad advice are one-line errors that add nothing.
A fake reconstruction Python writes a given advice JSON (a real fit takes minutes: the slow chain test in
test_addon_pipeline.py runs the real advisor)."""

import json

import bpy
import pytest
from mathutils import Vector

from tests.support.addon_fixtures import (blank, call, draw_panel, expect_error, fake_executable,  # noqa: F401
                                          room, set_prefs)

from addon import jobs, panels

#: writes the JSON in $FAKE_ADVICE (verbatim text) to --out, or fails with $FAKE_FAIL
FAKE_ADVISE_PYTHON = r'''
import os, sys
if sys.argv[1] == "-c":
    print("OK torch 2.13.0 cpu"); sys.exit(0)
assert sys.argv[1:4] == ["-m", "torch_recon", "advise-spots"], sys.argv
if os.environ.get("FAKE_FAIL"):
    print("platolidar: error: fitted to other data than the dataset", flush=True); sys.exit(2)
open(sys.argv[sys.argv.index("--out") + 1], "w").write(os.environ["FAKE_ADVICE"])
print("advice ->", sys.argv[sys.argv.index("--out") + 1], flush=True)
if os.environ.get("FAKE_SLEEP"):
    import time; time.sleep(float(os.environ["FAKE_SLEEP"]))
'''

#: on the room scene (tests/support/addon_fixtures.build_room): the box's front face (y = 0.5), the wall
FRONT, WALL = [0.2, 0.5, 0.6], [1.5, 3.0, 2.0]


def _advice(points, existing=((0.0, 0.5, 0.5),), notes=()):
    """The advisor's JSON as Advice.to_json writes it (only the fields the add-on reads matter)."""
    return json.dumps({"advised": [{"point": list(p), "pixel": [3, 4], "voxels_reached": 10,
                                    "expected_voxels_carved": 5.0} for p in points],
                       "existing": [list(p) for p in existing], "hull_voxels": 100,
                       "hull_voxels_reached_by_existing": 0, "voxel_m": 0.02, "spot_list": "", "notes": list(notes)})


def _fast_fit(folder, mode="fast"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "fit.json").write_text(json.dumps({"settings": {"mode": mode}}))
    (folder / "volume.npz").write_bytes(b"")
    return folder


@pytest.fixture
def advised_room(room, tmp_path, monkeypatch):
    """The room with one listed spot, a dataset, a fast fit in the Reconstruct output folder, the fake Python."""
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    s = room.platolidar
    (tmp_path / "ds").mkdir()
    (tmp_path / "ds" / "dataset.json").write_text("{}")
    s.recon_dataset_dir = str(tmp_path / "ds")
    s.recon_out_dir = str(_fast_fit(tmp_path / "fit"))
    set_prefs(python_path=str(fake_executable(tmp_path / "python", FAKE_ADVISE_PYTHON)))
    monkeypatch.setenv("FAKE_ADVICE", _advice([FRONT, WALL]))
    return room


def _names(scene):
    return [sp.name for sp in scene.platolidar.spots]


def test_advised_points_become_marked_spots(advised_room, tmp_path):
    s = advised_room.platolidar
    s.advise_add, s.advise_beyond_view_deg = 2, 30.0
    res, err = call(bpy.ops.platolidar.advise_spots)
    assert err is None and res == {"FINISHED"}, err
    assert _names(advised_room) == ["Spot 01", "Advised 01", "Advised 02"]
    assert [sp.advised for sp in s.spots] == [False, True, True]
    for sp, p in zip(s.spots[1:], (FRONT, WALL)):
        assert sp.enabled and tuple(sp.target) == pytest.approx(p, abs=1e-4)
    # the advice is kept next to the fit
    assert json.loads((tmp_path / "fit" / "advice.json").read_text())["advised"][0]["point"] == FRONT
    # the re-simulation gets them: the exported settings list all three spots
    res, err = call(bpy.ops.platolidar.export_config, filepath=str(tmp_path / "settings.json"))
    assert err is None, err
    spots = json.loads((tmp_path / "settings.json").read_text())["spots"]
    assert [sp["name"] for sp in spots] == ["Spot 01", "Advised 01", "Advised 02"]
    assert spots[2]["target"] == pytest.approx(WALL, abs=1e-4)
    # and the mark comes back with the names when those settings are loaded
    s.spots.clear()
    res, err = call(bpy.ops.platolidar.load_config, filepath=str(tmp_path / "settings.json"))
    assert err is None, err
    assert [(sp.name, sp.advised) for sp in s.spots] == [("Spot 01", False), ("Advised 01", True),
                                                         ("Advised 02", True)]


def test_the_spot_goes_where_the_laser_aimed_at_the_advised_point_lands(advised_room, monkeypatch):
    """As Add Spot at Cursor: the advised point (the fit's surface, a bit inside the box here) only aims."""
    inside = (0.2, 0.53, 0.6)
    monkeypatch.setenv("FAKE_ADVICE", _advice([inside]))
    res, err = call(bpy.ops.platolidar.advise_spots)
    assert err is None, err
    target = Vector(advised_room.platolidar.spots[-1].target)
    origin = advised_room.platolidar.camera.location
    assert target.y == pytest.approx(0.5, abs=1e-4)  # on the box's front face
    assert (target - origin).normalized().dot((Vector(inside) - origin).normalized()) == pytest.approx(1.0, abs=1e-6)


def test_random_spots_of_the_dataset_are_listed_with_the_advice(advised_room, monkeypatch):
    s = advised_room.platolidar
    s.spots.clear()
    s.spot_source = "RANDOM"
    monkeypatch.setenv("FAKE_ADVICE", _advice([FRONT], existing=[(0.0, 0.5, 0.5), (-1.0, 3.0, 1.0)]))
    res, err = call(bpy.ops.platolidar.advise_spots)
    assert err is None, err
    assert s.spot_source == "LIST"
    assert _names(advised_room) == ["Spot 01", "Spot 02", "Advised 01"]
    assert tuple(s.spots[1].target) == pytest.approx((-1.0, 3.0, 1.0), abs=1e-4)


@pytest.mark.parametrize("text,fragment", [
    ("{not json", "not the advice json"),
    ('{"spots": []}', "'advised' list"),
    (json.dumps({"advised": [{"point": [0.0, 0.5]}]}), "advised[0].point"),
    (json.dumps({"advised": [{"point": [0.0, "NaN", 1.0]}]}), "advised[0].point"),
    ('{"advised": [{"point": [0.2, 0.5, NaN]}]}', "advised[0].point"),
    (_advice([]), "no spot advised")])
def test_bad_advice_is_one_line_and_adds_nothing(advised_room, monkeypatch, text, fragment):
    monkeypatch.setenv("FAKE_ADVICE", text)
    err = expect_error(bpy.ops.platolidar.advise_spots, fragment)
    assert "\n" not in err.strip()
    assert _names(advised_room) == ["Spot 01"]


def test_advice_hitting_nothing_adds_nothing(advised_room, monkeypatch):
    monkeypatch.setenv("FAKE_ADVICE", _advice([(0.0, -20.0, 8.0)]))  # behind the camera, up: leaves the room
    expect_error(bpy.ops.platolidar.advise_spots, "hits nothing")
    assert _names(advised_room) == ["Spot 01"]


def test_failed_job_adds_nothing_and_keeps_no_old_advice(advised_room, tmp_path, monkeypatch):
    (tmp_path / "fit" / "advice.json").write_text(_advice([FRONT]))  # an earlier run's advice
    monkeypatch.setenv("FAKE_FAIL", "1")
    err = expect_error(bpy.ops.platolidar.advise_spots, "exit code 2")
    assert "fitted to other data" in err
    assert _names(advised_room) == ["Spot 01"]
    assert not (tmp_path / "fit" / "advice.json").exists()


def test_missing_or_wrong_fit_is_one_line(advised_room, tmp_path):
    s = advised_room.platolidar
    s.recon_out_dir = str(tmp_path / "nothing")
    err = expect_error(bpy.ops.platolidar.advise_spots, "no fast fit")
    assert "Reconstruct with Mode Fast" in err and "\n" not in err.strip()
    s.recon_out_dir = str(_fast_fit(tmp_path / "nerf", mode="platonerf"))
    expect_error(bpy.ops.platolidar.advise_spots, "mode 'platonerf'")
    s.recon_out_dir = str(tmp_path / "fit")
    running = jobs.Job("reconstruction", ["true"])  # a fit being rewritten is not read
    jobs.set_active(running, "reconstruction")
    try:
        expect_error(bpy.ops.platolidar.advise_spots, "reconstruction is running")
    finally:
        jobs.set_active(None, "reconstruction")
    s.recon_dataset_dir, s.output_dir = str(tmp_path / "no-dataset"), ""
    expect_error(bpy.ops.platolidar.advise_spots, "not a dataset")
    assert _names(advised_room) == ["Spot 01"]


def test_cancelled_job_adds_nothing(advised_room, tmp_path, monkeypatch):
    """Cancelled after the advice was written (the user's Esc, here from the job's poll): nothing added."""
    monkeypatch.setenv("FAKE_SLEEP", "60")
    poll = jobs.Job.poll

    def cancel_once_written(job):
        if not job.cancelled and any("advice ->" in line for line in job.lines):
            job.cancel(grace=1.0)
        return poll(job)

    monkeypatch.setattr(jobs.Job, "poll", cancel_once_written)
    res, err = call(bpy.ops.platolidar.advise_spots)
    assert res == {"CANCELLED"} and err is None
    assert (tmp_path / "fit" / "advice.json").is_file() and _names(advised_room) == ["Spot 01"]


def test_command_parses_with_the_real_cli():
    import argparse

    from torch_recon.commands.advise_spots import register
    from torch_recon.contract.settings import from_args
    from torch_recon.recon.spot_advice import AdviceSettings

    cmd = jobs.advise_command("py", "/d", "/f", "/f/advice.json", 3, 12.5, "cpu")
    assert cmd[1:4] == ["-m", "torch_recon", "advise-spots"]
    ap = argparse.ArgumentParser()
    register(ap.add_subparsers())
    args = ap.parse_args(cmd[3:])
    s = from_args(AdviceSettings, args)
    assert (args.dataset, args.fit_dir, args.out) == ("/d", "/f", "/f/advice.json")
    assert (s.add, s.beyond_view_deg, s.device) == (3, 12.5, "cpu")


def test_panel_settings_match_the_advisor(blank):
    """The panel's defaults and limits are the advisor's (which imports torch, so Blender cannot read them)."""
    from torch_recon.recon.spot_advice import AdviceSettings

    props = blank.platolidar.bl_rna.properties
    a = AdviceSettings()
    assert props["advise_add"].default == a.add and props["advise_beyond_view_deg"].default == a.beyond_view_deg
    lo, hi = AdviceSettings.SETTINGS_META["beyond_view_deg"]["range"]
    assert (props["advise_beyond_view_deg"].hard_min, props["advise_beyond_view_deg"].hard_max) == (lo, hi)
    assert props["advise_add"].hard_min == AdviceSettings.SETTINGS_META["add"]["range"][0]


def test_panel_button_needs_a_fast_fit_and_advised_rows_are_marked(advised_room, tmp_path):
    s = advised_room.platolidar
    log = draw_panel(panels.PLATOLIDAR_PT_spots)
    assert ("operator", "platolidar.advise_spots") in log and ("disabled", "platolidar.advise_spots") not in log
    assert {("prop", "PLATOLIDAR_PG_settings", "advise_add"),
            ("prop", "PLATOLIDAR_PG_settings", "advise_beyond_view_deg")} <= set(log)
    s.recon_out_dir = str(tmp_path / "nothing")
    assert ("disabled", "platolidar.advise_spots") in draw_panel(panels.PLATOLIDAR_PT_spots)
    s.recon_out_dir = "//unsaved_relative"  # the panel never raises on a path it cannot resolve
    assert ("disabled", "platolidar.advise_spots") in draw_panel(panels.PLATOLIDAR_PT_spots)
    # the tooltip (the operator's docstring) says what it does
    assert "fast fit" in bpy.ops.platolidar.advise_spots.get_rna_type().description
    s.recon_out_dir = str(tmp_path / "fit")
    assert call(bpy.ops.platolidar.advise_spots)[1] is None
    from tests.support.addon_fixtures import RecordingLayout
    for sp, marked in ((s.spots[0], False), (s.spots[1], True)):
        layout = RecordingLayout()
        panels.PLATOLIDAR_UL_spots.draw_item(None, bpy.context, layout, s, sp, 0, s, "active_spot_index", 0)
        assert (("label", "") in layout.log) == marked


def test_advised_rays_have_their_own_colour(advised_room):
    from addon import draw_spots

    call(bpy.ops.platolidar.advise_spots)
    advised_room.platolidar.active_spot_index = 0
    segs = draw_spots.ray_segments(advised_room)
    assert len(segs["advised"]) == 2 * 8 and len(segs["active"]) == 8 and segs["enabled"] == []


def test_operator_registered_under_the_prefix(blank):
    from addon import operators

    assert "platolidar.advise_spots" in [c.bl_idname for c in operators.classes]
    assert bpy.ops.platolidar.advise_spots.poll()


def test_running_advice_shows_progress_and_the_cancel_button_stops_it(blank):
    import sys

    job = jobs.Job("advice", [sys.executable, "-c", "import time; time.sleep(60)"]).start()
    jobs.set_active(job, "advice")
    try:
        log = draw_panel(panels.PLATOLIDAR_PT_spots)
        assert ("op_prop", "platolidar.cancel_job", "kind") in log and ("operator", "platolidar.advise_spots") not in log
        res, err = call(bpy.ops.platolidar.cancel_job, kind="advice")
        assert err is None and res == {"FINISHED"} and job.cancelled
    finally:
        job.cancel(grace=1.0)
        jobs.set_active(None, "advice")
