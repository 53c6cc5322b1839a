"""Adaptive edge sampling and deferred shading (pipeline/adaptive_sampling.py, spot_samples.py), bpy-free.

A small analytic scene (a wall, a floor and a block in front of the wall, like sim_fixtures'
.blend) seen by a 48 x 48 sensor. The Cycles passes are stood in for by Embree hits at the
same 2 x 2 stratified sub-samples; the reference is torch_recon.contract.analytic at 16 x 16
samples per pixel (the footprint-integrated expectation).
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("embreex")

from pipeline import adaptive_sampling  # noqa: E402
from pipeline.spot_samples import SpotSampler, windows_to_dense  # noqa: E402
from torch_recon.contract import analytic  # noqa: E402
from torch_recon.contract.dataset import PulseSpec, SensorSpec  # noqa: E402
from torch_recon.contract.frames import camera_ray_directions, look_at_c2w  # noqa: E402

from tests.support.sim_fixtures import blend_trimesh  # noqa: E402

RES = 48
REF_SIDE = 16
#: lit: energy above this fraction of the median lit pixel's (rounding leaves ~1e-16 on surfaces
#: coplanar with the spot; a pixel lit over 1/256 of its footprint has ~4e-3)
LIT_FLOOR = 1e-6


@pytest.fixture(scope="module")
def scene():
    mesh, albedo = blend_trimesh()
    sensor = SensorSpec(width=RES, height=RES, fov_rad=math.pi / 2, camera_to_world=look_at_c2w([0, 0, 0], [0, 3, 0]).tolist(),
                        laser_origin=[0.0, 0.0, 0.0], pulse=PulseSpec("gaussian", 128.0), bins=320)
    # Cycles' passes, stood in for: 2 x 2 stratified hits per pixel
    c2w = np.asarray(sensor.camera_to_world)
    dirs = camera_ray_directions(RES, RES, sensor.fov_rad, "x", adaptive_sampling.stratified_offsets(2)) @ c2w[:3, :3].T
    hit, x, tri, nrm, _ = analytic._camera_hits(mesh, c2w[:3, 3], dirs.reshape(-1, 3))
    s = (4, RES, RES)
    geometry = (np.where(hit[:, None], x, 0).reshape(s + (3,)).astype(np.float32), nrm.reshape(s + (3,)).astype(np.float32),
                np.repeat(np.where(hit, albedo[np.maximum(tri, 0)], 0)[:, None], 3, 1).reshape(s + (3,)).astype(np.float32),
                hit.reshape(s))
    return mesh, albedo, sensor, geometry


def _spot(mesh, albedo, sensor, target):
    o = np.asarray(sensor.laser_origin)
    d = np.asarray(target, float) - o
    d /= np.linalg.norm(d)
    _, pts, tri, _ = analytic.first_hits(mesh, o[None], d[None])
    n = mesh.face_normals[tri[0]]
    n = n if np.dot(n, o - pts[0]) >= 0 else -n
    return SimpleNamespace(direction=d, first_bounce=pts[0], normal=n, albedo=float(albedo[tri[0]]), pixel=None,
                           first_bounce_radiance=0.0)


def _sampler(scene, adaptive=64):
    mesh, albedo, sensor, geometry = scene
    owner = np.arange(len(mesh.faces))                  # one 'object' per face: its albedo
    return SpotSampler(sensor, geometry, (mesh.vertices, mesh.faces, owner, []), albedo, adaptive, 1.0, 1.0)


#: on the floor left of the block: the block casts a shadow onto the wall and the floor
TARGET = [-1.2, 2.0, -1.0]


def _flags(sampler, spot):
    rad, path = sampler._shade(sampler.pos, sampler.nrm, sampler.alb, sampler.valid, spot)
    sh = (4, RES, RES)
    return adaptive_sampling.flag_pixels(path.reshape(sh), rad.reshape(sh) > 0, sampler.valid.reshape(sh),
                                         sampler.sensor.bin_width_m, 1.0, sampler.breaks)


def _reference(mesh, albedo, sensor, spot):
    """The footprint-integrated expectation (H, W, T): analytic at 16 x 16 samples per pixel."""
    return analytic.render_two_bounce(mesh, sensor, [spot.direction], albedo=albedo, subpixel=REF_SIDE,
                                      include_first_bounce=False)[0]


def test_edge_detector_selects_step_and_shadow_edges(scene):
    mesh, albedo, sensor, _ = scene
    sampler = _sampler(scene)
    spot = _spot(mesh, albedo, sensor, TARGET)
    flags = _flags(sampler, spot)
    # step edge: pixels whose 16 x 16 footprint sees both the block and what lies behind it
    c2w = np.asarray(sensor.camera_to_world)
    dirs = camera_ray_directions(RES, RES, sensor.fov_rad, "x", adaptive_sampling.stratified_offsets(REF_SIDE)) @ c2w[:3, :3].T
    _, _, tri, _, dist = analytic._camera_hits(mesh, c2w[:3, 3], dirs.reshape(-1, 3))
    on_block = (tri >= 24).reshape(REF_SIDE ** 2, RES, RES)          # faces 24.. belong to the block
    dist = dist.reshape(REF_SIDE ** 2, RES, RES)
    # the block and, 0.2 m or more behind it, the wall or floor (not where it stands on the floor)
    step = on_block.any(0) & ~on_block.all(0) & (dist.max(0) - dist.min(0) > 0.2)
    assert step.sum() > 8
    assert flags["depth"][step].all()
    # shadow edge: pixels partly lit (some but not all of the 256 samples)
    e = _reference(mesh, albedo, sensor, spot).sum(-1)
    # lit in the reference, but not at every one of the 2 x 2 base samples: partly lit
    penumbra = (e > LIT_FLOOR * np.median(e[e > 0])) & ~_base_lit(sampler, spot).all(0)
    assert penumbra.sum() >= 5 and flags["shadow"][penumbra].all() and flags["resample"][penumbra].all()
    # far from every edge nothing is flagged: the smooth wall interior keeps its base samples
    assert 0 < flags["edge"].mean() < 0.35


def _base_lit(sampler, spot):
    rad, _ = sampler._shade(sampler.pos, sampler.nrm, sampler.alb, sampler.valid, spot)
    return (rad > 0).reshape(4, RES, RES)


@pytest.mark.parametrize("target", [TARGET, [1.0, 3.0, 0.5]])
def test_default_sampling_meets_peak_and_shadow_goals(scene, target):
    mesh, albedo, sensor, _ = scene
    sampler = _sampler(scene)
    spot = _spot(mesh, albedo, sensor, target)
    g = sensor.bins
    start, window, needed, _ = sampler.expected_windows(spot, g)
    assert needed <= g
    cube = windows_to_dense(start, window, g).reshape(RES, RES, g)
    ref = _reference(mesh, albedo, sensor, spot)
    e, e_ref = cube.sum(-1), ref.sum(-1)
    floor = LIT_FLOOR * np.median(e_ref[e_ref > 0])
    mask, mask_ref = e > floor, e_ref > floor
    iou = (mask & mask_ref).sum() / (mask | mask_ref).sum()
    lit = e_ref > 1e-3 * np.median(e_ref[mask_ref])
    within = (np.abs(cube.argmax(-1) - ref.argmax(-1)) <= 1)[lit].mean()
    assert iou >= 0.98, iou
    assert within >= 0.99, within
    ratio = e[lit] / e_ref[lit]
    assert abs(np.median(ratio) - 1) < 0.01
    # fixed 2 x 2 sampling on the same scene is measurably worse at the shadow edges
    start4, window4, _, _ = _sampler(scene, adaptive=0).expected_windows(spot, g)
    e4 = windows_to_dense(start4, window4, g).sum(-1).reshape(RES, RES) > floor
    iou4 = (e4 & mask_ref).sum() / (e4 | mask_ref).sum()
    assert iou4 < iou


def test_footprint_samples_keep_the_mean_and_span_the_pixel():
    base = np.array([[1.0], [2.0], [3.0], [4.0]])        # 2 x 2 grid at +-1/4: 2.5 + 2 dx + 4 dy
    fine = adaptive_sampling.footprint_samples(base, 4)  # 4 x 4 grid at +-1/8, +-3/8
    assert fine.shape == (1, 16)
    assert fine.mean() == pytest.approx(2.5)
    assert fine.min() == pytest.approx(2.5 - 6 * 0.375) and fine.max() == pytest.approx(2.5 + 6 * 0.375)
    assert fine[0, 1] - fine[0, 0] == pytest.approx(2 * 0.25)           # dx fastest, as Cycles' sub-samples


def test_edge_samples_shade_with_interpolated_corner_normals():
    """Refined samples take the normal Cycles shades with: corner normals interpolated at the hit, else the face's."""
    from pipeline.spot_shading import SceneRays

    v = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    corner = np.array([[[0, 0, 1.0], [0.6, 0, 0.8], [0, 0.6, 0.8]]], np.float32)
    o, d = np.array([[0.2, 0.3, 1.0]]), np.array([[0.0, 0.0, -1.0]])
    _, _, _, n_flat = SceneRays(v, [[0, 1, 2]]).first_hits(o, d, shading_normals=True)
    assert np.allclose(n_flat, [[0, 0, 1]])
    _, _, _, n = SceneRays(v, [[0, 1, 2]], corner_normals=corner).first_hits(o, d, shading_normals=True)
    expect = 0.5 * corner[0, 0] + 0.2 * corner[0, 1] + 0.3 * corner[0, 2]
    assert np.allclose(n[0], expect / np.linalg.norm(expect), atol=1e-6)


