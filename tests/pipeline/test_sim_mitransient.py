"""The Cycles simulator (pipeline/simulate.py) against an independent path tracer: mitransient (Mitsuba 3), slow.

Needs `pip install mitransient "mitsuba==3.8.0"` (not a project dependency; see
../shared/REFERENCE_RENDERER.md); skipped without it. mitransient's laser is a projector
emitter in its own units, so energies are compared up to one global factor per spot
(the factor must be the same for every pixel), and time by each pixel's energy-weighted
mean bin (mitransient jitters samples over the pixel; the simulator takes stratified ones).
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("bpy")
mi = pytest.importorskip("mitsuba")

from torch_recon.contract import scenes  # noqa: E402
from torch_recon.contract.dataset import load_dataset  # noqa: E402

from tests.support.sim_fixtures import simulate  # noqa: E402

RES, SPP = 64, 256


def mitransient_cube(ex, target, sensor, tmp_path):
    import trimesh

    mi.set_variant("llvm_ad_mono")
    pytest.importorskip("mitransient")
    shapes = {}
    for i, p in enumerate(ex.parts):
        fn = str(tmp_path / f"part{i}.ply")
        trimesh.Trimesh(p.vertices, p.faces, process=False).export(fn)
        shapes[f"s{i}"] = {"type": "ply", "filename": fn, "face_normals": True,
                           "bsdf": {"type": "diffuse", "reflectance": {"type": "uniform", "value": p.albedo}}}
    t = mi.ScalarTransform4f
    c2w = np.asarray(sensor.camera_to_world)
    eye, ahead, up = c2w[:3, 3], c2w[:3, 3] - c2w[:3, 2], c2w[:3, 1]
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_nlos_path", "nlos_laser_sampling": True,
                       "account_first_and_last_bounces": True, "max_depth": 2, "temporal_filter": "box"},
        "sensor": {"type": "perspective", "fov": float(np.degrees(sensor.fov_rad)), "fov_axis": sensor.fov_axis,
                   "near_clip": 1e-4, "to_world": t().look_at(origin=eye.tolist(), target=ahead.tolist(),
                                                              up=up.tolist()),
                   "film": {"type": "transient_hdr_film", "width": sensor.width, "height": sensor.height,
                            "temporal_bins": sensor.bins, "bin_width_opl": sensor.bin_width_m,
                            "start_opl": sensor.start_m, "rfilter": {"type": "box"}}},
        "laser": {"type": "projector", "fov": 0.2, "irradiance": 1.0,
                  "to_world": t().look_at(origin=list(sensor.laser_origin), target=list(target), up=[0, 0, 1])},
        **shapes}, optimize=False)
    _, transient = mi.render(scene, spp=SPP)
    return np.array(transient)[..., 0]


@pytest.mark.slow
@pytest.mark.parametrize("spot", [4, 9])
def test_matches_mitransient(tmp_path, spot):
    ex = scenes.cave_chair()
    target = ex.spot_targets[spot]
    simulate(tmp_path / "ds", "--example", "cave-chair", "--resolution", RES, "--photons", 0, "--no-gt",
             "--spot-list=" + ",".join(map(str, target)))
    ds = load_dataset(tmp_path / "ds")
    (_, tr), = ds.iter_transients()
    ours = tr.dense().astype(np.float64)
    ref = mitransient_cube(ex, target, ds.sensor, tmp_path).astype(np.float64)
    e, e_ref = ours.sum(-1), ref.sum(-1)
    e[np.unravel_index(np.argmax(e), e.shape)] = 0          # mitransient records no first bounce
    lit = (e > 1e-3 * np.median(e[e > 0])) & (e_ref > 0)
    assert ((e > 0) != (e_ref > 0)).mean() < 0.01           # the same pixels lit and in shadow
    ratio = e_ref[lit] / e[lit]
    lo, hi = np.percentile(ratio, [5, 95])
    assert hi / lo < 1.06                                    # one factor for all pixels (cosines, 1/r^2 agree)
    assert np.corrcoef(e.ravel(), e_ref.ravel())[0, 1] > 0.998
    bins = np.arange(ours.shape[-1]) + 0.5
    mean_bin = (ours * bins).sum(-1)[lit] / ours.sum(-1)[lit]
    mean_bin_ref = (ref * bins).sum(-1)[lit] / e_ref[lit]
    assert np.mean(np.abs(mean_bin - mean_bin_ref) < 0.5) >= 0.97
