"""Measurements -> training rays: one (spot, pixel) pair per usable measurement, as flat tensors.

A pair is usable when the pixel is not excluded and is either lit (a two-bounce peak with a finite
path) or shadowed. Pixels are shared between spots, so camera rays are stored once per pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..contract.errors import MeasurementsError, UnconstrainedMeasurementsError  # noqa: F401 (Unconstrained...: re-export)
from ..measurements import Measurements


@dataclass
class RayData:
    sensor_origin: torch.Tensor    # (3,) c
    laser_origin: torch.Tensor     # (3,) o
    pixel_dirs: torch.Tensor       # (P, 3) unit camera-ray directions, P = H * W (row-major)
    spot_points: torch.Tensor      # (S, 3) first-bounce points l_k
    laser_to_spot: torch.Tensor    # (S,) |l_k - o|
    pair_pixel: torch.Tensor       # (N,) long
    pair_spot: torch.Tensor        # (N,) long
    path: torch.Tensor             # (N,) measured optical path (m); NaN where shadowed
    lit: torch.Tensor              # (N,) bool: a two-bounce peak (signal)
    shadowed: torch.Tensor         # (N,) bool
    visible_depth: torch.Tensor    # (P,) closed-form range along the pixel ray; NaN unknown
    height: int
    width: int
    nearest_depth: torch.Tensor | None = None  # (P,) range of the nearest surface any part of the pixel sees
                                               # (<= visible_depth: a thin part in front); None: unknown
    amplitude: torch.Tensor | None = None  # (S, P) matched-filter peak of each spot's strongest return (NaN where
                                           # not lit); None: unknown (recon/thin_parts.py part_coverage)
    bin_width_m: float | None = None   # the sensor's time bin as a path length (m); None: unknown

    @property
    def n_pairs(self) -> int:
        return int(self.pair_pixel.shape[0])

    def to(self, device) -> "RayData":
        for k, v in vars(self).items():
            if isinstance(v, torch.Tensor):
                setattr(self, k, v.to(device))
        return self

    def lit_index(self) -> torch.Tensor:
        return torch.nonzero(self.lit, as_tuple=False).squeeze(1)

    def sample(self, n: int, generator: torch.Generator, lit_only: bool = False) -> torch.Tensor:
        """n pair indices drawn uniformly (with replacement) from the lit pairs or all of them.

        With no lit pair at all (build_ray_data refuses such data; a hand-made RayData may have it)
        the warm-up draws from all pairs: the distance loss is then zero and only the shadow loss speaks.
        """
        if self.n_pairs == 0:
            raise UnconstrainedMeasurementsError("measurements: no usable (spot, pixel) pair "
                                                 "(every pixel excluded or unlabelled)")
        if lit_only and self._lit is None:
            self._lit = self.lit_index()
        pool = self._lit if lit_only and self._lit.numel() > 0 else None
        size = self.n_pairs if pool is None else pool.numel()
        i = torch.randint(0, size, (n,), generator=generator, device=generator.device).to(self.pair_pixel.device)
        return i if pool is None else pool[i]

    _lit: torch.Tensor | None = None

    def scene_points(self) -> np.ndarray:
        """Observed surface points (visible depth) and the spots: the extent of what was measured."""
        d = self.visible_depth.cpu().numpy()
        ok = np.isfinite(d)
        x = self.sensor_origin.cpu().numpy() + self.pixel_dirs.cpu().numpy()[ok] * d[ok, None]
        return np.concatenate([x, self.spot_points.cpu().numpy()], 0)


def pixel_angle(data, at_centre: bool = False) -> float | None:
    """Angle (radians, float64) between neighbouring pixel rays along a row of `data` (RayData, or anything
    with `pixel_dirs`, `height`, `width`): a pixel's footprint at range r is this x r. At the image's corner
    (default: the smallest, where the far surfaces' rays lie closest) or at its centre; None for an image one
    pixel wide."""
    if data.width < 2:
        return None
    dirs = data.pixel_dirs.detach().reshape(data.height, data.width, 3).cpu().double()
    j = data.width // 2 if at_centre else 1
    return float(torch.arccos((dirs[0, j - 1] * dirs[0, j]).sum().clamp(-1, 1)))


def build_ray_data(meas: Measurements) -> RayData:
    if not meas.spots:
        raise UnconstrainedMeasurementsError("measurements: no spots")
    h, w = meas.height, meas.width
    dirs = meas.pixel_directions()
    c = np.asarray(meas.sensor_origin, np.float64)
    o = np.asarray(meas.laser_origin, np.float64)
    pix, spt, path, lit, shd, ls, amp = [], [], [], [], [], [], []
    for k, s in enumerate(meas.spots):
        l = np.asarray(s.first_bounce, np.float64)
        if l.shape != (3,) or not np.all(np.isfinite(l)):
            raise MeasurementsError(f"measurements: spot {s.spot_id}: first_bounce must be 3 finite numbers, got {l}")
        for name in ("path_length", "signal", "shadow", "excluded"):
            if getattr(s, name).shape != (h, w):
                raise MeasurementsError(f"measurements: spot {s.spot_id}: {name} has shape "
                                        f"{getattr(s, name).shape}, expected {(h, w)}")
        ls.append(l)
        p = s.path_length.reshape(-1).astype(np.float32)
        sig = s.signal.reshape(-1) & np.isfinite(p) & ~s.excluded.reshape(-1)
        sh = s.shadow.reshape(-1) & ~s.signal.reshape(-1) & ~s.excluded.reshape(-1)
        use = np.flatnonzero(sig | sh)
        pix.append(use)
        spt.append(np.full(len(use), k))
        path.append(np.where(sig[use], p[use], np.nan))
        lit.append(sig[use])
        shd.append(sh[use])
        if s.amplitude is not None and np.shape(s.amplitude) == (h, w):
            amp.append(np.where(sig, np.asarray(s.amplitude, np.float32).reshape(-1), np.nan))
    ls = np.stack(ls)
    if not any(l.any() for l in lit):
        # Without a single two-bounce return there is no distance to fit and no visible surface to
        # start from: every shadow says only "something unknown blocks this", so any density that
        # fills the room fits it. Refuse instead of returning an arbitrary volume.
        n_shadow = int(sum(s.sum() for s in shd))
        raise UnconstrainedMeasurementsError(
            f"measurements: no pixel has a two-bounce return in any of the {len(meas.spots)} spot(s) "
            f"({n_shadow} shadowed pairs, 0 lit): nothing constrains the geometry. Check the time "
            f"gate (gate_max_m), the photon budget and preprocess.shadow_threshold")
    vd = meas.visible_depth
    vd = np.full(h * w, np.nan, np.float32) if vd is None else np.asarray(vd, np.float32).reshape(-1)
    f32 = lambda a: torch.as_tensor(np.asarray(a), dtype=torch.float32)  # noqa: E731
    return RayData(sensor_origin=f32(c), laser_origin=f32(o), pixel_dirs=f32(dirs.reshape(-1, 3)),
                   spot_points=f32(ls), laser_to_spot=f32(np.linalg.norm(ls - o, axis=1)),
                   pair_pixel=torch.as_tensor(np.concatenate(pix), dtype=torch.long),
                   pair_spot=torch.as_tensor(np.concatenate(spt), dtype=torch.long),
                   path=f32(np.concatenate(path)), lit=torch.as_tensor(np.concatenate(lit)),
                   shadowed=torch.as_tensor(np.concatenate(shd)), visible_depth=f32(vd), height=h, width=w,
                   nearest_depth=None if meas.nearest_depth is None else f32(np.fmin(
                       np.asarray(meas.nearest_depth, np.float32).reshape(-1), vd)),
                   amplitude=f32(np.stack(amp)) if len(amp) == len(meas.spots) else None,
                   bin_width_m=float(meas.bin_width_m))


def unexplained_lit(data: RayData, tolerance_m: float) -> torch.Tensor:
    """(N,) bool: lit pairs whose measured path is more than `tolerance_m` from the path through their pixel's
    visible point x (the fused depth). Their light came from another surface in the pixel's footprint: at a
    depth edge the spots that light the surface behind return a path 0.4-1.3 m longer (dark-room's box top in
    front of the floor), so x -> l is not the segment the light took. False where the depth is unknown."""
    from .losses import predicted_path
    d = data.visible_depth[data.pair_pixel]
    x = data.sensor_origin + data.pixel_dirs[data.pair_pixel] * d[:, None]
    via_x = predicted_path(d, torch.linalg.vector_norm(data.spot_points[data.pair_spot] - x, dim=-1),
                           data.laser_to_spot[data.pair_spot])
    return data.lit & ((data.path - via_x).abs() > tolerance_m)     # NaN compares False


def own_ranges(data: RayData, pairs) -> torch.Tensor:
    """Range along each pair's pixel ray where its own path puts the surface (the ellipsoid with foci l and c;
    NaN where there is none)."""
    from ..visible_depth import ellipsoid_range
    t = torch.full(pairs.shape, float("nan"), dtype=data.visible_depth.dtype, device=pairs.device)
    for k in torch.unique(data.pair_spot[pairs]).tolist():
        sel = data.pair_spot[pairs] == k
        p = pairs[sel]
        t[sel] = ellipsoid_range(data.path[p].double(), data.spot_points[k].double(), data.laser_origin.double(),
                                 data.sensor_origin.double(), data.pixel_dirs[data.pair_pixel[p]].double())[0].to(t.dtype)
    return t


def lit_path_tolerance(data: RayData, voxel: float, tolerance_voxels: float) -> float:
    """`unexplained_lit`'s tolerance (m) for `fast.lit_path_tolerance_voxels` (0: off): never below half a time
    bin, the error of one spot's sub-bin path (coarse bins must not turn every lit pair into an outlier)."""
    if tolerance_voxels <= 0:
        return 0.0
    return max(tolerance_voxels * voxel, 0.5 * (data.bin_width_m or 0.0))


def without_shadowed(data: RayData, pairs: torch.Tensor) -> RayData:
    """A copy of `data` (tensors shared except shadowed) in which `pairs` (bool (N,)) are not shadowed: the shadow
    loss skips them (a spot in the pixel's own plane: `voxel_evidence.in_plane_pairs`)."""
    import dataclasses
    return dataclasses.replace(data, shadowed=data.shadowed & ~pairs.to(data.shadowed.device))


def without_lit(data: RayData, pairs: torch.Tensor) -> RayData:
    """A copy of `data` (tensors shared except lit / path) in which `pairs` (bool (N,)) are neither lit nor
    shadowed: the losses skip them."""
    import dataclasses
    return dataclasses.replace(data, lit=data.lit & ~pairs,
                               path=torch.where(pairs, torch.full_like(data.path, float("nan")), data.path),
                               _lit=None)
