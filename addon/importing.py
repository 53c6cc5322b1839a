"""Bring reconstructions into the scene: meshes in place, error colours, visible-depth points.

Frames on disk follow torch_recon/mesh_export.py: .ply holds Blender world (Z-up)
coordinates, imported with forward Y / up Z (no conversion); .obj and .glb/.gltf are
Y-up files, imported with the importers' own Y-up defaults, which restore the world
frame. A ``<stem>.mesh.json`` sidecar, when present, says which frame a file uses and
wins. Objects keep identity transforms. Errors are ``ImportProblem`` with a message.
"""

from __future__ import annotations

import json
import os

import bpy
import numpy as np
from mathutils.bvhtree import BVHTree

from torch_recon.contract.errors import PlatolidarError

COLLECTION_NAME = "Reconstruction"
ERROR_ATTRIBUTE = "error_m"
ERROR_COLOUR = "error_colour"
POINTS_NAME = "Visible Depth"


class ImportProblem(PlatolidarError, RuntimeError):
    """A file the import cannot use; the message names it."""


def reconstruction_collection(scene) -> bpy.types.Collection:
    coll = bpy.data.collections.get(COLLECTION_NAME)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION_NAME)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _move_to(obj, coll):
    for c in list(obj.users_collection):
        c.objects.unlink(obj)
    coll.objects.link(obj)


def file_is_z_up(path: str) -> bool:
    """Is this mesh file in Blender's Z-up world (True) or a Y-up file (False)?"""
    ext = os.path.splitext(path)[1].lower()
    sidecar = os.path.join(os.path.dirname(path), os.path.splitext(os.path.basename(path))[0] + ".mesh.json")
    try:
        with open(sidecar) as f:
            frame = json.load(f)["mesh"]["file_frames"][os.path.basename(path)]
        return str(frame).startswith("blender_world_z_up")
    except (OSError, ValueError, KeyError, TypeError):
        return ext == ".ply"


def import_mesh_file(path: str) -> list:
    """Import a .ply/.obj/.glb in place (world frame); returns the new objects."""
    if not os.path.isfile(path):
        raise ImportProblem(f"Mesh file '{path}' does not exist")
    ext = os.path.splitext(path)[1].lower()
    axes = {"forward_axis": "Y", "up_axis": "Z"} if file_is_z_up(path) else \
        {"forward_axis": "NEGATIVE_Z", "up_axis": "Y"}
    before = set(bpy.data.objects)
    try:
        if ext == ".ply":
            bpy.ops.wm.ply_import(filepath=path, **axes)
        elif ext == ".obj":
            bpy.ops.wm.obj_import(filepath=path, **axes)
        elif ext in (".glb", ".gltf"):
            if not hasattr(bpy.ops.import_scene, "gltf"):
                raise ImportProblem("The glTF importer (io_scene_gltf2) is not enabled: enable it or use .ply")
            bpy.ops.import_scene.gltf(filepath=path)  # glTF is Y-up by definition; the importer converts
        else:
            raise ImportProblem(f"'{path}': expected a .ply, .obj or .glb mesh, got '{ext or 'no extension'}'")
    except RuntimeError as exc:
        raise ImportProblem(f"Blender could not import '{path}': {str(exc).strip()}") from None
    new = [o for o in bpy.data.objects if o not in before]
    if not new:
        raise ImportProblem(f"'{path}' holds no mesh Blender could read")
    return new


def import_reconstruction(scene, path: str) -> list:
    coll = reconstruction_collection(scene)
    objs = import_mesh_file(path)
    for o in objs:
        _move_to(o, coll)
    return objs


def dataset_gt_mesh(dataset_dir: str) -> str | None:
    """The ground-truth mesh named by a dataset's manifest, when present on disk."""
    manifest = os.path.join(dataset_dir, "dataset.json")
    try:
        with open(manifest) as f:
            d = json.load(f)
    except (OSError, ValueError):
        return None
    rel = (d.get("ground_truth") or {}).get("mesh_file") if isinstance(d, dict) else None
    if not isinstance(rel, str) or not rel:
        return None
    p = os.path.join(dataset_dir, rel)
    return p if os.path.isfile(p) else None


def _world_vertices(obj) -> np.ndarray:
    me = obj.data
    co = np.empty(len(me.vertices) * 3, dtype=np.float64)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    m = np.array(obj.matrix_world, dtype=np.float64)
    return co @ m[:3, :3].T + m[:3, 3]


def gt_bvh(gt_path: str) -> BVHTree:
    """BVH of the ground-truth mesh (imported temporarily, then removed)."""
    objs = import_mesh_file(gt_path)
    try:
        verts, polys = [], []
        for o in objs:
            if o.type != "MESH":
                continue
            base = len(verts)
            verts.extend(map(tuple, _world_vertices(o)))
            polys.extend([tuple(base + i for i in p.vertices) for p in o.data.polygons])
        if not polys:
            raise ImportProblem(f"Ground-truth mesh '{gt_path}' has no faces")
        return BVHTree.FromPolygons(verts, polys)
    finally:
        for o in objs:
            data = o.data
            bpy.data.objects.remove(o)
            if isinstance(data, bpy.types.Mesh) and data.users == 0:
                bpy.data.meshes.remove(data)


def error_ramp(t: np.ndarray) -> np.ndarray:
    """Blue (0) -> green -> yellow -> red (1), RGBA float."""
    t = np.clip(t, 0.0, 1.0)[:, None]
    stops = np.array([[0.05, 0.15, 0.9], [0.1, 0.8, 0.2], [0.95, 0.9, 0.1], [0.9, 0.1, 0.05]])
    x = t * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)[:, 0]
    f = x[:, 0] - i
    rgb = stops[i] * (1 - f)[:, None] + stops[i + 1] * f[:, None]
    return np.concatenate([rgb, np.ones((len(rgb), 1))], axis=1)


