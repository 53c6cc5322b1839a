"""Synthetic datasets with known answers, from the analytic two-bounce renderer (no Cycles, no torch).

Used by the measurement/evaluation tests and benchmarks: simple trimesh scenes
(a wall at a known distance, a box in the paper's room, an occluder casting a
known shadow) rendered by `torch_recon.contract.analytic` and written with DatasetWriter,
including ground truth (train range image, mesh, test views).
"""

from __future__ import annotations

import math

import numpy as np

from . import reference
from .analytic import render_two_bounce
from .dataset import (DatasetWriter, Manifest, NoiseSpec, Provenance, SensorSpec, Spot, TimeGate, Transient,
                      TransientLayout)
from .dataset.schema import PulseSpec
from .frames import look_at_c2w, paper_to_blender_points
from .ground_truth import render_ground_truth
from .scenes import OBJECT_ALBEDO, WALL_ALBEDO, MeshPart, box, cave_chair, room_walls
from .units import ps_to_m


def room_mesh(back_wall=True):
    """The paper's room (scenes.room_walls): x in [-2, 2], y (depth) in [0, 4], z in [-2, 2], open at y = 0."""
    return room_walls(back_wall=back_wall)


def concat(parts):
    """One trimesh of scene parts (scenes.MeshPart) and/or trimesh meshes."""
    import trimesh

    meshes = [trimesh.Trimesh(p.vertices, p.faces, process=False) if isinstance(p, MeshPart) else p for p in parts]
    return trimesh.util.concatenate(meshes)


def plane_scene(distance=3.0, half=3.0):
    """A wall facing the sensor at y = distance (plus a side wall for the laser to hit)."""
    wall = box("wall", (-half, distance, -half), (half, distance + 0.02, half), WALL_ALBEDO)
    side = box("side", (1.5, 0.3, -half), (1.52, distance, half), WALL_ALBEDO)
    return concat([wall, side])


def box_room_scene():
    """The paper's room with a 0.6 m box on the floor at 3 m depth."""
    return concat(room_mesh() + [box("box", (-0.3, 2.7, -2.0), (0.3, 3.3, -1.4), OBJECT_ALBEDO)])


def occluder_scene():
    """A back wall at y=4 and a thin vertical slab at y=3 hiding part of it from a spot on the side wall."""
    return concat(room_mesh() + [box("slab", (-0.4, 3.0, -1.0), (0.4, 3.05, 1.0), OBJECT_ALBEDO)])


def cave_chair_scene():
    """The paper's room with the procedural chair (scenes.cave_chair): (mesh, its name)."""
    mesh, _ = cave_chair().trimesh()
    return mesh, "torch_recon.contract.scenes.cave_chair"


def paper_laser_directions(origin=(0.0, 0.0, 0.0), used_only=True):
    """Unit laser directions towards the paper's targets (Blender frame)."""
    t = reference.laser_targets_24()
    if used_only:
        t = t[list(reference.used_16_indices())]
    v = paper_to_blender_points(t) - np.asarray(origin, float)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def default_sensor(width=32, height=32, bins=160, fov_rad=math.pi / 2, bin_ps=128.0, fwhm_ps=128.0,
                   origin=(0.0, 0.0, 0.0), target=(0.0, 3.0, 0.0), laser_origin=None, start_m=0.0,
                   pulse_shape="gaussian") -> SensorSpec:
    return SensorSpec(width=width, height=height, fov_rad=fov_rad, fov_axis="x",
                      camera_to_world=look_at_c2w(origin, target).tolist(),
                      laser_origin=list(origin if laser_origin is None else laser_origin),
                      pulse=PulseSpec(pulse_shape, fwhm_ps), bin_width_ps=bin_ps, bin_width_m=ps_to_m(bin_ps),
                      bins=bins, start_m=start_m, time_gate=TimeGate(False, 0))


def write_analytic_dataset(out_dir, mesh, sensor: SensorSpec, laser_directions, *, albedo=0.8, subpixel=1,
                           window_bins=None, photons_per_pixel=None, ambient_per_bin=0.0, seed=0,
                           test_cameras=None, test_size=(32, 32), record_first_bounce=True, scene="synthetic",
                           window_start="strongest"):
    """Render `mesh` analytically and write a complete dataset; returns (path, render parts).

    photons_per_pixel: None for noise-free expected radiance, else Poisson counts
    scaled so the brightest two-bounce pixel expects that many photons.
    window_start (with window_bins): 'strongest' keeps each pixel's window_bins bins holding the most counts;
    'expected' centres them on the pixel's expected two-bounce path, shadowed pixels too (a time gate, as
    the simulator's: a window chosen by its counts would pick a shadowed pixel's densest stray photons).
    """
    cubes, parts = render_two_bounce(mesh, sensor, laser_directions, albedo=albedo, subpixel=subpixel,
                                     return_parts=True)
    noise = NoiseSpec(seed=seed)
    if photons_per_pixel is not None:
        rng = np.random.default_rng(seed)
        two = render_two_bounce(mesh, sensor, laser_directions, albedo=albedo, subpixel=subpixel,
                                include_first_bounce=False)
        scale = photons_per_pixel / max(float(two.sum(-1).max()), 1e-30)
        cubes = rng.poisson(cubes * scale + ambient_per_bin).astype(np.float32)
        noise = NoiseSpec(photon_counts=True, photons_per_pixel=float(photons_per_pixel),
                          ambient_per_bin=float(ambient_per_bin), seed=seed)
    g = sensor.bins if window_bins is None else int(window_bins)
    spots = []
    with DatasetWriter(out_dir) as w:
        for k, (ld, sp) in enumerate(zip(laser_directions, parts["spots"])):
            tr = Transient.from_dense(cubes[k], g, _gate_starts(parts, sp, sensor, g) if window_start == "expected" else None)
            ld = np.asarray(ld, float) / np.linalg.norm(ld)
            fb = None if (sp.first_bounce is None or not record_first_bounce) else [float(v) for v in sp.first_bounce]
            spots.append(Spot(id=k, laser_direction=ld.tolist(), transient_file=w.write_transient(k, tr),
                              first_bounce=fb))
        gt = render_ground_truth(w, mesh, sensor, test_cameras=test_cameras, test_size=test_size,
                                 test_fov_rad=sensor.fov_rad)
        sensor.time_gate = TimeGate(g < sensor.bins, g if g < sensor.bins else 0)
        man = Manifest(sensor=sensor, spots=spots,
                       layout=TransientLayout("windowed" if g < sensor.bins else "dense", g, "float32"),
                       noise=noise, ground_truth=gt,
                       provenance=Provenance(generator="torch_recon.contract.synthetic (analytic)",
                                             generator_version="1", seed=seed, scene=scene))
        path = w.commit(man)
    return path, parts


def _gate_starts(parts, spot, sensor: SensorSpec, g: int):
    """First bin (H, W) of a g-bin window centred on each pixel's expected two-bounce path (None: no first
    bounce: the strongest windows); pixels seeing no surface get the first g bins."""
    if spot.first_bounce is None:
        return None
    x, hit = parts["points"], parts["hit"]
    o, c = np.asarray(sensor.laser_origin, float), np.asarray(sensor.camera_to_world, float)[:3, 3]
    l = np.asarray(spot.first_bounce, float)
    path = np.linalg.norm(l - o) + np.linalg.norm(x - l, axis=-1) + np.linalg.norm(x - c, axis=-1)
    u = (path - sensor.start_m) / sensor.bin_width_m
    return np.clip(np.floor(np.where(hit, u, 0.0) - 0.5 * g + 0.5), 0, sensor.bins - g).astype(np.int64)
