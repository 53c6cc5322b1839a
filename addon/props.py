"""Scene settings of the lidar: sensor, noise, gate, spots, job paths (``scene.platolidar``).

Stored in the .blend with the scene. ``config_io`` turns them into a
``pipeline.config.SimulationConfig``; names match that class where a setting exists there.
Times in ps (as typed), lengths in metres, as in the config.
"""

import math

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, PointerProperty, StringProperty)

from pipeline.config import SimulationConfig  # on sys.path: addon/__init__.py
from torch_recon.contract.methods import DEFAULT_FIT_METHOD, METHODS

_SIM = SimulationConfig()   # the panel's defaults are the simulator's (one source of defaults)


def _blend_relative_option() -> set:
    """Paths may start with '//' (relative to the .blend): Blender 5.0 wants this declared, older
    versions lack the flag. Ask Blender by registering a throwaway class."""
    flag = {"PATH_SUPPORTS_BLEND_RELATIVE"}
    probe = type("PLATOLIDAR_PG_probe", (bpy.types.PropertyGroup,),
                 {"__annotations__": {"path": StringProperty(subtype="FILE_PATH", options=flag)}})
    try:
        bpy.utils.register_class(probe)
    except (ValueError, TypeError):
        return set()
    bpy.utils.unregister_class(probe)
    return flag


_BLEND_RELATIVE = _blend_relative_option()


def _redraw_views(self, context):
    """Laser rays are drawn from these settings: redraw 3D views when they change."""
    wm = getattr(context, "window_manager", None)
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def _is_camera(self, obj):
    return obj.type == "CAMERA"


#: name of the spots Advise Spots adds ('Advised 01', ...): settings files keep names, so the mark survives them
ADVISED_PREFIX = "Advised"


class PLATOLIDAR_PG_spot(bpy.types.PropertyGroup):
    # `name` is PropertyGroup's built-in name property (shown and renamed in the list)
    enabled: BoolProperty(name="Enabled", default=True, description="Simulate this spot", update=_redraw_views)
    target: FloatVectorProperty(name="Target", size=3, subtype="XYZ", unit="LENGTH", update=_redraw_views,
                                description="World point the laser is aimed at (where it hits the surface)")
    advised: BoolProperty(name="Advised", default=False,
                          description="Added by Advise Spots (where a fast fit says new light is most needed)")


