"""Helpers for the simulator tests: run pipeline/simulate.py, build small .blend files (in a subprocess)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

from pipeline.launch import run_simulate

ROOT = Path(__file__).resolve().parents[2]


def simulate(out, *args, check=True, blend=None):
    proc = run_simulate(["--out", out, *args], blend=blend, cwd=ROOT, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(f"simulate failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return proc


_BUILD = """
import json, sys, bpy
sys.path.insert(0, {root!r})
from pipeline.blender_scene import diffuse_material, store_config
from torch_recon.contract.simulation import SimulationConfig, SpotConfig
from torch_recon.contract.scenes import box
from torch_recon.contract.frames import look_at_c2w
from mathutils import Matrix
opts = json.loads({opts!r})
bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene
def add(part, hidden=False):
    me = bpy.data.meshes.new(part.name)
    me.from_pydata(part.vertices.tolist(), [], part.faces.tolist())
    ob = bpy.data.objects.new(part.name, me)
    sc.collection.objects.link(ob)
    me.materials.append(diffuse_material(part.name, part.albedo))
    ob.hide_render = hidden
for name, lo, hi, albedo in {parts!r}:
    add(box(name, lo, hi, albedo))
if opts.get("hidden_box"):
    add(box("hidden", (-1.5, 1.0, -0.9), (1.5, 1.2, 1.5), 0.9), hidden=True)
if opts.get("laser_at"):
    laser = bpy.data.objects.new("laser", None); sc.collection.objects.link(laser)
    laser.location = opts["laser_at"]
if opts.get("camera", True):
    cam = bpy.data.cameras.new("cam"); cam.sensor_fit = "HORIZONTAL"; cam.angle = 1.5707963
    co = bpy.data.objects.new("cam", cam); sc.collection.objects.link(co); sc.camera = co
    co.matrix_world = Matrix(look_at_c2w([0, 0, 0], [0, 3, 0]).tolist())
cfg = SimulationConfig(**opts.get("config", {{}}))
cfg.spots = [SpotConfig(**s) for s in opts.get("spots", [])]
store_config(cfg)
bpy.ops.wm.save_as_mainfile(filepath={path!r})
"""


BLEND_PARTS = (("wall", (-2, 3, -1), (2, 3.05, 2), 0.7), ("floor", (-2, 0, -1.05), (2, 3, -1), 0.5),
               ("block", (-0.3, 2.0, -1), (0.3, 2.4, -0.4), 0.6))


def blend_trimesh():
    """The trimesh and face albedo of build_blend's scene (without the hidden box)."""
    import numpy as np
    import trimesh

    from torch_recon.contract.scenes import box

    parts = [box(*p) for p in BLEND_PARTS]
    off = np.cumsum([0] + [len(p.vertices) for p in parts])
    mesh = trimesh.Trimesh(np.concatenate([p.vertices for p in parts]),
                           np.concatenate([p.faces + o for p, o in zip(parts, off)]), process=False)
    return mesh, np.concatenate([np.full(len(p.faces), p.albedo) for p in parts])


def build_blend(path, **opts) -> Path:
    """A wall, a floor and a block (plus options: hidden_box, camera=False, laser_at=[x, y, z] (an
    Empty named 'laser'), config={...}, spots=[...])."""
    code = textwrap.dedent(_BUILD).format(root=str(ROOT), opts=json.dumps(opts), path=str(path), parts=BLEND_PARTS)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    if proc.returncode != 0:
        raise AssertionError(proc.stderr[-3000:])
    return Path(path)
