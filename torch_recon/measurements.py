"""Measurements: what preprocessing extracts from the transients, what reconstruction fits.

The interface between `preprocess` (transients -> measurements) and every
reconstructor (closed-form depth, BF Lidar, the field fit). numpy arrays, saved
as one .npz; torch is only used by the code that computes or consumes them.
All positions in the Blender world frame, lengths and optical paths in metres.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .contract.errors import MeasurementsError

MEASUREMENTS_VERSION = 1


_OPTIONAL_SPOT_ARRAYS = ("pulse", "first_bounce_path_m", "amplitude", "first_bounce_recorded", "first_return_path")


@dataclass
class SpotMeasurement:
    spot_id: int
    first_bounce: np.ndarray          # (3,) l_k, estimated from the first-bounce return
    laser_direction: np.ndarray       # (3,) unit
    path_length: np.ndarray           # (H, W) float32 two-bounce optical path (m); NaN where no signal
    signal: np.ndarray                # (H, W) bool: a two-bounce peak was found (pixel sees l_k: lit)
    shadow_confidence: np.ndarray     # (H, W) float32 in [0, 1]: max of the normalised matched filter
    shadow: np.ndarray                # (H, W) bool: x_p does not see l_k (confidence below threshold, or
                                      # partly shadowed: shadow_decision); a pixel neither signal nor shadow
                                      # nor excluded is unlabelled (no evidence either way)
    excluded: np.ndarray              # (H, W) bool: pixels whose first and second bounce overlap
                                      # ('parallel' pixels along the laser ray) or are otherwise unusable
    first_bounce_pixel: tuple | None = None  # (row, col) seeing l_k, when found
    # optional extras (added by preprocess; absent in older files)
    pulse: np.ndarray | None = None           # (K,) unit-sum pulse template from the first-bounce return
    first_bounce_path_m: float | None = None  # optical path of the first-bounce return, |l-o| + |l-c|
    amplitude: np.ndarray | None = None       # (H, W) float32 raw matched-filter peak (signal strength)
    first_bounce_recorded: np.ndarray | None = None  # (3,) l_k as recorded by the simulator, if any
    first_return_path: np.ndarray | None = None  # (H, W) float32 path of the earliest significant two-bounce
                                                 # return (a thin part in front of the surface); NaN: no signal

    @property
    def usable(self) -> np.ndarray:
        """(H, W) pixels that carry a measurement (lit or shadow), i.e. not excluded."""
        return ~np.asarray(self.excluded, bool)


@dataclass
class Measurements:
    width: int
    height: int
    fov_rad: float
    fov_axis: str
    camera_to_world: np.ndarray       # (4, 4)
    laser_origin: np.ndarray          # (3,)
    bin_width_m: float
    shadow_threshold: float
    spots: list = field(default_factory=list)   # list[SpotMeasurement]
    visible_depth: np.ndarray | None = None     # (H, W) range along pixel rays (closed form, fused); NaN = unknown
    visible_confidence: np.ndarray | None = None  # (H, W) in [0, 1]
    nearest_depth: np.ndarray | None = None       # (H, W) range of the nearest surface any part of the pixel
                                                  # sees (earliest returns, fused); <= visible_depth; NaN = unknown
    settings: dict = field(default_factory=dict)  # preprocessing settings used (JSON-able)
    ray_directions: np.ndarray | None = None      # (H, W, 3) unit world directions when the sensor is no
                                                  # pinhole (e.g. a scanned real capture); None = pinhole

    @property
    def sensor_origin(self) -> np.ndarray:
        return np.asarray(self.camera_to_world)[:3, 3]

    def pixel_directions(self) -> np.ndarray:
        """(H, W, 3) unit world-frame direction of each pixel's ray (from `sensor_origin`)."""
        if self.ray_directions is not None:
            return np.asarray(self.ray_directions, np.float64)
        from .contract.frames import pixel_rays
        return pixel_rays(self.camera_to_world, self.width, self.height, self.fov_rad, self.fov_axis)[1]

    def save(self, path) -> Path:
        path = Path(path)
        arrays = {"version": np.array(MEASUREMENTS_VERSION),
                  "meta_f": np.array([self.fov_rad, self.bin_width_m, self.shadow_threshold]),
                  "meta_i": np.array([self.width, self.height]),
                  "fov_axis": np.array(self.fov_axis), "camera_to_world": self.camera_to_world,
                  "laser_origin": self.laser_origin}
        arrays["settings_json"] = np.array(json.dumps(self.settings))
        if self.ray_directions is not None:
            arrays["ray_directions"] = np.asarray(self.ray_directions, np.float64)
        if self.visible_depth is not None:
            arrays["visible_depth"] = self.visible_depth
            arrays["visible_confidence"] = self.visible_confidence
        if self.nearest_depth is not None:
            arrays["nearest_depth"] = self.nearest_depth
        for k, s in enumerate(self.spots):
            arrays[f"s{k}_id"] = np.array(s.spot_id)
            arrays[f"s{k}_fbpix"] = np.array(s.first_bounce_pixel if s.first_bounce_pixel else (-1, -1))
            for name in ("first_bounce", "laser_direction", "path_length", "signal", "shadow_confidence",
                         "shadow", "excluded"):
                arrays[f"s{k}_{name}"] = getattr(s, name)
            for name in _OPTIONAL_SPOT_ARRAYS:
                if getattr(s, name) is not None:
                    arrays[f"s{k}_{name}"] = np.asarray(getattr(s, name))
        tmp = path.with_name(path.name + ".tmp.npz")
        try:                    # whole or not at all: a failed write leaves the earlier file as it was
            np.savez_compressed(tmp, **arrays)
            tmp.replace(path)
        finally:
            tmp.unlink(missing_ok=True)
        return path

    @classmethod
    def load(cls, path) -> "Measurements":
        """Read and validate a measurements .npz (MeasurementsError naming the file and the array)."""
        import zipfile
        try:
            with np.load(path, allow_pickle=False) as z:
                return cls._from_npz(z, path)
        except MeasurementsError:
            raise
        except KeyError as exc:
            raise MeasurementsError(f"{path}: not a measurements file of this project: array {exc} missing "
                                        f"(write one with `python -m torch_recon preprocess`)") from None
        except (zipfile.BadZipFile, EOFError, ValueError, TypeError, OSError) as exc:
            if isinstance(exc, FileNotFoundError):
                raise
            raise MeasurementsError(f"{path}: unreadable measurements file (truncated or not a .npz: "
                                        f"{str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None

    @classmethod
    def _from_npz(cls, z, path) -> "Measurements":
        from .contract.units import transient_size_problem

        if int(z["version"]) != MEASUREMENTS_VERSION:
            raise MeasurementsError(f"{path}: measurements version {int(z['version'])}, "
                                    f"expected {MEASUREMENTS_VERSION}")
        fov, bw, thr = (float(v) for v in z["meta_f"])
        w, h = (int(v) for v in z["meta_i"])
        too_big = transient_size_problem(w, h, 1) if w > 0 and h > 0 else f"{w} x {h} pixels"
        if too_big:
            raise MeasurementsError(f"{path}: meta_i (width, height): {too_big}")
        c2w = np.asarray(z["camera_to_world"], np.float64)
        if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
            raise MeasurementsError(f"{path}: camera_to_world: expected a finite 4x4 matrix")
        if not (np.isfinite([fov, bw]).all() and 0 < fov < np.pi and bw > 0):
            raise MeasurementsError(f"{path}: meta_f: fov_rad {fov} or bin_width_m {bw} out of range")
        spots = []
        k = 0
        while f"s{k}_id" in z:
            fb = tuple(int(v) for v in z[f"s{k}_fbpix"])
            for name in ("path_length", "signal", "shadow_confidence", "shadow", "excluded"):
                if z[f"s{k}_{name}"].shape != (h, w):
                    raise MeasurementsError(f"{path}: s{k}_{name}: expected shape {(h, w)}, "
                                                f"got {z[f's{k}_{name}'].shape}")
            for name in ("first_bounce", "laser_direction"):
                if z[f"s{k}_{name}"].shape != (3,) or not np.isfinite(z[f"s{k}_{name}"]).all():
                    raise MeasurementsError(f"{path}: s{k}_{name}: expected 3 finite numbers")
            spots.append(SpotMeasurement(
                spot_id=int(z[f"s{k}_id"]), first_bounce=z[f"s{k}_first_bounce"],
                laser_direction=z[f"s{k}_laser_direction"], path_length=z[f"s{k}_path_length"],
                signal=z[f"s{k}_signal"], shadow_confidence=z[f"s{k}_shadow_confidence"],
                shadow=z[f"s{k}_shadow"], excluded=z[f"s{k}_excluded"],
                first_bounce_pixel=None if fb[0] < 0 else fb,
                **{name: (z[f"s{k}_{name}"] if name != "first_bounce_path_m" else float(z[f"s{k}_{name}"]))
                   for name in _OPTIONAL_SPOT_ARRAYS if f"s{k}_{name}" in z}))
            k += 1
        return cls(width=w, height=h, fov_rad=fov, fov_axis=str(z["fov_axis"]),
                   camera_to_world=z["camera_to_world"], laser_origin=z["laser_origin"], bin_width_m=bw,
                   shadow_threshold=thr, spots=spots,
                   visible_depth=z["visible_depth"] if "visible_depth" in z else None,
                   visible_confidence=z["visible_confidence"] if "visible_confidence" in z else None,
                   nearest_depth=z["nearest_depth"] if "nearest_depth" in z else None,
                   settings=json.loads(str(z["settings_json"])) if "settings_json" in z else {},
                   ray_directions=z["ray_directions"] if "ray_directions" in z else None)
