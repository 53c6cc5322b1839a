"""Frames and cameras, in one module (round-trip tested in tests/torch_recon/contract/test_frames.py).

The project's one frame is Blender's world: right-handed, Z up, metres.
Cameras use the Blender/OpenGL convention: the camera looks down its local -Z,
+Y is image-up, +X is image-right. A camera-to-world matrix is 4x4 with
columns (right, up, back, origin).

The PlatoNeRF paper's world (Mitsuba) is y-up, the camera looks along +z and
image-right is -x. ``contract/data/platonerf_cave.json`` maps it to Blender by
(x, y, z) -> (-x, z, y) (a proper rotation, determinant +1); the released
``transforms_train.json`` stores OpenGL camera-to-world matrices in that y-up
world.
"""

from __future__ import annotations

import math
import numpy as np

from .reference import PaperTestViews

#: Rotation taking paper (y-up) coordinates to Blender (Z-up) coordinates.
BLENDER_FROM_PAPER = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
PAPER_FROM_BLENDER = BLENDER_FROM_PAPER.T

#: Blender camera axes -> Mitsuba camera axes (Mitsuba: x left, y up, z forward).
MITSUBA_CAM_FROM_OPENGL_CAM = np.diag([-1.0, 1.0, -1.0])


def _as_points(p) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.shape[-1] != 3:
        raise ValueError(f"expected points with a last axis of 3, got shape {p.shape}")
    return p


def paper_to_blender_points(p) -> np.ndarray:
    """Points or directions (..., 3) from the paper's y-up frame to Blender's."""
    return _as_points(p) @ BLENDER_FROM_PAPER.T


def blender_to_paper_points(p) -> np.ndarray:
    return _as_points(p) @ PAPER_FROM_BLENDER.T


