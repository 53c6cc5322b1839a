"""3D View > Sidebar > Lidar: Sensor (+ Noise & Gating), Spots, Simulate, Reconstruct, Import."""

from __future__ import annotations

import bpy

from . import jobs
from .config_io import effective_bins, ps_to_m
from torch_recon.contract.methods import METHODS


class _LidarPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Lidar"

    @classmethod
    def poll(cls, context):
        return getattr(context.scene, "platolidar", None) is not None


def _job_row(layout, kind: str) -> bool:
    """Progress bar and Cancel button while a job of this kind runs; True when one runs."""
    job = jobs.active(kind)
    if job is None:
        return False
    row = layout.row(align=True)
    row.progress(factor=job.progress or 0.0, type="BAR", text=job.short_status()[:48])
    op = row.operator("platolidar.cancel_job", text="", icon="CANCEL")
    op.kind = kind
    return True


class PLATOLIDAR_PT_sensor(_LidarPanel, bpy.types.Panel):
    bl_label = "Sensor"
    bl_idname = "PLATOLIDAR_PT_sensor"

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "camera")
        if s.camera is None and context.scene.camera is not None:
            layout.label(text=f"Using scene camera '{context.scene.camera.name}'", icon="INFO")
        col = layout.column(align=True)
        col.prop(s, "width", text="Resolution X")
        col.prop(s, "height", text="Y")
        col = layout.column(align=True)
        col.prop(s, "bin_ps")
        col.prop(s, "range_mode")
        col.prop(s, "bins" if s.range_mode == "BINS" else "max_path_m")
        col.prop(s, "start_m")
        bins = effective_bins(s)
        bin_m = ps_to_m(s.bin_ps)
        layout.label(text=f"{bins} bins of {100 * bin_m:.2f} cm, path to {s.start_m + bins * bin_m:.2f} m")
        col = layout.column(align=True)
        col.prop(s, "pulse_fwhm_ps")
        col.prop(s, "pulse_shape")
        layout.prop(s, "laser_mode")
        if s.laser_mode == "OBJECT":
            layout.prop(s, "laser_object")
        layout.prop(s, "footprint_radius_m")


class PLATOLIDAR_PT_noise(_LidarPanel, bpy.types.Panel):
    bl_label = "Noise & Gating"
    bl_idname = "PLATOLIDAR_PT_noise"
    bl_parent_id = "PLATOLIDAR_PT_sensor"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(s, "photon_counts")
        col = layout.column(align=True)
        col.prop(s, "photons_per_pixel")
        col.prop(s, "ambient_per_bin")
        col.prop(s, "wavelength_filter_factor")
        col.prop(s, "dark_counts_per_bin")
        layout.prop(s, "time_gate")
        sub = layout.column()
        sub.active = s.time_gate
        sub.prop(s, "gate_window_bins")


