"""Synthetic datasets with known answers, from the analytic two-bounce renderer (no Cycles, no torch).

Used by the measurement/evaluation tests and benchmarks: simple trimesh scenes
(a wall at a known distance, a box in the paper's room, an occluder casting a
known shadow) rendered by `torch_recon.analytic` and written with DatasetWriter,
including ground truth (train range image, mesh, test views).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .analytic import range_image, render_two_bounce
from .dataset import (DatasetWriter, GroundTruth, GroundTruthViews, Manifest, NoiseSpec, Provenance, SensorSpec, Spot,
                      TimeGate, Transient, TransientLayout)
from .dataset.schema import PulseSpec
from .frames import look_at_c2w
from .units import ps_to_m


def box_mesh(lo, hi):
    import trimesh
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return b


def room_mesh(back_wall=True, thickness=0.02):
    """The paper's room in Blender's frame: x in [-2, 2], y (depth) in [0, 4], z in [-2, 2], open at y = 0."""
    t = thickness
    parts = [box_mesh((-2 - t, 0, -2 - t), (-2, 4 + t, 2 + t)), box_mesh((2, 0, -2 - t), (2 + t, 4 + t, 2 + t)),
             box_mesh((-2, 0, -2 - t), (2, 4 + t, -2)), box_mesh((-2, 0, 2), (2, 4 + t, 2 + t))]
    if back_wall:
        parts.append(box_mesh((-2, 4, -2), (2, 4 + t, 2)))
    return parts


def concat(parts):
    import trimesh
    return trimesh.util.concatenate(parts)


def plane_scene(distance=3.0, half=3.0):
    """A wall facing the sensor at y = distance (plus a side wall for the laser to hit)."""
    wall = box_mesh((-half, distance, -half), (half, distance + 0.02, half))
    side = box_mesh((1.5, 0.3, -half), (1.52, distance, half))
    return concat([wall, side])


def box_room_scene():
    """The paper's room with a 0.6 m box on the floor at 3 m depth."""
    return concat(room_mesh() + [box_mesh((-0.3, 2.7, -2.0), (0.3, 3.3, -1.4))])


def occluder_scene():
    """A back wall at y=4 and a thin vertical slab at y=3 hiding part of it from a spot on the side wall."""
    return concat(room_mesh() + [box_mesh((-0.4, 3.0, -1.0), (0.4, 3.05, 1.0))])


def cave_chair_scene():
    """The paper's room with a chair made of boxes (pipeline/scenes.py when present, else built here)."""
    try:
        from pipeline.scenes import cave_chair
        mesh, _ = cave_chair().trimesh()
        return mesh, "pipeline.scenes.cave_chair"
    except Exception:  # noqa: BLE001 - fall back to a local copy of the same recipe
        s, base = 1.25, np.array([0.0, 3.0, -2.0])
        parts = [((-0.22, -0.21, 0.40), (0.22, 0.21, 0.44)), ((-0.22, 0.18, 0.44), (0.22, 0.21, 0.80))]
        for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            x, y = sx * 0.20 - 0.015, sy * 0.19 - 0.015
            parts.append(((x, y, 0.0), (x + 0.03, y + 0.03, 0.40)))
        boxes = [box_mesh(np.array(lo) * s + base, np.array(hi) * s + base) for lo, hi in parts]
        return concat(room_mesh() + boxes), "torch_recon.synthetic (local chair of boxes)"


def paper_laser_directions(origin=(0.0, 0.0, 0.0), used_only=True):
    """Unit laser directions towards the paper's targets (Blender frame)."""
    from .frames import paper_to_blender_points
    import json
    ref = Path(__file__).resolve().parents[1] / "pipeline" / "data" / "platonerf_cave.json"
    d = json.loads(ref.read_text())
    t = np.asarray(d["laser_targets_24"], float)
    if used_only:
        t = t[d["laser_targets_used_16_indices"]]
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
                           test_cameras=None, test_size=(32, 32), record_first_bounce=True, scene="synthetic"):
    """Render `mesh` analytically and write a complete dataset; returns (path, render parts).

    photons_per_pixel: None for noise-free expected radiance, else Poisson counts
    scaled so the brightest two-bounce pixel expects that many photons.
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
            tr = Transient.from_dense(cubes[k], g)
            ld = np.asarray(ld, float) / np.linalg.norm(ld)
            fb = None if (sp.first_bounce is None or not record_first_bounce) else [float(v) for v in sp.first_bounce]
            spots.append(Spot(id=k, laser_direction=ld.tolist(), transient_file=w.write_transient(k, tr),
                              first_bounce=fb))
        mesh.export(w.path("ground_truth/mesh.ply"))
        train = range_image(mesh, sensor.camera_to_world, sensor.width, sensor.height, sensor.fov_rad,
                            sensor.fov_axis)
        gt = GroundTruth(train_depth_file=w.write_depth("ground_truth/train_depth.exr", train),
                         mesh_file="ground_truth/mesh.ply")
        if test_cameras is not None and len(test_cameras):
            tw, th = test_size
            depths = np.stack([range_image(mesh, c, tw, th, sensor.fov_rad, "x") for c in test_cameras])
            gt.test_views = GroundTruthViews(width=tw, height=th, fov_rad=sensor.fov_rad, fov_axis="x",
                                             camera_to_world=[np.asarray(c).tolist() for c in test_cameras],
                                             depth_file=w.write_depth("ground_truth/test_depth.exr", depths))
        sensor.time_gate = TimeGate(g < sensor.bins, g if g < sensor.bins else 0)
        man = Manifest(sensor=sensor, spots=spots,
                       layout=TransientLayout("windowed" if g < sensor.bins else "dense", g, "float32"),
                       noise=noise, ground_truth=gt,
                       provenance=Provenance(generator="torch_recon.synthetic (analytic)", generator_version="1",
                                             seed=seed, scene=scene))
        path = w.commit(man)
    return path, parts