def _rigid(rotation: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = rotation
    return m


def paper_to_blender_c2w(c2w_paper) -> np.ndarray:
    """An OpenGL-convention camera-to-world matrix from the paper's world to Blender's.

    The camera convention (OpenGL == Blender) is unchanged; only the world rotates.
    """
    return _rigid(BLENDER_FROM_PAPER) @ np.asarray(c2w_paper, dtype=np.float64)


def blender_to_paper_c2w(c2w_blender) -> np.ndarray:
    return _rigid(PAPER_FROM_BLENDER) @ np.asarray(c2w_blender, dtype=np.float64)


def opengl_to_mitsuba_c2w(c2w_opengl) -> np.ndarray:
    """Camera-to-world with OpenGL camera axes -> Mitsuba camera axes (same world)."""
    return np.asarray(c2w_opengl, dtype=np.float64) @ _rigid(MITSUBA_CAM_FROM_OPENGL_CAM)


def mitsuba_to_opengl_c2w(c2w_mitsuba) -> np.ndarray:
    return np.asarray(c2w_mitsuba, dtype=np.float64) @ _rigid(MITSUBA_CAM_FROM_OPENGL_CAM.T)


def look_at_c2w(origin, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Blender/OpenGL camera-to-world for a camera at `origin` looking at `target`.

    Raises ValueError when origin == target or `up` is parallel to the view direction.
    """
    origin = np.asarray(origin, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - origin
    n = np.linalg.norm(forward)
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError("look_at: target coincides with the camera origin")
    forward /= n
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    rn = np.linalg.norm(right)
    if rn < 1e-9:
        raise ValueError("look_at: 'up' is parallel to the viewing direction")
    right /= rn
    cam_up = np.cross(right, forward)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, cam_up, -forward, origin
    return m


def focal_length_px(width: int, height: int, fov_rad: float, fov_axis: str = "x") -> float:
    """Pinhole focal length in pixels for a field of view along `fov_axis`."""
    if not (0.0 < fov_rad < math.pi):
        raise ValueError(f"field of view must be in (0, pi) radians, got {fov_rad}")
    if fov_axis == "x":
        return 0.5 * width / math.tan(0.5 * fov_rad)
    if fov_axis == "y":
        return 0.5 * height / math.tan(0.5 * fov_rad)
    raise ValueError(f"fov_axis must be 'x' or 'y', got {fov_axis!r}")


def camera_ray_directions(width: int, height: int, fov_rad: float, fov_axis: str = "x",
                          subpixel_offsets=None) -> np.ndarray:
    """Unit ray directions in camera space (OpenGL axes), shape (H, W, 3) or (S, H, W, 3).

    Rays go through pixel centres (row 0 is the image top, column 0 the left), or
    through ``centre + offset`` for each (dx, dy) in `subpixel_offsets`, offsets in
    pixels in [-0.5, 0.5] with +dx right and +dy down.
    """
    f = focal_length_px(width, height, fov_rad, fov_axis)
    offsets = np.zeros((1, 2)) if subpixel_offsets is None else np.asarray(subpixel_offsets, np.float64)
    cols = np.arange(width, dtype=np.float64) + 0.5
    rows = np.arange(height, dtype=np.float64) + 0.5
    out = np.empty((len(offsets), height, width, 3))
    for s, (dx, dy) in enumerate(offsets):
        out[s, :, :, 0] = ((cols + dx) - 0.5 * width)[None, :] / f
        out[s, :, :, 1] = -((rows + dy) - 0.5 * height)[:, None] / f
        out[s, :, :, 2] = -1.0
    out /= np.linalg.norm(out, axis=-1, keepdims=True)
    return out[0] if subpixel_offsets is None else out


def pixel_rays(c2w, width: int, height: int, fov_rad: float, fov_axis: str = "x"):
    """World-space rays through pixel centres: (origins (H, W, 3), unit directions (H, W, 3))."""
    c2w = np.asarray(c2w, dtype=np.float64)
    dirs = camera_ray_directions(width, height, fov_rad, fov_axis) @ c2w[:3, :3].T
    origins = np.broadcast_to(c2w[:3, 3], dirs.shape).copy()
    return origins, dirs


def project_points(c2w, width: int, height: int, fov_rad: float, points, fov_axis: str = "x"):
    """World points -> continuous pixel coordinates (col, row) and camera-space depth (> 0 in front)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    w2c = np.linalg.inv(c2w)
    p = _as_points(points) @ w2c[:3, :3].T + w2c[:3, 3]
    depth = -p[..., 2]
    f = focal_length_px(width, height, fov_rad, fov_axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        col = 0.5 * width + f * p[..., 0] / depth
        row = 0.5 * height - f * p[..., 1] / depth
    return col, row, depth


def paper_test_view_cameras(traj=None, dolly_count: int | None = None,
                      orbit_count: int | None = None) -> np.ndarray:
    """Camera-to-world matrices (N, 4, 4) of the test views, in Blender's frame.

    With a different `dolly_count` the dolly spans the same distance as the
    paper's (38 steps of `dolly_step_m`).
    """
    traj = traj or PaperTestViews.from_reference()
    nd = traj.dolly_count if dolly_count is None else int(dolly_count)
    no = traj.orbit_count if orbit_count is None else int(orbit_count)
    if nd < 0 or no < 0:
        raise ValueError("test-view counts must be >= 0")
    cx, cz = traj.centre_xz
    target = np.array([cx, traj.height_m, cz])
    up = paper_to_blender_points([0.0, 1.0, 0.0])
    span = traj.dolly_step_m * (traj.dolly_count - 1)
    cams = []
    for i in range(nd):
        z = 0.0 if nd == 1 else span * i / (nd - 1)
        origin = np.array([cx, traj.height_m, z])
        cams.append(look_at_c2w(paper_to_blender_points(origin), paper_to_blender_points(target), up))
    for k in range(no):
        a = traj.orbit_start_rad + 2.0 * math.pi * k / max(no, 1)
        origin = np.array([cx + traj.orbit_radius_m * math.cos(a), traj.height_m,
                           cz + traj.orbit_radius_m * math.sin(a)])
        cams.append(look_at_c2w(paper_to_blender_points(origin), paper_to_blender_points(target), up))
    return np.stack(cams) if cams else np.zeros((0, 4, 4))


#: The PlatoNeRF training code's frame from the paper's (Mitsuba) world: a half turn about y.
#: Their preprocessing writes light origins and aimed-at points in this frame (x and z negated),
#: and negates rows 0 and 2 of the stored camera pose before casting rays, which lands the
#: camera in the same frame. Self-inverse.
PLATONERF_TRAIN_FROM_PAPER = np.diag([-1.0, 1.0, -1.0])


def blender_to_platonerf_train_points(p) -> np.ndarray:
    """Points or directions (..., 3) from Blender's frame to the PlatoNeRF training frame."""
    return blender_to_paper_points(p) @ PLATONERF_TRAIN_FROM_PAPER.T


def platonerf_train_to_blender_points(p) -> np.ndarray:
    return paper_to_blender_points(_as_points(p) @ PLATONERF_TRAIN_FROM_PAPER.T)
