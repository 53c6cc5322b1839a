"""Every panel's draw() against a recording UILayout that checks each drawn property and operator."""

from types import SimpleNamespace

import bpy
import pytest

from tests.support.addon_fixtures import ADDON, RecordingLayout, blank, call, draw_panel, room  # noqa: F401 (fixtures)

from addon import jobs, panels, preferences

PANELS = [c for c in panels.classes if issubclass(c, bpy.types.Panel)]


def _props(log):
    return {entry[2] for entry in log if entry[0] == "prop"}


def _ops(log):
    return {entry[1] for entry in log if entry[0] == "operator"}


@pytest.mark.parametrize("panel", PANELS, ids=lambda c: c.__name__)
def test_panels_draw_on_an_empty_scene(blank, panel):
    assert panel.poll(bpy.context)
    log = draw_panel(panel)
    assert log, "nothing drawn"


def test_panels_draw_in_every_branch(room):
    s = room.platolidar
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    seen_props, seen_ops = set(), set()
    for range_mode, laser_mode, bounces, gate, budget in (("BINS", "COLOCATED", 2, False, "STEPS"),
                                                          ("RANGE", "OBJECT", 3, True, "TIME")):
        s.range_mode, s.laser_mode, s.bounces, s.time_gate = range_mode, laser_mode, bounces, gate
        s.recon_budget = budget
        for panel in PANELS:
            log = draw_panel(panel)
            seen_props |= _props(log)
            seen_ops |= _ops(log)
    # every setting and every operator of the add-on is reachable from the sidebar
    settings = {p for p in s.bl_rna.properties.keys() if p not in ("rna_type", "name", "spots",
                                                                   "active_spot_index")
                and not p.startswith("result_")}  # results are shown as text: test_results_are_shown
    assert settings - seen_props == set()
    # (Cancel appears only while a job runs: test_running_job_shows_progress_and_cancel; the environment
    # set-up is in the preferences: test_preferences_draw; Open Summary after an evaluation: test_results_are_shown)
    assert {c.bl_idname for c in __import__("addon").operators.classes} - seen_ops == {
        "platolidar.cancel_job", "platolidar.setup_environment", "platolidar.open_summary"}
    assert "target" in seen_props  # the active spot's target is editable


def test_spots_list_rows(room):
    room.cursor.location = (0.0, 0.5, 0.5)
    call(bpy.ops.platolidar.add_spot_cursor)
    s = room.platolidar
    layout = RecordingLayout()
    panels.PLATOLIDAR_UL_spots.draw_item(None, bpy.context, layout, s, s.spots[0], 0, s, "active_spot_index", 0)
    assert ("prop", "PLATOLIDAR_PG_spot", "enabled") in layout.log
    assert any(e[0] == "label" and "0.50" in e[1] for e in layout.log)


def test_running_job_shows_progress_and_cancel(blank):
    job = jobs.Job("simulation", ["true"])
    job.progress, job.progress_line, job.last_line = 0.25, "spot 4/16", "Saved: x.exr"
    jobs.set_active(job, "simulation")
    try:
        log = draw_panel(panels.PLATOLIDAR_PT_simulate)
    finally:
        jobs.set_active(None, "simulation")
    assert ("progress", 0.25, "25%  spot 4/16") in log
    assert ("op_prop", "platolidar.cancel_job", "kind") in log
    assert "platolidar.simulate" not in _ops(log)


@pytest.mark.parametrize("mode,shown,hidden", [
    ("fast", {"recon_budget", "recon_steps", "recon_resolution", "recon_device"}, {"recon_max_seconds"}),
    ("platonerf", {"recon_budget", "recon_steps", "recon_resolution", "recon_device"}, set()),
    ("bflidar", {"recon_resolution", "recon_device"}, {"recon_budget", "recon_steps", "recon_max_seconds"})])
