import json
import math

import numpy as np
import pytest

from torch_recon.contract import frames

from torch_recon.contract.reference import REFERENCE_FILE as REF  # noqa: E402


def test_paper_mapping_is_a_rotation():
    r = frames.BLENDER_FROM_PAPER
    np.testing.assert_allclose(r @ r.T, np.eye(3))
    assert np.linalg.det(r) == pytest.approx(1.0)
    # paper: y up, camera looks along +z, image-right is -x
    np.testing.assert_allclose(frames.paper_to_blender_points([0, 1, 0]), [0, 0, 1])
    np.testing.assert_allclose(frames.paper_to_blender_points([0, 0, 1]), [0, 1, 0])
    np.testing.assert_allclose(frames.paper_to_blender_points([-1, 0, 0]), [1, 0, 0])


def test_points_round_trip():
    p = np.random.default_rng(0).normal(size=(10, 3))
    np.testing.assert_allclose(frames.blender_to_paper_points(frames.paper_to_blender_points(p)), p)


def test_c2w_round_trips():
    c2w = frames.look_at_c2w([0.3, -1, 0.2], [0, 3, -1])
    np.testing.assert_allclose(frames.paper_to_blender_c2w(frames.blender_to_paper_c2w(c2w)), c2w, atol=1e-12)
    np.testing.assert_allclose(frames.mitsuba_to_opengl_c2w(frames.opengl_to_mitsuba_c2w(c2w)), c2w, atol=1e-12)
    # Mitsuba cameras look along +z_cam: the world direction of +z equals OpenGL's -z
    m = frames.opengl_to_mitsuba_c2w(c2w)
    np.testing.assert_allclose(m[:3, 2], -c2w[:3, 2])


def test_look_at_axes():
    c2w = frames.look_at_c2w([0, 0, 0], [0, 3, 0], up=[0, 0, 1])
    np.testing.assert_allclose(c2w[:3, 0], [1, 0, 0], atol=1e-12)   # right = +X
    np.testing.assert_allclose(c2w[:3, 1], [0, 0, 1], atol=1e-12)   # up = +Z
    np.testing.assert_allclose(c2w[:3, 2], [0, -1, 0], atol=1e-12)  # back = -forward
    with pytest.raises(ValueError, match="coincides"):
        frames.look_at_c2w([1, 1, 1], [1, 1, 1])
    with pytest.raises(ValueError, match="parallel"):
        frames.look_at_c2w([0, 0, 0], [0, 0, 5], up=[0, 0, 1])


def test_pixel_rays_fov_and_orientation():
    c2w = frames.look_at_c2w([0, 0, 0], [0, 3, 0])
    o, d = frames.pixel_rays(c2w, 4, 2, math.pi / 2)
    assert d.shape == (2, 4, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0)
    # row 0 is the top (+Z), column 0 the left (-X)
    assert d[0, 0, 2] > 0 and d[1, 0, 2] < 0
    assert d[0, 0, 0] < 0 and d[0, -1, 0] > 0
    # fov on x: the outer pixel edges are at +-45 degrees; centre of the outer pixel at atan(0.75)
    assert math.atan2(d[0, -1, 0], d[0, -1, 1]) == pytest.approx(math.atan(0.75), abs=0.02)
    # a wall 3 m ahead: a 90 degree fov sees +-3 m at the edges
    f = frames.focal_length_px(4, 2, math.pi / 2)
    assert f == pytest.approx(2.0)
    with pytest.raises(ValueError):
        frames.focal_length_px(4, 2, math.pi)
    with pytest.raises(ValueError):
        frames.focal_length_px(4, 2, 1.0, "z")


def test_projection_inverts_rays():
    c2w = frames.look_at_c2w([0.1, -0.2, 0.3], [0, 3, 0])
    w, h = 16, 12
    _, d = frames.pixel_rays(c2w, w, h, 1.3, "x")
    pts = c2w[:3, 3] + 2.5 * d
    col, row, depth = frames.project_points(c2w, w, h, 1.3, pts)
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    np.testing.assert_allclose(col, jj, atol=1e-9)
    np.testing.assert_allclose(row, ii, atol=1e-9)
    assert np.all(depth > 0)


def test_subpixel_offsets():
    d = frames.camera_ray_directions(8, 8, 1.0, "y", subpixel_offsets=[(0, 0), (-0.5, -0.5), (0.5, 0.5)])
    assert d.shape == (3, 8, 8, 3)
    np.testing.assert_allclose(d[0], frames.camera_ray_directions(8, 8, 1.0, "y"))
    # the (+0.5, +0.5) corner of pixel (r, c) equals the (-0.5, -0.5) corner of (r + 1, c + 1)
    np.testing.assert_allclose(d[2, :-1, :-1], d[1, 1:, 1:], atol=1e-12)


def test_test_views_match_reference():
    ref = json.loads(REF.read_text())["test_views"]
    cams = frames.paper_test_view_cameras()
    assert len(cams) == ref["dolly"]["count"] + ref["orbit"]["count"]
    paper = frames.blender_to_paper_points(cams[:, :3, 3])
    np.testing.assert_allclose(paper[5], [0, -1.5, 0.06282151815625667 * 5], atol=1e-12)
    a = -math.pi / 2 + 2 * math.pi * 7 / 100
    np.testing.assert_allclose(paper[39 + 7], [0.99 * math.cos(a), -1.5, 3 + 0.99 * math.sin(a)], atol=1e-12)
    # every view looks at the chair centre
    target = frames.paper_to_blender_points(ref["orbit"]["look_at"])
    fwd = -cams[:, :3, 2]
    to_t = target - cams[:, :3, 3]
    to_t /= np.linalg.norm(to_t, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("ij,ij->i", fwd, to_t), 1.0, atol=1e-9)
    # counts are configurable, and the dolly keeps its span
    c2 = frames.paper_test_view_cameras(dolly_count=3, orbit_count=4)
    assert len(c2) == 7
    np.testing.assert_allclose(frames.blender_to_paper_points(c2[2, :3, 3])[2], 0.06282151815625667 * 38)
    with pytest.raises(ValueError):
        frames.paper_test_view_cameras(dolly_count=-1)