class PLATOLIDAR_UL_spots(bpy.types.UIList):
    """Spot rows: enable toggle, name, target point."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.prop(item, "enabled", text="")
        row.prop(item, "name", text="", emboss=False)
        if item.advised:
            row.label(text="", icon="SOLO_ON")  # added by Advise Spots
        t = item.target
        row.label(text=f"{t[0]:.2f}, {t[1]:.2f}, {t[2]:.2f}")


class PLATOLIDAR_PT_spots(_LidarPanel, bpy.types.Panel):
    bl_label = "Spots"
    bl_idname = "PLATOLIDAR_PT_spots"

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.prop(s, "spot_source", expand=True)
        row = layout.row()
        row.template_list("PLATOLIDAR_UL_spots", "", s, "spots", s, "active_spot_index", rows=4)
        col = row.column(align=True)
        col.operator("platolidar.add_spot_cursor", text="", icon="PIVOT_CURSOR")
        col.operator("platolidar.add_spot_click", text="", icon="RESTRICT_SELECT_OFF")
        col.operator("platolidar.remove_spot", text="", icon="REMOVE")
        if 0 <= s.active_spot_index < len(s.spots):
            layout.prop(s.spots[s.active_spot_index], "target")
        box = layout.box()
        row = box.row(align=True)
        row.prop(s, "random_candidates")
        row.prop(s, "random_keep")
        row = box.row(align=True)
        row.prop(s, "seed")
        row.operator("platolidar.generate_spots", icon="STICKY_UVS_DISABLE")
        _advise_box(layout.box(), context)
        layout.prop(s, "show_rays")


def _advise_box(box, context):
    """Advise Spots: its settings, and the button, usable once the Reconstruct output folder holds a fast fit."""
    from .operators.advise_spots import last_fit_dir

    s = context.scene.platolidar
    row = box.row(align=True)
    row.prop(s, "advise_add")
    row.prop(s, "advise_beyond_view_deg")
    if _job_row(box, "advice"):
        return
    has_fit = last_fit_dir(context) is not None
    row = box.row()
    row.enabled = has_fit
    row.operator("platolidar.advise_spots", icon="LIGHT_SPOT")
    if not has_fit:
        box.label(text="Needs a fast fit (Reconstruct, Mode Fast)", icon="INFO")


class PLATOLIDAR_PT_simulate(_LidarPanel, bpy.types.Panel):
    bl_label = "Simulate"
    bl_idname = "PLATOLIDAR_PT_simulate"

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.prop(s, "output_dir")
        col = layout.column(heading="Render", align=True)
        col.prop(s, "bounces")
        if s.bounces == 3 and hasattr(s, "third_bounce_vpls"):
            col.prop(s, "third_bounce_vpls")
        col.prop(s, "subpixel_grid")
        col.prop(s, "rgb")
        col = layout.column(heading="Ground Truth", align=True)
        col.prop(s, "train_depth")
        col.prop(s, "gt_mesh")
        row = col.row(align=True)
        row.prop(s, "test_views_dolly")
        row.prop(s, "test_views_orbit")
        col.prop(s, "test_view_resolution")
        if not _job_row(layout, "simulation"):
            layout.operator("platolidar.simulate", icon="RENDER_STILL")
        row = layout.row(align=True)
        row.operator("platolidar.export_config", icon="EXPORT")
        row.operator("platolidar.load_config", icon="IMPORT")


class PLATOLIDAR_PT_reconstruct(_LidarPanel, bpy.types.Panel):
    bl_label = "Reconstruct"
    bl_idname = "PLATOLIDAR_PT_reconstruct"

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.prop(s, "recon_dataset_dir")
        layout.prop(s, "recon_out_dir")
        layout.prop(s, "recon_mode")
        m = METHODS[s.recon_mode]
        col = layout.column(align=True)
        if m.command == "fit":
            col.prop(s, "recon_budget", expand=True)
            col.prop(s, "recon_steps" if s.recon_budget == "STEPS" else "recon_max_seconds")
        if m.grid_setting:
            col.prop(s, "recon_resolution")
        col.prop(s, "recon_device")
        if not _job_row(layout, "reconstruction"):
            layout.operator("platolidar.reconstruct", icon="MESH_ICOSPHERE")
        layout.operator("platolidar.check_environment", icon="CHECKMARK")
        if not _job_row(layout, "evaluation"):
            layout.operator("platolidar.evaluate", icon="GRAPH")
        numbers = _result_numbers(s)
        if numbers:
            box = layout.box()
            box.label(text="Last evaluation (test views / surface):")
            for label, text in numbers:
                row = box.row()
                row.label(text=label)
                row.label(text=text)
            if s.result_summary:
                box.operator("platolidar.open_summary", icon="URL")


def _result_numbers(s) -> list:
    import json
    try:
        return [tuple(x) for x in json.loads(s.result_numbers)] if s.result_numbers else []
    except (ValueError, TypeError):
        return []


#: the error ramp's stops (addon/importing.py error_ramp: blue, green, yellow, red) as Blender's colour-tag icons
LEGEND_ICONS = ("COLLECTION_COLOR_05", "COLLECTION_COLOR_04", "COLLECTION_COLOR_03", "COLLECTION_COLOR_01")


def _error_legend(box, s):
    """The colours of the imported reconstruction: distance to the ground truth at each ramp stop."""
    box.label(text="Error colours (distance to ground truth):")
    scale = s.result_error_scale_m
    row = box.row(align=True)
    for i, icon in enumerate(LEGEND_ICONS):
        v = scale * i / (len(LEGEND_ICONS) - 1)
        row.label(text=f"{'>= ' if i == len(LEGEND_ICONS) - 1 else ''}{100 * v:.1f} cm", icon=icon)
    box.label(text=f"mean {100 * s.result_error_mean_m:.2f} cm, max {100 * s.result_error_max_m:.2f} cm")


class PLATOLIDAR_PT_import(_LidarPanel, bpy.types.Panel):
    bl_label = "Import"
    bl_idname = "PLATOLIDAR_PT_import"

    def draw(self, context):
        s = context.scene.platolidar
        layout = self.layout
        layout.prop(s, "import_path")
        layout.prop(s, "import_color_error")
        layout.operator("platolidar.import_reconstruction", icon="IMPORT")
        if s.import_color_error and s.result_error_scale_m > 0:
            _error_legend(layout.box(), s)
        layout.separator()
        layout.prop(s, "measurements_path")
        layout.operator("platolidar.import_visible_depth", icon="OUTLINER_OB_POINTCLOUD")


classes = (PLATOLIDAR_UL_spots, PLATOLIDAR_PT_sensor, PLATOLIDAR_PT_noise, PLATOLIDAR_PT_spots,
           PLATOLIDAR_PT_simulate, PLATOLIDAR_PT_reconstruct, PLATOLIDAR_PT_import)
