"""Cycles renders of the sensor view, read back from multilayer EXR files.

Sub-pixel point samples: the image is rendered at s x the sensor resolution with
one sample per pixel and a 0.01-pixel box filter, so every rendered pixel is a
point sample at a sub-pixel centre; each s x s block is one sensor pixel's
S = s^2 samples (sample k = a * s + b: row offset a, column offset b, the order
of torch_recon.contract.analytic's stratified offsets).

Light units (checked numerically, tests/pipeline/test_sim_physics.py): a Cycles disk area
light of power P_e watts is a Lambertian emitter of exitance P_e / A, so a
Lambertian surface of albedo rho_x at distance r returns radiance
(rho_x / pi) (P_e / pi) cos_l cos_x / r^2. The lit laser spot reflects
rho_l * P of the laser power P, so an emitter of P_e = rho_l * P reproduces the
two-bounce radiance (rho_l/pi)(rho_x/pi) P cos_l cos_x / r^2 of torch_recon.contract.analytic.
"""

from __future__ import annotations

import os
import tempfile

import bpy
import numpy as np
import OpenEXR
from mathutils import Vector

from pipeline.blender_scene import scene_lights
from torch_recon.contract.dataset.staging import InterruptGuard

#: the emitter floats this far above the lit surface (keeps it out of the surface's own shadow test)
EMITTER_OFFSET_M = 1e-3
LAYER_PREFIX = "ViewLayer"


def read_multilayer_exr(path: str) -> dict:
    """{pass name: (H, W, C) float32} from a Blender multilayer EXR.

    Channels are named 'ViewLayer.<Pass>.<C>'; Blender 5.0 writes each pass as its own EXR
    part, earlier versions one part with all channels: both are grouped by pass here.
    """
    order = {"R": 0, "G": 1, "B": 2, "A": 3, "X": 0, "Y": 1, "Z": 2}
    groups: dict = {}
    f = OpenEXR.File(path, separate_channels=True)
    for part in f.parts:
        for name, ch in part.channels.items():
            prefix, comp = name.rsplit(".", 1) if "." in name else (part.name(), name)
            pass_name = prefix.split(".", 1)[-1]          # drop the view layer name
            groups.setdefault(pass_name, []).append((order.get(comp, 9), np.asarray(ch.pixels, np.float32)))
    return {k: np.stack([a for _, a in sorted(v, key=lambda t: t[0])], -1) for k, v in groups.items()}


def to_subsamples(img: np.ndarray, s: int) -> np.ndarray:
    """(H*s, W*s, ...) -> (s*s, H, W, ...): the s x s block of each pixel as S samples."""
    hs, ws = img.shape[:2]
    h, w = hs // s, ws // s
    rest = img.shape[2:]
    blocks = img.reshape((h, s, w, s) + rest)
    return np.moveaxis(blocks, (1, 3), (0, 1)).reshape((s * s, h, w) + rest)


