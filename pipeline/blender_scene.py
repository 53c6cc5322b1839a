"""Blender side of the scene: build an example scene, read settings, inspect camera and geometry.

Everything here needs bpy. Geometry of the examples comes from torch_recon/contract/scenes.py
so the bpy-free tests see the same triangles.
"""

from __future__ import annotations

import math

import bpy
import numpy as np
from mathutils import Matrix, Vector

from torch_recon.contract.errors import PlatolidarError
from torch_recon.contract.simulation import CONFIG_TEXT_NAME, SimulationConfig, SpotConfig
from torch_recon.contract.scene_objects import OBJECTS_COLLECTION
from torch_recon.contract.scenes import AreaLight, BlenderPrimitive, ExampleScene, MeshPart


class SceneError(PlatolidarError, RuntimeError):
    """The scene cannot be simulated (no camera, unsupported camera, ...)."""


# -- building the examples ---------------------------------------------------------------
def diffuse_material(name: str, albedo: float):
    """A Lambertian material (Diffuse BSDF, roughness 0) of grey albedo."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (albedo, albedo, albedo, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    mat.diffuse_color = (albedo, albedo, albedo, 1.0)
    return mat


def _link(scene, obj):
    scene.collection.objects.link(obj)
    return obj


def _object_collection(scene, label: str):
    """The collection Objects/<label> (made on first use): how a scene labels the objects that matter."""
    top = bpy.data.collections.get(OBJECTS_COLLECTION)
    if top is None:
        top = bpy.data.collections.new(OBJECTS_COLLECTION)
        scene.collection.children.link(top)
    col = top.children.get(label)
    if col is None:
        col = bpy.data.collections.new(label)
        top.children.link(col)
    return col


def labelled_objects() -> dict | None:
    """{label: [object names]} from the collection 'Objects' (see contract.scene_objects); None without it."""
    top = bpy.data.collections.get(OBJECTS_COLLECTION)
    if top is None:
        return None
    out = {o.name: [o.name] for o in top.objects if o.type == "MESH"}
    for col in top.children:
        names = [o.name for o in col.all_objects if o.type == "MESH"]
        if names:
            out[col.name] = names
    return out or None


def build_example(ex: ExampleScene, config: SimulationConfig | None = None):
    """Replace the open file by an empty scene holding `ex`; store its settings in the .blend."""
    # the factory startup scene, emptied; read_factory_settings would also reset the preferences, re-enabling
    # every add-on (Blender's extensions add-on imports urllib/http: 0.1 s of a 128 x 128 run's start-up)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = ex.name
    label_of = {p: label for label, parts in ex.objects.items() for p in parts}
    for part in ex.parts:
        mat = diffuse_material(f"{part.name}_albedo", part.albedo)
        if isinstance(part, MeshPart):
            me = bpy.data.meshes.new(part.name)
            me.from_pydata(part.vertices.tolist(), [], part.faces.tolist())
            me.update()
            obj = _link(scene, bpy.data.objects.new(part.name, me))
        elif isinstance(part, BlenderPrimitive) and part.kind == "monkey":
            bpy.ops.mesh.primitive_monkey_add(size=2.0 * part.scale, location=part.location)
            obj = bpy.context.active_object
            obj.name = part.name
            mod = obj.modifiers.new("subdivision", "SUBSURF")
            mod.levels = mod.render_levels = part.subdivisions
            for poly in obj.data.polygons:
                poly.use_smooth = True
        else:
            raise ValueError(f"unknown part {part!r}")
        obj.data.materials.append(mat)
        if part.name in label_of:     # move the part from the scene's root into Objects/<label>
            _object_collection(scene, label_of[part.name]).objects.link(obj)
            for c in list(obj.users_collection):
                if c.name != label_of[part.name]:
                    c.objects.unlink(obj)
    for light in ex.lights:
        if isinstance(light, AreaLight):
            data = bpy.data.lights.new(light.name, "AREA")
            data.shape, data.size, data.energy = "SQUARE", light.size, light.power_w
            _link(scene, bpy.data.objects.new(light.name, data)).location = light.location
    cam = bpy.data.cameras.new("sensor")
    cam.sensor_fit = "HORIZONTAL" if ex.fov_axis == "x" else "VERTICAL"
    cam.angle = ex.fov_rad
    cam.clip_start = 1e-4
    cam_obj = _link(scene, bpy.data.objects.new("sensor", cam))
    cam_obj.matrix_world = Matrix(np.asarray(ex.camera_to_world).tolist())
    scene.camera = cam_obj
    cfg = config or SimulationConfig()
    if not cfg.spots:
        cfg.spots = [SpotConfig(target=list(t), enabled=bool(e), name=f"target_{i:02d}")
                     for i, (t, e) in enumerate(zip(ex.spot_targets, ex.spot_enabled))]
    for k, v in ex.config_overrides.items():
        setattr(cfg, k, v)
    store_config(cfg)
    bpy.context.view_layer.update()
    return scene


def store_config(cfg: SimulationConfig):
    text = bpy.data.texts.get(CONFIG_TEXT_NAME) or bpy.data.texts.new(CONFIG_TEXT_NAME)
    text.clear()
    text.write(cfg.to_json())


def stored_config() -> SimulationConfig | None:
    """The settings the add-on stored in the .blend, or None."""
    text = bpy.data.texts.get(CONFIG_TEXT_NAME)
    if text is None:
        return None
    return SimulationConfig.from_json(text.as_string(), f"{bpy.data.filepath or '<scene>'}:{CONFIG_TEXT_NAME}")


# -- preparing a scene for simulation ------------------------------------------------------
def match_viewport_to_render(scene):
    """Make viewport visibility and modifier levels equal the render's.

    scene.ray_cast and the ground-truth mesh use the evaluated (viewport)
    depsgraph; Cycles uses render settings. Only this process's copy of the
    scene changes (the .blend is never saved). Objects hidden from render are
    thereby ignored everywhere.
    """
    for col in bpy.data.collections:
        col.hide_viewport = col.hide_render
    for obj in scene.objects:
        obj.hide_viewport = obj.hide_render
        if not obj.hide_render:
            try:
                obj.hide_set(False)
            except RuntimeError:  # not in the view layer
                pass
        for mod in getattr(obj, "modifiers", []):
            mod.show_viewport = mod.show_render
            if mod.type == "SUBSURF":
                mod.levels = mod.render_levels
            elif mod.type == "MULTIRES":
                mod.levels = mod.render_levels
    bpy.context.view_layer.update()


def sensor_camera(scene, name: str | None):
    """The camera object to simulate, or SceneError naming what is wrong."""
    cam = scene.objects.get(name) if name else scene.camera
    if cam is None:
        what = f"no object named {name!r}" if name else "the scene has no camera (set one, or name it in 'camera')"
        raise SceneError(what)
    if cam.type != "CAMERA":
        raise SceneError(f"object {cam.name!r} is not a camera")
    if cam.data.type != "PERSP":
        raise SceneError(f"camera {cam.name!r}: only perspective cameras are supported, got {cam.data.type}")
    if abs(cam.data.shift_x) > 1e-9 or abs(cam.data.shift_y) > 1e-9:
        raise SceneError(f"camera {cam.name!r}: lens shift is not supported (shift_x/shift_y must be 0)")
    return cam


def camera_fov(cam, width: int, height: int):
    """(field of view in radians, axis 'x' or 'y') as Cycles renders it at width x height."""
    data = cam.data
    fit = data.sensor_fit
    if fit == "AUTO":
        # AUTO: sensor_width spans the image's larger dimension, whichever it is
        return 2.0 * math.atan(0.5 * data.sensor_width / data.lens), ("x" if width >= height else "y")
    if fit == "HORIZONTAL":
        return 2.0 * math.atan(0.5 * data.sensor_width / data.lens), "x"
    return 2.0 * math.atan(0.5 * data.sensor_height / data.lens), "y"


def rigid_c2w(cam) -> np.ndarray:
    """Camera-to-world without scale (Blender allows scaled camera objects)."""
    m = np.asarray(cam.matrix_world, np.float64)
    rot = m[:3, :3]
    u, _, vt = np.linalg.svd(rot)
    out = np.eye(4)
    out[:3, :3] = u @ vt
    out[:3, 3] = m[:3, 3]
    return out


def ray_cast(scene, depsgraph, origin, direction, max_dist=1e4, exclude=(), max_hops: int = 16):
    """First hit of a ray in the evaluated scene: (point, geometric normal, object) or None.

    Objects in `exclude` (e.g. the laser's own housing) are passed through.
    """
    origin, direction = Vector(origin), Vector(direction).normalized()
    for _ in range(max_hops):
        hit, loc, nrm, index, obj, _ = scene.ray_cast(depsgraph, origin, direction, distance=max_dist)
        if not hit:
            return None
        if obj is None or obj.original not in exclude:
            return np.array(loc, np.float64), np.array(nrm, np.float64), obj
        origin = loc + direction * 1e-5
    return None


def random_spot_targets(scene, depsgraph, sensor, n_candidates: int, keep: int, seed: int, exclude=()):
    """contract.spots.random_spot_targets with Blender's ray casts (the laser object in `exclude`)."""
    from torch_recon.contract.spots import random_spot_targets as pick

    def cast(origin, direction):
        hit = ray_cast(scene, depsgraph, origin, direction, exclude=exclude)
        return None if hit is None else hit[:2]

    return pick(sensor, cast, n_candidates, keep, seed)


def object_albedo(obj) -> float | None:
    """Grey albedo of the object's first material, read from a Diffuse/Principled BSDF (None if unknown)."""
    mats = [s.material for s in getattr(obj, "material_slots", []) if s.material is not None]
    if not mats:
        return None
    mat = mats[0]
    if mat.node_tree is not None:
        for node in mat.node_tree.nodes:
            key = {"BSDF_DIFFUSE": "Color", "BSDF_PRINCIPLED": "Base Color"}.get(node.type)
            if key and not node.inputs[key].is_linked:
                c = node.inputs[key].default_value
                return float(np.dot([0.2126, 0.7152, 0.0722], list(c)[:3]))
    return float(np.dot([0.2126, 0.7152, 0.0722], list(mat.diffuse_color)[:3]))


def world_triangles(depsgraph):
    """All render-visible evaluated mesh geometry in the world frame: (vertices, faces, object index per face, names)."""
    return world_geometry(depsgraph, corner_normals=False)[0]


def world_geometry(depsgraph, corner_normals: bool = True):
    """(world_triangles' tuple, corner normals (T, 3, 3) float32 or None).

    Corner normals are the shading normals Cycles interpolates over each triangle (Blender's split
    normals: the face normal on flat faces, vertex normals on smooth ones, custom normals kept),
    in the world frame.
    """
    verts, faces, owner, normals, off = [], [], [], [], 0
    names = []
    for inst in depsgraph.object_instances:
        obj = inst.object
        if obj.type not in {"MESH", "CURVE", "SURFACE", "META", "FONT"} or obj.hide_render:
            continue
        try:
            me = obj.to_mesh()
        except RuntimeError:
            continue
        if me is None:
            continue
        me.calc_loop_triangles()
        n_v, n_t = len(me.vertices), len(me.loop_triangles)
        if n_t:
            co = np.empty(n_v * 3, np.float32)
            me.vertices.foreach_get("co", co)
            tri = np.empty(n_t * 3, np.int32)
            me.loop_triangles.foreach_get("vertices", tri)
            m = np.asarray(inst.matrix_world, np.float64)
            v = co.reshape(-1, 3).astype(np.float64) @ m[:3, :3].T + m[:3, 3]
            verts.append(v)
            faces.append(tri.reshape(-1, 3).astype(np.int64) + off)
            owner.append(np.full(n_t, len(names)))
            names.append(obj.original.name if obj.original else obj.name)
            off += n_v
            if corner_normals:
                sn = np.empty(n_t * 9, np.float32)
                me.loop_triangles.foreach_get("split_normals", sn)
                normal_matrix = np.linalg.inv(m[:3, :3]).T        # normals transform by the inverse transpose
                n = sn.reshape(-1, 3).astype(np.float64) @ normal_matrix.T
                n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
                normals.append(n.reshape(n_t, 3, 3).astype(np.float32))
        obj.to_mesh_clear()
    if not verts:
        return (np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), names), \
            (np.zeros((0, 3, 3), np.float32) if corner_normals else None)
    tris = (np.concatenate(verts), np.concatenate(faces), np.concatenate(owner), names)
    return tris, (np.concatenate(normals) if corner_normals else None)


def scene_lights(scene):
    """Light objects that would render (the ambient lights of the scene)."""
    return [o for o in scene.objects if o.type == "LIGHT" and not o.hide_render]


def blender_version() -> str:
    return bpy.app.version_string