class PLATOLIDAR_PG_settings(bpy.types.PropertyGroup):
    # -- sensor ------------------------------------------------------------------------
    camera: PointerProperty(name="Lidar Camera", type=bpy.types.Object, poll=_is_camera, update=_redraw_views,
                            description="Camera that is the lidar's detector (empty: the scene camera)")
    width: IntProperty(name="Width", default=_SIM.width, min=1, soft_max=2048, description="Detector pixels across")
    height: IntProperty(name="Height", default=_SIM.height, min=1, soft_max=2048, description="Detector pixels down")
    bin_ps: FloatProperty(name="Bin Width (ps)", default=_SIM.bin_ps, min=0.01, soft_max=1000.0,
                          description="Time bin width in picoseconds")
    range_mode: EnumProperty(name="Histogram Length", default="BINS",
                             items=(("BINS", "Bin Count", "Give the number of time bins"),
                                    ("RANGE", "Maximum Path", "Give the longest optical path to record")))
    bins: IntProperty(name="Bins", default=_SIM.bins, min=1, soft_max=4096, description="Number of time bins")
    max_path_m: FloatProperty(name="Max Path", default=15.0, min=0.001, subtype="DISTANCE", unit="LENGTH",
                              description="Longest optical path (laser to scene to sensor) the histogram covers")
    start_m: FloatProperty(name="Start", default=_SIM.start_m, min=0.0, subtype="DISTANCE", unit="LENGTH",
                           description="Optical path at the start of the first bin")
    pulse_fwhm_ps: FloatProperty(name="Pulse FWHM (ps)", default=_SIM.pulse_fwhm_ps, min=0.01, soft_max=2000.0,
                                 description="Laser pulse full width at half maximum, in picoseconds")
    pulse_shape: EnumProperty(name="Pulse Shape", default=_SIM.pulse_shape,
                              items=(("gaussian", "Gaussian", "Gaussian pulse of the given FWHM"),
                                     ("box", "Box", "All energy in a single bin")))
    laser_mode: EnumProperty(name="Laser Origin", default="COLOCATED", update=_redraw_views,
                             items=(("COLOCATED", "Co-located", "Laser at the camera's centre (as in the paper)"),
                                    ("OBJECT", "Object", "Laser at another object's location")))
    laser_object: PointerProperty(name="Laser Object", type=bpy.types.Object, update=_redraw_views,
                                  description="Object whose world location is the laser origin")
    footprint_radius_m: FloatProperty(name="Footprint Radius", default=_SIM.footprint_radius_m, min=1e-5, subtype="DISTANCE",
                                      unit="LENGTH", description="Radius of the lit laser spot on the surface")
    # -- noise and gating --------------------------------------------------------------------
    photon_counts: BoolProperty(name="Photon Counts", default=_SIM.photon_counts,
                                description="Poisson-sample photon counts instead of expected values")
    photons_per_pixel: FloatProperty(name="Photons", default=_SIM.photons_per_pixel, min=0.0,
                                     description="Signal budget: mean photons of the brightest lit pixel")
    ambient_per_bin: FloatProperty(name="Ambient", default=_SIM.ambient_per_bin, min=0.0,
                                   description="Ambient photons per pixel per bin, before the wavelength filter")
    wavelength_filter_factor: FloatProperty(name="Wavelength Filter", default=_SIM.wavelength_filter_factor, min=0.0, max=1.0,
                                            subtype="FACTOR",
                                            description="Fraction of ambient light passing the band-pass filter")
    dark_counts_per_bin: FloatProperty(name="Dark Counts", default=_SIM.dark_counts_per_bin, min=0.0,
                                       description="Detector dark counts per pixel per bin")
    time_gate: BoolProperty(name="Time Gate", default=_SIM.time_gate,
                            description="Keep only a window of bins around the expected return")
    gate_window_bins: IntProperty(name="Gate Window (bins)", default=_SIM.gate_window_bins, min=1, description="Bins kept by the gate")
    # -- what to render ---------------------------------------------------------------------
    bounces: IntProperty(name="Bounces", default=_SIM.bounces, min=2, max=3, description="2, or 3 for third-order light")
    third_bounce_vpls: IntProperty(name="Third-bounce Lights", default=_SIM.third_bounce_vpls, min=1, soft_max=256,
                                   description="With 3 bounces: virtual point lights (one render each) per spot")
    subpixel_grid: IntProperty(name="Sub-pixel Grid", default=math.isqrt(_SIM.subpixel_samples), min=1, max=8,
                               description="N: N x N sub-pixel samples per pixel, for depth edges spanning bins")
    rgb: BoolProperty(name="RGB Images", default=_SIM.rgb, description="Also render RGB images (RGB-shadow baseline)")
    train_depth: BoolProperty(name="Train-view Depth", default=_SIM.train_depth, description="Ground-truth depth of the sensor")
    gt_mesh: BoolProperty(name="Ground-truth Mesh", default=_SIM.gt_mesh, description="Export the scene mesh (world frame)")
    test_views_dolly: IntProperty(name="Dolly Views", default=_SIM.test_views_dolly, min=0, description="Test views (0: none)")
    test_views_orbit: IntProperty(name="Orbit Views", default=_SIM.test_views_orbit, min=0, description="Test views (0: none)")
    test_view_resolution: IntProperty(name="Test View Size", default=_SIM.test_view_resolution, min=1)
    # -- spots --------------------------------------------------------------------------------
    spot_source: EnumProperty(name="Spots", default="LIST",
                              items=(("LIST", "Listed", "Simulate the spots in the list"),
                                     ("RANDOM", "Random at Simulation", "Let the simulator draw random spots")))
    spots: CollectionProperty(type=PLATOLIDAR_PG_spot)
    active_spot_index: IntProperty(name="Active Spot", default=0, min=0)
    random_candidates: IntProperty(name="Candidates", default=_SIM.random_candidates, min=1, description="Random candidate spots")
    random_keep: IntProperty(name="Keep", default=_SIM.random_keep, min=1, description="Spots kept by diversity")
    seed: IntProperty(name="Seed", default=_SIM.seed, min=0, description="Seed of every random choice")
    show_rays: BoolProperty(name="Show Laser Rays", default=True, update=_redraw_views)
    # Advise Spots (`advise-spots`; defaults and ranges are AdviceSettings', which imports torch: a test compares)
    advise_add: IntProperty(name="Spots to Add", default=4, min=1, soft_max=32,
                            description="Laser spots the advice adds to the list")
    advise_beyond_view_deg: FloatProperty(name="Beyond View (deg)", default=0.0, min=0.0, max=60.0,
                                          description="Also consider laser directions up to this many degrees "
                                                      "beyond the camera's view (0: in view only)")
    # -- jobs -------------------------------------------------------------------------------
    output_dir: StringProperty(name="Dataset Folder", default="//lidar_dataset", subtype="DIR_PATH", options=_BLEND_RELATIVE,
                               description="Where the simulation writes the dataset")
    recon_dataset_dir: StringProperty(name="Dataset", default="", subtype="DIR_PATH", options=_BLEND_RELATIVE,
                                      description="Dataset to reconstruct (empty: the simulation's folder)")
    recon_out_dir: StringProperty(name="Output Folder", default="//lidar_recon", subtype="DIR_PATH", options=_BLEND_RELATIVE)
    recon_mode: EnumProperty(name="Mode", default=DEFAULT_FIT_METHOD,
                             items=[(m.name, m.label, m.description) for m in METHODS.values()])
    recon_budget: EnumProperty(name="Budget", default="STEPS", items=[
        ("STEPS", "Steps", "Stop after a number of optimisation steps"),
        ("TIME", "Time", "Stop after a wall-clock time budget")])
    recon_steps: IntProperty(name="Steps", default=0, min=0, soft_max=100000,
                             description="Optimisation steps (0: the mode's default)")
    recon_max_seconds: FloatProperty(name="Time Budget (s)", default=0.0, min=0.0, soft_max=3600.0,
                                     description="Wall-clock budget of the optimisation in seconds (0: none)")
    recon_resolution: IntProperty(name="Grid Resolution", default=0, min=0, max=1024,
                                  description="Voxels along the longest side of the reconstruction grid "
                                              "(0: the mode's default)")
    recon_device: EnumProperty(name="Device", default="auto", items=[
        ("auto", "Auto", "CUDA when the reconstruction Python's torch sees a GPU, else CPU"),
        ("cpu", "CPU", "Run on the CPU"),
        ("cuda", "CUDA", "Run on the first CUDA GPU (fails when there is none)")])
    import_path: StringProperty(name="Mesh", default="", subtype="FILE_PATH", options=_BLEND_RELATIVE,
                                description="Reconstructed mesh (.ply or .obj, Blender world frame)")
    import_color_error: BoolProperty(name="Colour by Error", default=False,
                                     description="Colour vertices by distance to the dataset's ground-truth mesh")
    # -- results (written by the operators, shown as text: not settings) ---------------------------
    result_numbers: StringProperty(name="Evaluation Numbers", default="", options={"HIDDEN", "SKIP_SAVE"},
                                   description="JSON [[label, text], ...] of the last evaluation's key numbers")
    result_summary: StringProperty(name="Summary Page", default="", subtype="FILE_PATH", options={"HIDDEN"},
                                   description="The last evaluation's summary.html")
    result_error_scale_m: FloatProperty(name="Error Colour Scale", default=0.0, options={"HIDDEN"}, unit="LENGTH",
                                        description="Distance to the ground truth shown red in the error colours")
    result_error_mean_m: FloatProperty(name="Mean Error", default=0.0, options={"HIDDEN"}, unit="LENGTH")
    result_error_max_m: FloatProperty(name="Max Error", default=0.0, options={"HIDDEN"}, unit="LENGTH")
    measurements_path: StringProperty(name="Measurements", default="", subtype="FILE_PATH", options=_BLEND_RELATIVE,
                                      description="Measurements .npz (torch_recon) with the visible depth")


classes = (PLATOLIDAR_PG_spot, PLATOLIDAR_PG_settings)


def register_properties():
    bpy.types.Scene.platolidar = PointerProperty(type=PLATOLIDAR_PG_settings)


def unregister_properties():
    del bpy.types.Scene.platolidar