def test_reconstruct_panel_shows_the_modes_settings(blank, mode, shown, hidden):
    from torch_recon.contract.methods import METHODS
    s = blank.platolidar
    assert {i.identifier for i in s.bl_rna.properties["recon_mode"].enum_items} == set(METHODS)
    s.recon_mode = mode
    props = _props(draw_panel(panels.PLATOLIDAR_PT_reconstruct))
    assert shown <= props and not hidden & props, props
    s.recon_budget = "TIME"
    props = _props(draw_panel(panels.PLATOLIDAR_PT_reconstruct))
    if mode != "bflidar":
        assert "recon_max_seconds" in props and "recon_steps" not in props


def test_running_reconstruction_shows_stage_progress_eta(blank):
    job = jobs.Job("reconstruction", ["true"])
    job.progress, job.stage, job.eta_s = 0.42, "fit fast", 74.0
    jobs.set_active(job, "reconstruction")
    try:
        log = draw_panel(panels.PLATOLIDAR_PT_reconstruct)
    finally:
        jobs.set_active(None, "reconstruction")
    assert ("progress", 0.42, "fit fast 42% ETA 1:14") in log
    assert ("op_prop", "platolidar.cancel_job", "kind") in log


def test_preferences_draw(blank):
    prefs = bpy.context.preferences.addons[ADDON].preferences
    for torch_build, cuda_shown in (("cpu", False), ("cuda", True)):
        prefs.env_torch = torch_build
        layout = RecordingLayout()
        proxy = SimpleNamespace(layout=layout, bl_rna=prefs.bl_rna, env_torch=prefs.env_torch)
        preferences.PLATOLIDAR_AP_preferences.draw(proxy, bpy.context)
        assert _props(layout.log) == {"python_path", "blender_path", "project_dir", "output_dir", "env_base_python",
                                      "env_dir", "env_torch"} | ({"env_cuda"} if cuda_shown else set())
        assert "platolidar.setup_environment" in _ops(layout.log)


def test_the_stub_catches_typos(blank):
    s = bpy.context.scene.platolidar

    def bad_prop(self, context):
        self.layout.prop(s, "bin_width_ps")  # not a property

    def bad_operator(self, context):
        self.layout.operator("platolidar.simulat")

    def bad_operator_prop(self, context):
        self.layout.operator("platolidar.cancel_job").knd = "simulation"

    def bad_icon(self, context):
        self.layout.operator("platolidar.simulate", icon="RENDER_STIL")

    def bad_argument(self, context):
        self.layout.prop(s, "width", txt="W")

    for draw in (bad_prop, bad_operator, bad_operator_prop, bad_icon, bad_argument):
        with pytest.raises(AssertionError):
            draw(SimpleNamespace(layout=RecordingLayout()), bpy.context)


def test_results_are_shown(blank, tmp_path):
    """After an evaluation: the key numbers and Open Summary; after an error-coloured import: the legend."""
    import json
    s = blank.platolidar
    log = draw_panel(panels.PLATOLIDAR_PT_reconstruct)
    assert "platolidar.open_summary" not in _ops(log)
    s.result_numbers = json.dumps([["Depth L1", "0.0123 m"], ["F-score", "0.912"]])
    s.result_summary = str(tmp_path / "summary.html")
    log = draw_panel(panels.PLATOLIDAR_PT_reconstruct)
    labels = [e[1] for e in log if e[0] == "label"]
    assert "Depth L1" in labels and "0.0123 m" in labels and "0.912" in labels
    assert "platolidar.open_summary" in _ops(log)
    s.import_color_error, s.result_error_scale_m, s.result_error_mean_m, s.result_error_max_m = True, 0.3, 0.01, 0.5
    labels = [e[1] for e in draw_panel(panels.PLATOLIDAR_PT_import) if e[0] == "label"]
    assert ["0.0 cm", "10.0 cm", "20.0 cm", ">= 30.0 cm"] == [t for t in labels if t.endswith(" cm") and "mean" not in t]
    assert "mean 1.00 cm, max 50.00 cm" in labels