def colour_by_error(obj, bvh: BVHTree, scale_m: float | None = None) -> dict:
    """Per-vertex distance to the ground truth as attribute ``error_m`` and a colour attribute.

    scale_m: distance mapped to red (default: the 95th percentile, so outliers do not wash it out).
    """
    me = obj.data
    pts = _world_vertices(obj)
    dist = np.full(len(pts), np.nan, dtype=np.float32)
    for i, p in enumerate(pts):
        hit = bvh.find_nearest(p)
        if hit[0] is not None:
            dist[i] = hit[3]
    if not np.all(np.isfinite(dist)):
        raise ImportProblem(f"{int(np.sum(~np.isfinite(dist)))} vertices found no ground-truth surface")
    for name in (ERROR_ATTRIBUTE, ERROR_COLOUR):
        if name in me.attributes:
            me.attributes.remove(me.attributes[name])
    me.attributes.new(ERROR_ATTRIBUTE, "FLOAT", "POINT").data.foreach_set("value", dist)
    scale = float(scale_m) if scale_m else float(np.percentile(dist, 95)) if len(dist) else 0.0
    colours = error_ramp(dist / max(scale, 1e-9)).astype(np.float32)
    ca = me.color_attributes.new(ERROR_COLOUR, "FLOAT_COLOR", "POINT")
    ca.data.foreach_set("color", colours.ravel())
    me.color_attributes.active_color = ca
    me.color_attributes.render_color_index = me.color_attributes.active_color_index
    _attach_colour_material(obj)
    return {"mean_m": float(dist.mean()) if len(dist) else 0.0, "max_m": float(dist.max()) if len(dist) else 0.0,
            "scale_m": scale}


def _attach_colour_material(obj):
    mat = bpy.data.materials.get("Reconstruction Error") or bpy.data.materials.new("Reconstruction Error")
    if mat.node_tree is None:  # Blender < 5.0 creates materials without nodes
        mat.use_nodes = True
    nt = mat.node_tree
    bsdf = next((n for n in nt.nodes if n.type == "BSDF_PRINCIPLED"), None)
    attr = next((n for n in nt.nodes if n.type == "VERTEX_COLOR"), None) or nt.nodes.new("ShaderNodeVertexColor")
    attr.layer_name = ERROR_COLOUR
    if bsdf is not None:
        nt.links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def visible_depth_points(npz_path: str) -> tuple[np.ndarray, np.ndarray | None]:
    """World points of the closed-form visible depth in a measurements .npz (and their confidence)."""
    from . import _project
    _project.ensure_importable()
    from torch_recon.contract.frames import pixel_rays
    from torch_recon.measurements import Measurements

    if not os.path.isfile(npz_path):
        raise ImportProblem(f"Measurements file '{npz_path}' does not exist")
    try:
        m = Measurements.load(npz_path)
    except (OSError, ValueError, KeyError) as exc:
        raise ImportProblem(f"'{npz_path}' is not a measurements file: {exc}") from None
    if m.visible_depth is None:
        raise ImportProblem(f"'{npz_path}' holds no visible depth (run preprocessing with depth)")
    depth = np.asarray(m.visible_depth, dtype=np.float64)
    if depth.shape != (m.height, m.width):
        raise ImportProblem(f"'{npz_path}': visible_depth has shape {depth.shape}, expected "
                            f"({m.height}, {m.width})")
    origins, dirs = pixel_rays(m.camera_to_world, m.width, m.height, m.fov_rad, m.fov_axis)
    ok = np.isfinite(depth) & (depth > 0)
    pts = origins[ok] + dirs[ok] * depth[ok][:, None]
    conf = None if m.visible_confidence is None else np.asarray(m.visible_confidence, np.float32)[ok]
    return pts, conf


def points_object(scene, points: np.ndarray, confidence=None, radius: float = 0.005, name: str = POINTS_NAME):
    """A mesh of loose vertices shown as points (Geometry Nodes 'Mesh to Points'), in the collection."""
    me = bpy.data.meshes.new(name)
    me.vertices.add(len(points))
    me.vertices.foreach_set("co", np.asarray(points, np.float32).ravel())
    if confidence is not None:
        me.attributes.new("confidence", "FLOAT", "POINT").data.foreach_set("value", confidence)
    me.update()
    obj = bpy.data.objects.new(name, me)
    reconstruction_collection(scene).objects.link(obj)
    mod = obj.modifiers.new("Show as Points", "NODES")
    mod.node_group = _points_node_group(radius)
    return obj


def _points_node_group(radius: float):
    name = "platolidar Mesh to Points"
    ng = bpy.data.node_groups.get(name)
    if ng is None:
        ng = bpy.data.node_groups.new(name, "GeometryNodeTree")
        ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
        n_in = ng.nodes.new("NodeGroupInput")
        n_out = ng.nodes.new("NodeGroupOutput")
        m2p = ng.nodes.new("GeometryNodeMeshToPoints")
        ng.links.new(n_in.outputs[0], m2p.inputs["Mesh"])
        ng.links.new(m2p.outputs["Points"], n_out.inputs[0])
    m2p = next(n for n in ng.nodes if n.bl_idname == "GeometryNodeMeshToPoints")
    m2p.inputs["Radius"].default_value = radius
    return ng