def test_shallow_facet_edges_are_resampled_where_the_light_changes():
    """A 2 degree facet turn (too shallow for a depth edge) is flagged where the radiance changes across it."""
    h = w = 6
    nrm = np.zeros((4, h, w, 3))
    nrm[..., 1] = 1.0
    turn = np.radians(2.0)
    nrm[:, :, 3:] = [np.sin(turn), np.cos(turn), 0.0]        # columns 3.. on the next facet
    valid = np.ones((4, h, w), bool)
    creases = adaptive_sampling.normal_breaks(nrm, valid)
    assert creases[:, 2:4].all() and not creases[:, :2].any() and not creases[:, 5:].any()
    flat_light = np.ones((4, h, w))
    grazing = np.where(np.arange(w) >= 3, 0.7, 1.0) * np.ones((4, h, w))   # the light turns by 30 % there
    paths = np.full((4, h, w), 5.0)
    for radiance, flagged in ((flat_light, False), (grazing, True)):
        f = adaptive_sampling.flag_pixels(paths, radiance > 0, valid, 0.0384, 1.0, np.zeros((h, w), bool), creases,
                                          radiance)
        assert f["shading"][:, 2:4].all() == flagged and f["resample"][:, 2:4].all() == flagged
        assert not f["shading"][:, :2].any() and not f["shading"][:, 5:].any()
