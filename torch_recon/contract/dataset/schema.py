"""The dataset manifest (``dataset.json``): versioned schema as dataclasses.

Documented in docs/dataset_format.md. Every field is validated on read; an error
names the file and the dotted field path and says what was expected.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from ..units import MAX_SENSOR_SIDE, bin_widths_consistent, ps_to_m, transient_size_problem
from .field_reader import DatasetError, FieldReader  # noqa: F401  (DatasetError: re-exported)

SCHEMA_NAME = "platolidar.dataset"
SCHEMA_VERSION = "1.1"
SUPPORTED_VERSIONS = ("1.0", "1.1")
#: 1.1 adds measurement-only datasets (``kind``, ``spots[].measurement_file``) and per-pixel
#: ray directions (``sensor.ray_directions_file``); a manifest without them is written as 1.0.
KINDS = ("transients", "measurements")
MANIFEST_NAME = "dataset.json"


@dataclass
class PulseSpec:
    shape: str = "gaussian"  # 'gaussian' or 'box' (single bin)
    fwhm_ps: float = 128.0

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        return cls(shape=ck.string(d, "shape", f"{path}.shape", choices=("gaussian", "box")),
                   fwhm_ps=ck.number(d, "fwhm_ps", f"{path}.fwhm_ps", positive=True))


@dataclass
class TimeGate:
    """Keep only `window_bins` bins around the expected return (enabled) or all bins."""

    enabled: bool = False
    window_bins: int = 0

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        en = ck.boolean(d, "enabled", f"{path}.enabled")
        wb = ck.integer(d, "window_bins", f"{path}.window_bins", minimum=0)
        if en and wb < 1:
            ck.fail(f"{path}.window_bins", "expected >= 1 when the time gate is enabled")
        return cls(enabled=en, window_bins=wb)


@dataclass
class SensorSpec:
    width: int = 512
    height: int = 512
    fov_rad: float = math.pi / 2
    fov_axis: str = "x"
    camera_to_world: list = field(default_factory=lambda: np.eye(4).tolist())
    laser_origin: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    pulse: PulseSpec = field(default_factory=PulseSpec)
    bin_width_ps: float = 128.0
    bin_width_m: float = 0.0384
    bins: int = 391
    start_m: float = 0.0
    time_gate: TimeGate = field(default_factory=TimeGate)
    ray_directions_file: str | None = None  # 1.1: EXR of per-pixel unit ray directions (X, Y, Z), world
                                            # frame, from the sensor origin; None = pinhole rays

    @property
    def sensor_origin(self) -> np.ndarray:
        return np.asarray(self.camera_to_world, dtype=np.float64)[:3, 3]

    @property
    def end_m(self) -> float:
        return self.start_m + self.bins * self.bin_width_m

    def bin_centres_m(self) -> np.ndarray:
        return self.start_m + (np.arange(self.bins) + 0.5) * self.bin_width_m

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        s = cls(
            width=ck.integer(d, "width", f"{path}.width", minimum=1),
            height=ck.integer(d, "height", f"{path}.height", minimum=1),
            fov_rad=ck.number(d, "fov_rad", f"{path}.fov_rad", positive=True),
            fov_axis=ck.string(d, "fov_axis", f"{path}.fov_axis", choices=("x", "y")),
            camera_to_world=ck.matrix4(d, "camera_to_world", f"{path}.camera_to_world"),
            laser_origin=ck.vector(d, "laser_origin", f"{path}.laser_origin"),
            pulse=PulseSpec.from_dict(ck.get(d, "pulse", f"{path}.pulse"), ck, f"{path}.pulse"),
            bin_width_ps=ck.number(d, "bin_width_ps", f"{path}.bin_width_ps", positive=True),
            bin_width_m=ck.number(d, "bin_width_m", f"{path}.bin_width_m", positive=True),
            bins=ck.integer(d, "bins", f"{path}.bins", minimum=1),
            start_m=ck.number(d, "start_m", f"{path}.start_m", nonneg=True),
            time_gate=TimeGate.from_dict(ck.get(d, "time_gate", f"{path}.time_gate"), ck, f"{path}.time_gate"),
            ray_directions_file=ck.string(d, "ray_directions_file", f"{path}.ray_directions_file", default=None),
        )
        if s.fov_rad >= math.pi:
            ck.fail(f"{path}.fov_rad", f"expected a field of view below pi radians, got {s.fov_rad}")
        if not bin_widths_consistent(s.bin_width_m, s.bin_width_ps):
            ck.fail(f"{path}.bin_width_m", f"{s.bin_width_m} m disagrees with bin_width_ps={s.bin_width_ps} "
                                          f"(= {ps_to_m(s.bin_width_ps):.6f} m of optical path)")
        if s.time_gate.enabled and s.time_gate.window_bins > s.bins:
            ck.fail(f"{path}.time_gate.window_bins", f"window of {s.time_gate.window_bins} bins exceeds bins={s.bins}")
        too_big = transient_size_problem(s.width, s.height, s.bins)   # refused before anything is allocated
        if too_big:
            ck.fail(f"{path}.{'width' if max(s.width, s.height) > MAX_SENSOR_SIDE else 'bins'}", too_big)
        return s


@dataclass
class NoiseSpec:
    """Sensor model. Rates are expected photons per pixel per bin (before Poisson sampling)."""

    photon_counts: bool = False          # Poisson sampling of counts
    photons_per_pixel: float = 0.0       # two-bounce signal budget: mean photons of the brightest lit pixel
    ambient_per_bin: float = 0.0         # ambient background before the wavelength filter
    wavelength_filter_factor: float = 1.0  # fraction of ambient light passing the band-pass filter
    dark_counts_per_bin: float = 0.0
    seed: int = 0

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        n = cls(
            photon_counts=ck.boolean(d, "photon_counts", f"{path}.photon_counts"),
            photons_per_pixel=ck.number(d, "photons_per_pixel", f"{path}.photons_per_pixel", nonneg=True),
            ambient_per_bin=ck.number(d, "ambient_per_bin", f"{path}.ambient_per_bin", nonneg=True),
            wavelength_filter_factor=ck.number(d, "wavelength_filter_factor", f"{path}.wavelength_filter_factor",
                                               nonneg=True),
            dark_counts_per_bin=ck.number(d, "dark_counts_per_bin", f"{path}.dark_counts_per_bin", nonneg=True),
            seed=ck.integer(d, "seed", f"{path}.seed", minimum=0),
        )
        if n.wavelength_filter_factor > 1:
            ck.fail(f"{path}.wavelength_filter_factor", f"expected a fraction in [0, 1], got {n.wavelength_filter_factor}")
        return n


@dataclass
class Spot:
    id: int
    laser_direction: list                 # unit vector from the laser origin, world frame
    transient_file: str | None            # relative to the dataset directory (None: measurements kind)
    enabled: bool = True
    first_bounce: list | None = None      # l_k when known (world frame, m)
    content_hash: str | None = None       # hash of the simulator inputs that affect this spot
    measurement_file: str | None = None   # 1.1, measurements kind: EXR of per-pixel path_m / lit / valid

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str, kind: str = "transients"):
        s = cls(
            id=ck.integer(d, "id", f"{path}.id", minimum=0),
            laser_direction=ck.vector(d, "laser_direction", f"{path}.laser_direction"),
            transient_file=ck.string(d, "transient_file", f"{path}.transient_file",
                                     **({} if kind == "transients" else {"default": None})),
            measurement_file=ck.string(d, "measurement_file", f"{path}.measurement_file",
                                       **({} if kind == "measurements" else {"default": None})),
            enabled=ck.boolean(d, "enabled", f"{path}.enabled", default=True),
            first_bounce=ck.vector(d, "first_bounce", f"{path}.first_bounce", default=None),
            content_hash=ck.string(d, "content_hash", f"{path}.content_hash", default=None),
        )
        n = np.linalg.norm(s.laser_direction)
        if abs(n - 1.0) > 1e-3:
            ck.fail(f"{path}.laser_direction", f"expected a unit vector, got length {n:.6f}")
        if kind == "measurements" and s.first_bounce is None:
            ck.fail(f"{path}.first_bounce", "a measurements dataset has no transients to find l_k in: "
                                            "expected the first-bounce point")
        return s


@dataclass
class TransientLayout:
    """How per-spot transients are stored (see docs/dataset_format.md).

    'windowed': per pixel a start bin and `window_bins` consecutive values.
    'dense' is the same with window_bins == bins and every start 0.
    """

    kind: str = "dense"
    window_bins: int = 391
    sample_type: str = "float32"  # 'float32' or 'float16'

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        return cls(kind=ck.string(d, "kind", f"{path}.kind", choices=("dense", "windowed")),
                   window_bins=ck.integer(d, "window_bins", f"{path}.window_bins", minimum=1),
                   sample_type=ck.string(d, "sample_type", f"{path}.sample_type", choices=("float32", "float16")))


@dataclass
class GroundTruthViews:
    """Ground-truth test views: cameras inline, depths (range, m) in one EXR stack."""

    width: int
    height: int
    fov_rad: float
    fov_axis: str
    camera_to_world: list        # list of 4x4
    depth_file: str              # EXR of shape (N*H, W), channel 'range'; inf where nothing is hit
    trajectory: str | None = None  # 'scene' (dolly + orbit around the objects) or 'paper' (the 139-view preset)
    n_invalid: int = 0           # requested views dropped because the camera was not in free space

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        cams = ck.get(d, "camera_to_world", f"{path}.camera_to_world")
        if not isinstance(cams, list) or not cams:
            ck.fail(f"{path}.camera_to_world", "expected a non-empty list of 4x4 matrices")
        return cls(width=ck.integer(d, "width", f"{path}.width", minimum=1),
                   height=ck.integer(d, "height", f"{path}.height", minimum=1),
                   fov_rad=ck.number(d, "fov_rad", f"{path}.fov_rad", positive=True),
                   fov_axis=ck.string(d, "fov_axis", f"{path}.fov_axis", choices=("x", "y")),
                   camera_to_world=[ck.matrix4({"m": m}, "m", f"{path}.camera_to_world[{i}]")
                                    for i, m in enumerate(cams)],
                   depth_file=ck.string(d, "depth_file", f"{path}.depth_file"),
                   trajectory=ck.string(d, "trajectory", f"{path}.trajectory", default=None,
                                        choices=("scene", "paper")),
                   n_invalid=ck.integer(d, "n_invalid", f"{path}.n_invalid", default=0, minimum=0))


@dataclass
class GroundTruthObject:
    """One labelled object of the scene (the rest of the GT mesh is the room)."""

    name: str                    # label: a child collection of 'Objects', or an object's name
    mesh_file: str               # .ply in the world frame (its triangles are also in ground_truth.mesh_file)
    parts: list = field(default_factory=list)   # Blender object names that make it

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        parts = ck.get(d, "parts", f"{path}.parts", default=[])
        if not isinstance(parts, list) or not all(isinstance(p, str) for p in parts):
            ck.fail(f"{path}.parts", f"expected a list of object names, got {parts!r}")
        name = ck.string(d, "name", f"{path}.name")
        if not name.strip():
            ck.fail(f"{path}.name", "expected a non-empty label")
        return cls(name=name, mesh_file=ck.string(d, "mesh_file", f"{path}.mesh_file"), parts=parts)


@dataclass
class GroundTruth:
    train_depth_file: str | None = None   # EXR (H, W) channel 'range' (m along the pixel ray; inf = no hit)
    mesh_file: str | None = None          # .ply in the world frame
    test_views: GroundTruthViews | None = None
    objects: list = field(default_factory=list)   # list[GroundTruthObject]: the objects that matter

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        tv = ck.get(d, "test_views", f"{path}.test_views", default=None)
        objs = ck.get(d, "objects", f"{path}.objects", default=[])
        if not isinstance(objs, list):
            ck.fail(f"{path}.objects", "expected a list of objects")
        objects = [GroundTruthObject.from_dict(o, ck, f"{path}.objects[{i}]") for i, o in enumerate(objs)]
        seen = set()
        for i, o in enumerate(objects):
            if o.name in seen:
                ck.fail(f"{path}.objects[{i}].name", f"label {o.name!r} appears twice")
            seen.add(o.name)
        return cls(train_depth_file=ck.string(d, "train_depth_file", f"{path}.train_depth_file", default=None),
                   mesh_file=ck.string(d, "mesh_file", f"{path}.mesh_file", default=None),
                   test_views=None if tv is None else GroundTruthViews.from_dict(tv, ck, f"{path}.test_views"),
                   objects=objects)


@dataclass
class Provenance:
    generator: str = "unknown"
    generator_version: str = "0"
    seed: int = 0
    blender_version: str | None = None
    scene: str | None = None
    created_utc: str | None = None
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d, ck: FieldReader, path: str):
        extra = ck.get(d, "extra", f"{path}.extra", default={})
        if not isinstance(extra, dict):
            ck.fail(f"{path}.extra", "expected an object")
        return cls(generator=ck.string(d, "generator", f"{path}.generator"),
                   generator_version=ck.string(d, "generator_version", f"{path}.generator_version"),
                   seed=ck.integer(d, "seed", f"{path}.seed", minimum=0),
                   blender_version=ck.string(d, "blender_version", f"{path}.blender_version", default=None),
                   scene=ck.string(d, "scene", f"{path}.scene", default=None),
                   created_utc=ck.string(d, "created_utc", f"{path}.created_utc", default=None),
                   extra=extra)


UNITS = {"length": "m", "optical_path": "m", "time": "ps", "angle": "rad",
         "frame": "blender_world_z_up", "camera": "opengl"}


@dataclass
class Manifest:
    sensor: SensorSpec
    spots: list
    layout: TransientLayout = field(default_factory=TransientLayout)
    noise: NoiseSpec = field(default_factory=NoiseSpec)
    ground_truth: GroundTruth = field(default_factory=GroundTruth)
    rgb_files: list = field(default_factory=list)   # per spot, optional (PNG/EXR), same order as spots
    provenance: Provenance = field(default_factory=Provenance)
    schema_version: str = field(default=SCHEMA_VERSION, compare=False)  # as read; writers pick 1.0 or 1.1
    kind: str = "transients"   # 1.1: 'measurements' = per-pixel two-bounce paths and shadow masks, no transients

    @property
    def uses_1_1(self) -> bool:
        return (self.kind != "transients" or self.sensor.ray_directions_file is not None
                or any(s.measurement_file is not None for s in self.spots))

    def to_dict(self) -> dict[str, Any]:
        """The manifest as JSON; written as version 1.0 (byte-identical to 1.0 writers) unless it needs 1.1."""
        d = asdict(self)
        d.pop("schema_version")
        if not self.uses_1_1:
            d.pop("kind")
            d["sensor"].pop("ray_directions_file")
            for sp in d["spots"]:
                sp.pop("measurement_file")
        return {"schema": SCHEMA_NAME, "schema_version": "1.1" if self.uses_1_1 else "1.0", "units": dict(UNITS),
                **d}

    def spot(self, spot_id: int) -> Spot:
        for s in self.spots:
            if s.id == spot_id:
                return s
        raise KeyError(f"no spot with id {spot_id}")

    @property
    def enabled_spots(self) -> list:
        return [s for s in self.spots if s.enabled]

    @classmethod
    def from_dict(cls, d: dict, file: str = MANIFEST_NAME) -> "Manifest":
        ck = FieldReader(file)
        if not isinstance(d, dict):
            ck.fail("", "expected a JSON object at the top level")
        if ck.string(d, "schema", "schema") != SCHEMA_NAME:
            ck.fail("schema", f"expected {SCHEMA_NAME!r}, got {d.get('schema')!r}")
        ver = ck.string(d, "schema_version", "schema_version")
        if ver not in SUPPORTED_VERSIONS:
            ck.fail("schema_version", f"unknown schema version {ver!r}; this reader knows {list(SUPPORTED_VERSIONS)}")
        kind = ck.string(d, "kind", "kind", default="transients", choices=KINDS)
        if ver == "1.0" and "kind" in d:
            ck.fail("kind", "needs schema_version 1.1")
        units = ck.get(d, "units", "units")
        if units != UNITS:
            ck.fail("units", f"expected {UNITS}, got {units!r}")
        sensor = SensorSpec.from_dict(ck.get(d, "sensor", "sensor"), ck, "sensor")
        layout = TransientLayout.from_dict(ck.get(d, "layout", "layout"), ck, "layout")
        if layout.window_bins > sensor.bins:
            ck.fail("layout.window_bins", f"window of {layout.window_bins} bins exceeds sensor.bins={sensor.bins}")
        if layout.kind == "dense" and layout.window_bins != sensor.bins:
            ck.fail("layout.window_bins", f"a dense layout stores all bins: expected {sensor.bins}, "
                                          f"got {layout.window_bins}")
        spots_raw = ck.get(d, "spots", "spots")
        if not isinstance(spots_raw, list):
            ck.fail("spots", "expected a list")
        spots = [Spot.from_dict(s, ck, f"spots[{i}]", kind) for i, s in enumerate(spots_raw)]
        if ver == "1.0" and (sensor.ray_directions_file is not None
                             or any(s.measurement_file is not None for s in spots)):
            ck.fail("schema_version", "ray_directions_file / measurement_file need schema_version 1.1")
        if sensor.ray_directions_file is not None and kind != "measurements":
            ck.fail("sensor.ray_directions_file", "per-pixel rays are only supported with kind 'measurements'")
        ids = [s.id for s in spots]
        if len(set(ids)) != len(ids):
            ck.fail("spots", f"spot ids must be unique, got {ids}")
        rgb = ck.get(d, "rgb_files", "rgb_files", default=[])
        if not isinstance(rgb, list) or (rgb and len(rgb) != len(spots)) or not all(isinstance(x, str) for x in rgb):
            ck.fail("rgb_files", "expected an empty list or one file name per spot")
        return cls(sensor=sensor, spots=spots, layout=layout,
                   noise=NoiseSpec.from_dict(ck.get(d, "noise", "noise"), ck, "noise"),
                   ground_truth=GroundTruth.from_dict(ck.get(d, "ground_truth", "ground_truth", default={}), ck,
                                                      "ground_truth"),
                   rgb_files=rgb,
                   provenance=Provenance.from_dict(ck.get(d, "provenance", "provenance"), ck, "provenance"),
                   schema_version=ver, kind=kind)