class CyclesRenderer:
    """Renders the sensor view with Cycles; keeps render data between renders (persistent data) unless
    told that one render will do (persistent_data=False: 50 MB less at 512 x 512 x 4 samples)."""

    def __init__(self, scene, camera, width: int, height: int, subpixel_side: int, seed: int = 0,
                 fov_axis: str = "x", fov_rad: float | None = None, persistent_data: bool = True):
        self.scene, self.camera = scene, camera
        self.persistent_data = bool(persistent_data)
        self.width, self.height, self.s = width, height, subpixel_side
        self.tmp = tempfile.TemporaryDirectory(prefix="platolidar_render_")
        self.ambient_lights = scene_lights(scene)
        for light in self.ambient_lights:      # the lidar render sees only the laser spot
            light.hide_render = True
        self._setup(seed)
        self.emitter = self._new_area_emitter()

    # -- setup ------------------------------------------------------------------------
    def _setup(self, seed):
        sc = self.scene
        sc.camera = self.camera
        r = sc.render
        r.engine = "CYCLES"
        r.resolution_x, r.resolution_y = self.width * self.s, self.height * self.s
        r.resolution_percentage = 100
        r.pixel_aspect_x = r.pixel_aspect_y = 1.0
        r.use_border = False
        r.film_transparent = True          # alpha 0 where a ray sees nothing
        r.use_persistent_data = self.persistent_data
        r.use_motion_blur = False
        c = sc.cycles
        c.device = "CPU"
        c.samples = 1
        c.use_adaptive_sampling = False
        c.use_denoising = False
        c.pixel_filter_type = "BOX"
        c.filter_width = 0.01
        c.seed = int(seed) % (2 ** 31)
        c.use_animated_seed = False
        c.max_bounces = 0
        c.direct_light_sampling_type = "NEXT_EVENT_ESTIMATION"
        c.light_sampling_threshold = 0.0
        c.use_light_tree = False           # one light per render: the tree only costs (~20 % CPU measured)
        c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
        c.caustics_reflective = c.caustics_refractive = False
        sc.world = None                    # no world light
        vl = sc.view_layers[0]
        for v in sc.view_layers:
            v.use = v == vl
        self.view_layer = vl
        self._set_passes()
        self._set_exr_output()
        r.use_compositing = False
        r.use_sequencer = False

    def _set_exr_output(self):
        ims = self.scene.render.image_settings
        if hasattr(ims, "media_type"):         # Blender 5.0: must precede file_format
            ims.media_type = "MULTI_LAYER_IMAGE"
        ims.file_format = "OPEN_EXR_MULTILAYER"
        ims.color_depth = "32"
        ims.exr_codec = "NONE"               # uncompressed: written and read once, at once

    def _set_passes(self, position=False, normal=False, albedo=False):
        vl = self.view_layer
        vl.use_pass_z = False
        vl.use_pass_mist = False
        vl.use_pass_position = position
        vl.use_pass_normal = normal
        vl.use_pass_diffuse_color = albedo

    def _new_area_emitter(self):
        data = bpy.data.lights.new("platolidar_laser_spot", "AREA")
        data.shape = "DISK"
        data.color = (1.0, 1.0, 1.0)
        data.cycles.use_multiple_importance_sampling = False  # light sampling only: exact for a tiny disk
        obj = bpy.data.objects.new("platolidar_laser_spot", data)
        self.scene.collection.objects.link(obj)
        obj.visible_camera = False
        obj.visible_glossy = obj.visible_transmission = False
        obj.hide_render = True
        return obj

    def _render(self, name: str) -> dict:
        path = os.path.join(self.tmp.name, name + ".exr")
        self.scene.render.filepath = path
        with InterruptGuard.deferring():   # Ctrl-C: this render ends, then the run stops (its image unused)
            bpy.ops.render.render(write_still=True, scene=self.scene.name)
        return read_multilayer_exr(path)

    # -- renders ----------------------------------------------------------------------
    def render_geometry(self):
        """Per sub-sample world position (S, H, W, 3), shading normal (S, H, W, 3),
        diffuse albedo (S, H, W, 3) and hit mask (S, H, W) - spot-independent, rendered once."""
        self._set_passes(position=True, normal=True, albedo=True)
        self.emitter.hide_render = True
        res = self._render("geometry")
        self._set_passes()
        valid = res["Combined"][..., 3] > 0.5
        s = self.s
        return (to_subsamples(res["Position"][..., :3], s), to_subsamples(res["Normal"][..., :3], s),
                to_subsamples(res["Diffuse Color"][..., :3], s), to_subsamples(valid, s))

    def place_emitter(self, location, normal, power_w: float, radius_m: float):
        """A Lambertian disk at `location` facing `normal` (area lights emit along local -Z)."""
        n = Vector(np.asarray(normal, np.float64).tolist()).normalized()
        obj = self.emitter
        obj.location = Vector(np.asarray(location, np.float64).tolist()) + EMITTER_OFFSET_M * n
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = Vector((0.0, 0.0, -1.0)).rotation_difference(n)
        obj.data.size = 2.0 * radius_m
        obj.data.energy = float(power_w)
        obj.hide_render = False

    def render_emitter(self, location, normal, power_w: float, radius_m: float, name="spot") -> np.ndarray:
        """Radiance (S, H, W) of the scene lit only by the disk emitter, direct light only."""
        self.place_emitter(location, normal, power_w, radius_m)
        res = self._render(name)
        self.emitter.hide_render = True
        return to_subsamples(res["Combined"][..., :3].mean(axis=-1), self.s)

    def render_rgb(self, location, power_w: float, path: str, samples: int = 64):
        """RGB-shadow baseline image: a point light at l, at most two bounces, sRGB PNG at sensor resolution."""
        sc, r, c = self.scene, self.scene.render, self.scene.cycles
        data = bpy.data.lights.new("platolidar_rgb_point", "POINT")
        data.shadow_soft_size = 0.0
        data.energy = float(power_w)
        obj = bpy.data.objects.new("platolidar_rgb_point", data)
        sc.collection.objects.link(obj)
        obj.location = Vector(np.asarray(location, np.float64).tolist())
        saved = (r.resolution_x, r.resolution_y, c.samples, c.max_bounces, c.filter_width, r.film_transparent,
                 c.direct_light_sampling_type, c.sample_clamp_indirect)
        try:
            r.resolution_x, r.resolution_y = self.width, self.height
            c.samples, c.max_bounces, c.filter_width = samples, 2, 1.5
            c.sample_clamp_indirect = 1.0      # the point light sits 1 cm off a wall: clamp its fireflies
            c.direct_light_sampling_type = "MULTIPLE_IMPORTANCE_SAMPLING"
            r.film_transparent = False
            sc.view_settings.view_transform = "Standard"   # plain sRGB gamma
            if hasattr(r.image_settings, "media_type"):
                r.image_settings.media_type = "IMAGE"
            r.image_settings.file_format = "PNG"
            r.image_settings.color_mode = "RGB"
            r.image_settings.color_depth = "8"
            r.filepath = path
            with InterruptGuard.deferring():
                bpy.ops.render.render(write_still=True, scene=sc.name)
        finally:
            bpy.data.objects.remove(obj)
            bpy.data.lights.remove(data)
            (r.resolution_x, r.resolution_y, c.samples, c.max_bounces, c.filter_width, r.film_transparent,
             c.direct_light_sampling_type, c.sample_clamp_indirect) = saved
            self._set_exr_output()

    def render_ambient(self, samples: int = 16) -> np.ndarray | None:
        """Radiance (H, W) of the scene under its own lights only (None when it has none)."""
        if not self.ambient_lights:
            return None
        r, c = self.scene.render, self.scene.cycles
        for light in self.ambient_lights:
            light.hide_render = False
        saved = (r.resolution_x, r.resolution_y, c.samples, c.max_bounces, c.filter_width,
                 c.direct_light_sampling_type)
        try:
            r.resolution_x, r.resolution_y = self.width, self.height
            c.samples, c.max_bounces, c.filter_width = samples, 2, 1.0
            c.direct_light_sampling_type = "MULTIPLE_IMPORTANCE_SAMPLING"
            res = self._render("ambient")
        finally:
            for light in self.ambient_lights:
                light.hide_render = True
            (r.resolution_x, r.resolution_y, c.samples, c.max_bounces, c.filter_width,
             c.direct_light_sampling_type) = saved
        return res["Combined"][..., :3].mean(axis=-1)

    def close(self):
        self.tmp.cleanup()
