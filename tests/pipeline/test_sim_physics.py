"""The Cycles simulator against the independent analytic renderer (trimesh/Embree, torch_recon.contract.analytic).

The simulator runs as a user runs it (`python pipeline/simulate.py --example cave-chair ...`);
expectations come from the bpy-free geometry of torch_recon/contract/scenes.py, ray cast by Embree.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("bpy")

from torch_recon.contract import scenes  # noqa: E402
from torch_recon.contract import analytic  # noqa: E402
from torch_recon.contract.dataset import load_dataset  # noqa: E402
from torch_recon.contract.frames import camera_ray_directions  # noqa: E402

from tests.support.sim_fixtures import simulate  # noqa: E402


REF_SIDE = 8


@pytest.fixture(scope="module")
def cave():
    mesh, albedo = scenes.cave_chair().trimesh()
    return mesh, albedo


def _runs(tmp_path_factory, res, spots, subpixel):
    out = tmp_path_factory.mktemp(f"cave{res}") / "ds"
    simulate(out, "--example", "cave-chair", "--resolution", res, "--spots", spots, "--photons", 0,
             "--subpixel", subpixel, "--test-views", "2,3", "--test-view-resolution", 32)
    return load_dataset(out)


@pytest.fixture(scope="module")
def ds64(tmp_path_factory):
    # 16 sub-samples: at 64x64 a grazing pixel spans several bins and 4 samples histogram it coarsely
    return _runs(tmp_path_factory, 64, 4, 16)


@pytest.fixture(scope="module")
def ds128(tmp_path_factory):
    return _runs(tmp_path_factory, 128, 3, 4)


def _compare(ds, mesh, albedo):
    """Per spot: simulated dense cube, analytic cube (same sub-pixel grid) and analytic parts."""
    s = ds.sensor
    # the footprint-integrated expectation: finer than the simulator's base samples, since its
    # adaptive sampling integrates edge and grazing pixels more finely than 2 x 2 samples would
    side = max(int(round(np.sqrt(ds.manifest.provenance.extra["subpixel_samples"]))), REF_SIDE)
    out = []
    for spot, tr in ds.iter_transients():
        ref, parts = analytic.render_two_bounce(mesh, s, [spot.laser_direction], albedo=albedo, subpixel=side,
                                                return_parts=True)
        out.append((spot, tr.dense(), ref[0], parts))
    return out


@pytest.fixture(scope="module")
def cmp64(ds64, cave):
    return _compare(ds64, *cave)


@pytest.fixture(scope="module")
def cmp128(ds128, cave):
    return _compare(ds128, *cave)


def _lit_and_paths(ref, parts, s):
    sp = parts["spots"][0]
    e = ref.sum(-1)
    fb = np.unravel_index(np.argmax(e), e.shape)      # the first-bounce pixel dominates
    lit = e > 1e-3 * np.median(e[e > 0])
    lit[fb] = False
    x = parts["points"]
    path = (np.linalg.norm(sp.first_bounce - np.asarray(s.laser_origin)) + np.linalg.norm(x - sp.first_bounce, axis=-1)
            + np.linalg.norm(x - s.sensor_origin, axis=-1))
    return lit, path, fb


@pytest.mark.parametrize("res,fraction", [(64, 0.90), (128, 0.99)])
def test_peak_bin_matches_analytic_path(request, cave, res, fraction):
    ds = request.getfixturevalue(f"ds{res}")
    s = ds.sensor
    fractions = []
    for spot, cube, ref, parts in request.getfixturevalue(f"cmp{res}"):
        lit, path, _ = _lit_and_paths(ref, parts, s)
        expect_bin = np.floor((path - s.start_m) / s.bin_width_m)
        within = np.abs(cube.argmax(-1) - expect_bin) <= 1
        fractions.append(within[lit].mean())
        # against the footprint-integrated expectation (same sub-samples), nearly every pixel agrees
        assert (np.abs(cube.argmax(-1) - ref.argmax(-1)) <= 1)[lit].mean() >= 0.995
    assert min(fractions) >= fraction, fractions


def test_energy_matches_analytic_radiometry(ds128, cmp128):
    for spot, cube, ref, parts in cmp128:
        lit, _, fb = _lit_and_paths(ref, parts, ds128.sensor)
        ratio = cube.sum(-1)[lit] / ref.sum(-1)[lit]
        assert abs(np.median(ratio) - 1.0) < 0.01
        assert np.mean(np.abs(ratio - 1.0) < 0.05) >= 0.97          # per pixel within 5 %
        assert cube.sum(-1)[fb] == pytest.approx(ref.sum(-1)[fb], rel=1e-3)   # first-bounce return


def test_shadow_cores_have_no_two_bounce_signal(cmp128):
    from scipy.ndimage import binary_erosion

    for spot, cube, ref, parts in cmp128:
        dark = (ref.sum(-1) == 0) & parts["hit"]
        core = binary_erosion(dark, np.ones((3, 3), bool))           # away from penumbra / pixel edges
        assert core.sum() > 50
        e = cube.sum(-1)
        assert e[core].max() <= 1e-6 * e.max()


def test_first_bounce_point_matches_laser_hit(ds64, cave):
    mesh, _ = cave
    s = ds64.sensor
    o = np.asarray(s.laser_origin)
    for spot in ds64.manifest.spots:
        d = np.asarray(spot.laser_direction)
        hit, pts, _, _ = analytic.first_hits(mesh, (o + 1e-4 * d)[None], d[None])
        assert hit[0]
        assert np.linalg.norm(pts[0] - np.asarray(spot.first_bounce)) < 0.01


def test_ground_truth_depths_and_mesh(ds64, cave):
    import trimesh

    mesh, _ = cave
    s = ds64.sensor
    depth = ds64.train_depth()
    ref = analytic.range_image(mesh, s.camera_to_world, s.width, s.height, s.fov_rad, s.fov_axis)
    assert np.allclose(depth, ref, atol=1e-4)
    # range, not planar depth: the corner pixel is farther than its z
    dirs = camera_ray_directions(s.width, s.height, s.fov_rad, s.fov_axis)
    assert depth[0, 0] * abs(dirs[0, 0, 2]) < depth[0, 0] - 0.5
    views, cams, depths = ds64.test_views()
    assert depths.shape == (5, 32, 32) and np.isfinite(depths).mean() > 0.9
    gt = trimesh.load(ds64.path(ds64.manifest.ground_truth.mesh_file), process=False)
    assert np.allclose(gt.bounds, mesh.bounds, atol=1e-5)


@pytest.mark.parametrize("name", ["occluders", "curved-wall", "low-albedo"])
def test_other_scenes_match_analytic(tmp_path, name):
    """Objects occluding each other, a curved wall, dark walls: same energy, shadows and paths."""
    from scipy.ndimage import binary_erosion

    simulate(tmp_path / "ds", "--example", name, "--resolution", 48, "--spots", 2, "--photons", 0, "--no-gt")
    ds = load_dataset(tmp_path / "ds")
    mesh, albedo = scenes.example(name).trimesh()
    for spot, cube, ref, parts in _compare(ds, mesh, albedo):
        lit, _, _ = _lit_and_paths(ref, parts, ds.sensor)
        ratio = cube.sum(-1)[lit] / ref.sum(-1)[lit]
        assert abs(np.median(ratio) - 1.0) < 0.01 and np.mean(np.abs(ratio - 1.0) < 0.05) >= 0.95
        assert (np.abs(cube.argmax(-1) - ref.argmax(-1)) <= 1)[lit].mean() >= 0.98   # multi-depth pixels: ties
        core = binary_erosion((ref.sum(-1) == 0) & parts["hit"], np.ones((3, 3), bool))
        assert core.any() and cube.sum(-1)[core].max() <= 1e-6 * cube.sum(-1).max()
