"""Reading (validated) and writing (atomic) dataset directories.

Atomicity: a writer fills a hidden staging directory beside the target and only
renames it into place in `commit()`, after the manifest is written. The
manifest is the last file written, so a directory without `dataset.json` is
never a dataset, and an interrupted run leaves the previous dataset untouched.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np

from .exr import read_exr, read_exr_channel, write_exr
from .schema import MANIFEST_NAME, DatasetError, GroundTruthViews, Manifest
from .staging import StagedDir
from .transient import Transient

TRANSIENT_DIR = "transients"
#: top-level names a dataset writer of this project writes (older datasets have no record of them)
DATASET_ENTRIES = (MANIFEST_NAME, TRANSIENT_DIR, "ground_truth", "rgb", "*.tmp")
WINDOW_CHANNEL = "w{:04d}"


MEASUREMENT_DIR = "measurements"
RAY_DIRECTIONS_FILE = "sensor/ray_directions.exr"
MEASUREMENT_CHANNELS = ("path_m", "lit", "valid")


def transient_relpath(spot_id: int) -> str:
    return f"{TRANSIENT_DIR}/spot_{spot_id:04d}.exr"


def measurement_relpath(spot_id: int) -> str:
    return f"{MEASUREMENT_DIR}/spot_{spot_id:04d}.exr"


def check_array(arr: np.ndarray, file: str, field: str, nonneg: bool = False, allow_inf: bool = False):
    """DatasetError naming `file` and `field` for NaN or infinite values (+inf allowed with `allow_inf`: no
    return) and, with `nonneg`, negative ones."""
    bad = ~np.isfinite(arr) if not allow_inf else np.isnan(arr)
    if allow_inf:
        bad |= np.isneginf(arr)
    if np.any(bad):
        n = int(bad.sum())
        raise DatasetError(file, field, f"{n} value(s) are NaN or infinite")
    if nonneg and np.any(arr < 0):
        raise DatasetError(file, field, f"{int((arr < 0).sum())} negative value(s); counts must be >= 0")


def read_json(path: Path):
    """A JSON file's content, or DatasetError naming the file."""
    try:
        return json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DatasetError(str(path), "", f"not valid JSON ({exc})") from None


class Dataset:
    """A validated dataset directory. Transients are read lazily, validated on read."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        mpath = self.root / MANIFEST_NAME
        if self.root.is_file():     # e.g. the dataset's own dataset.json
            raise DatasetError(str(self.root), "", f"expected a dataset directory, got a file (the folder holding "
                                                   f"it is {self.root.parent})")
        if not self.root.is_dir():
            raise DatasetError(str(self.root), "", "dataset directory does not exist")
        if not mpath.is_file():
            raise DatasetError(str(mpath), "", "manifest missing: not a dataset directory, or an incomplete one")
        raw = read_json(mpath)
        self.manifest = Manifest.from_dict(raw, file=str(mpath))
        for i, s in enumerate(self.manifest.spots):
            name = "transient_file" if self.manifest.kind == "transients" else "measurement_file"
            if not (self.root / getattr(s, name)).is_file():
                raise DatasetError(str(self.root / getattr(s, name)), f"spots[{i}].{name}", "file is missing")
        rays = self.manifest.sensor.ray_directions_file
        if rays is not None and not (self.root / rays).is_file():
            raise DatasetError(str(self.root / rays), "sensor.ray_directions_file", "file is missing")
        gt = self.manifest.ground_truth
        for name in ("train_depth_file", "mesh_file"):
            rel = getattr(gt, name)
            if rel is not None and not (self.root / rel).is_file():
                raise DatasetError(str(self.root / rel), f"ground_truth.{name}", "file is missing")
        for i, o in enumerate(gt.objects):
            if not (self.root / o.mesh_file).is_file():
                raise DatasetError(str(self.root / o.mesh_file), f"ground_truth.objects[{i}].mesh_file",
                                   "file is missing")
        if gt.test_views is not None and not (self.root / gt.test_views.depth_file).is_file():
            raise DatasetError(str(self.root / gt.test_views.depth_file), "ground_truth.test_views.depth_file",
                               "file is missing")

    @property
    def sensor(self):
        return self.manifest.sensor

    def path(self, rel: str) -> Path:
        return self.root / rel

    def read_transient(self, spot_id: int) -> Transient:
        m = self.manifest
        if m.kind != "transients":
            raise DatasetError(str(self.root / MANIFEST_NAME), "kind",
                               f"a {m.kind!r} dataset has no transients (read_spot_measurement instead)")
        idx = next((i for i, s in enumerate(m.spots) if s.id == spot_id), None)
        if idx is None:
            raise KeyError(f"{self.root}: no spot with id {spot_id}")
        return read_transient_file(self.root / m.spots[idx].transient_file, m, f"spots[{idx}].transient_file")

    def iter_transients(self, enabled_only: bool = True):
        for s in (self.manifest.enabled_spots if enabled_only else self.manifest.spots):
            yield s, self.read_transient(s.id)

    def _spot_index(self, spot_id: int) -> int:
        idx = next((i for i, s in enumerate(self.manifest.spots) if s.id == spot_id), None)
        if idx is None:
            raise KeyError(f"{self.root}: no spot with id {spot_id}")
        return idx

    def read_spot_measurement(self, spot_id: int) -> dict[str, np.ndarray]:
        """Measurements kind: {'path_m': (H, W) float32 two-bounce optical path (m, 0 where none),
        'lit': (H, W) bool two-bounce return seen, 'valid': (H, W) bool pixel usable}."""
        i = self._spot_index(spot_id)
        rel, s = self.manifest.spots[i].measurement_file, self.sensor
        field = f"spots[{i}].measurement_file"
        if rel is None:
            raise DatasetError(str(self.root / MANIFEST_NAME), field, "this spot has no measurement file")
        chans, _ = read_exr(self.root / rel, field)
        f = str(self.root / rel)
        for name in MEASUREMENT_CHANNELS:
            if name not in chans:
                raise DatasetError(f, field, f"EXR channel {name!r} missing (has {sorted(chans)})")
            if chans[name].shape != (s.height, s.width):
                raise DatasetError(f, field, f"expected images of {s.height}x{s.width}, got {chans[name].shape}")
        path = chans["path_m"].astype(np.float32)
        check_array(path, f, field, nonneg=True)
        lit, valid = chans["lit"] > 0.5, chans["valid"] > 0.5
        if np.any(lit & valid & (path <= 0)):
            raise DatasetError(f, field, f"{int((lit & valid & (path <= 0)).sum())} lit pixel(s) without a "
                                         "positive two-bounce path")
        return {"path_m": path, "lit": lit, "valid": valid}

    def ray_directions(self) -> np.ndarray | None:
        """(H, W, 3) unit world-frame ray directions from the sensor origin, or None for pinhole rays."""
        rel = self.sensor.ray_directions_file
        if rel is None:
            return None
        field, f, s = "sensor.ray_directions_file", str(self.root / rel), self.sensor
        chans, _ = read_exr(self.root / rel, field)
        if any(c not in chans for c in "XYZ"):
            raise DatasetError(f, field, f"expected channels X, Y, Z, got {sorted(chans)}")
        d = np.stack([chans[c] for c in "XYZ"], -1).astype(np.float64)
        if d.shape != (s.height, s.width, 3):
            raise DatasetError(f, field, f"expected images of {s.height}x{s.width}, got {d.shape[:2]}")
        check_array(d, f, field)
        n = np.linalg.norm(d, axis=-1)
        if np.any(np.abs(n - 1.0) > 1e-3):
            raise DatasetError(f, field, f"{int((np.abs(n - 1) > 1e-3).sum())} direction(s) are not unit vectors")
        return d / n[..., None]

    def train_depth(self) -> np.ndarray | None:
        rel = self.manifest.ground_truth.train_depth_file
        if rel is None:
            return None
        s = self.sensor
        d = read_exr_channel(self.root / rel, "range", "ground_truth.train_depth_file")
        if d.shape != (s.height, s.width):
            raise DatasetError(str(self.root / rel), "ground_truth.train_depth_file",
                               f"expected shape {(s.height, s.width)}, got {d.shape}")
        check_array(d, str(self.root / rel), "ground_truth.train_depth_file", nonneg=True, allow_inf=True)
        return d.astype(np.float32)

    def test_views(self) -> tuple[GroundTruthViews, np.ndarray, np.ndarray] | None:
        """(views, camera_to_world (N, 4, 4), range depths (N, H, W) with inf where nothing is hit)."""
        tv = self.manifest.ground_truth.test_views
        if tv is None:
            return None
        path = self.root / tv.depth_file
        d = read_exr_channel(path, "range", "ground_truth.test_views.depth_file")
        n = len(tv.camera_to_world)
        if d.shape != (n * tv.height, tv.width):
            raise DatasetError(str(path), "ground_truth.test_views.depth_file",
                               f"expected shape {(n * tv.height, tv.width)} ({n} views), got {d.shape}")
        check_array(d, str(path), "ground_truth.test_views.depth_file", nonneg=True, allow_inf=True)
        return tv, np.asarray(tv.camera_to_world), d.reshape(n, tv.height, tv.width).astype(np.float32)

    def content_hash(self) -> str:
        """sha256 over the manifest and every file it names (identifies the data a result came from)."""
        m = self.manifest
        gt = m.ground_truth
        named = [MANIFEST_NAME, *(s.transient_file for s in m.spots), *(s.measurement_file for s in m.spots),
                 m.sensor.ray_directions_file, *(m.rgb_files or []), gt.train_depth_file, gt.mesh_file,
                 *([gt.test_views.depth_file] if gt.test_views is not None else [])]
        named = [r for r in named if r]     # measurements-only datasets name no transients, and vice versa
        h = hashlib.sha256()   # a user's files beside the dataset (notes, fit outputs) do not change it
        for p in sorted(p for p in {self.root / r for r in named} if p.is_file()):
            h.update(str(p.relative_to(self.root)).encode())
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
        return h.hexdigest()


def read_transient_file(path: Path, manifest: Manifest, field: str) -> Transient:
    s, lay = manifest.sensor, manifest.layout
    chans, header = read_exr(path, field)
    f = str(path)
    if "start" not in chans:
        raise DatasetError(f, field, "EXR channel 'start' missing")
    names = [WINDOW_CHANNEL.format(j) for j in range(lay.window_bins)]
    missing = [n for n in names if n not in chans]
    extra = sorted(set(chans) - set(names) - {"start"})
    if missing or extra:
        raise DatasetError(f, field, f"expected {lay.window_bins} window channels w0000.. (layout.window_bins); "
                                     f"missing {missing[:3]}{'...' if len(missing) > 3 else ''}, unexpected {extra[:3]}")
    start = chans["start"]
    if start.shape != (s.height, s.width):
        raise DatasetError(f, field, f"expected images of {s.height}x{s.width} (sensor.height x sensor.width), "
                                     f"got {start.shape[0]}x{start.shape[1]}")
    start = start.astype(np.int64)
    if lay.kind == "dense" and np.any(start):
        raise DatasetError(f, field, "dense layout: every 'start' must be 0")
    if np.any(start + lay.window_bins > s.bins):
        raise DatasetError(f, field, f"window runs past sensor.bins={s.bins} at {int((start + lay.window_bins > s.bins).sum())} pixel(s)")
    # filled channel by channel, each freed once copied: np.stack + astype held two more cube copies
    window = np.empty((s.height, s.width, lay.window_bins), np.float32)
    for j, n in enumerate(names):
        window[..., j] = chans.pop(n)
    check_array(window, f, field, nonneg=True)
    return Transient(start, window, s.bins)


def write_transient_file(path: Path, tr: Transient, sample_type: str = "float32") -> None:
    dt = np.float16 if sample_type == "float16" else np.float32
    if sample_type == "float16" and np.any(tr.window > np.finfo(np.float16).max):
        raise ValueError("counts exceed the float16 range; use sample_type='float32'")
    chans = {"start": tr.start_bin.astype(np.uint32)}
    bins_first = np.ascontiguousarray(np.moveaxis(tr.window, 2, 0), dtype=dt)   # one pass, not G strided copies
    for j in range(tr.window_bins):
        chans[WINDOW_CHANNEL.format(j)] = bins_first[j]
    # RLE: half of ZIP's CPU time on these mostly-zero windows (the simulator's writer is its bottleneck)
    write_exr(path, chans, {"platolidar_bins": int(tr.bins)}, compression="rle")


def load_dataset(root: str | os.PathLike) -> Dataset:
    """Open and validate a dataset directory (raises DatasetError naming file and field)."""
    return Dataset(root)


class DatasetWriter:
    """Writes a dataset atomically: `with DatasetWriter(out) as w: ...; w.commit(manifest)`.

    Leaving the block without `commit` (an exception, Ctrl-C) removes the staging
    directory and leaves any existing dataset at `out` as it was.
    """

    def __init__(self, out_dir: str | os.PathLike, overwrite: bool = True):
        self.out_dir = Path(out_dir).absolute()
        if not overwrite and (self.out_dir / MANIFEST_NAME).is_file():
            raise FileExistsError(f"{self.out_dir}: a dataset is already there (overwrite=False)")
        self._stage = StagedDir(self.out_dir, "dataset", legacy=DATASET_ENTRIES, marker=MANIFEST_NAME)
        self.staging = self._stage.path
        self.committed = False

    @staticmethod
    def check_target(out_dir) -> None:
        """Refuse now (FileExistsError) an output folder a writer would refuse later."""
        StagedDir.check(out_dir, "dataset", legacy=DATASET_ENTRIES, marker=MANIFEST_NAME)

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self._stage.discard()
        return False

    def path(self, rel: str) -> Path:
        p = self.staging / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def write_transient(self, spot_id: int, tr: Transient, sample_type: str = "float32") -> str:
        rel = transient_relpath(spot_id)
        write_transient_file(self.path(rel), tr, sample_type)
        return rel

    def reuse_file(self, source: str | os.PathLike, rel: str) -> str:
        """Bring an unchanged file from an earlier dataset (hard link when possible)."""
        dst = self.path(rel)
        try:
            os.link(source, dst)
        except OSError:
            shutil.copy2(source, dst)
        return rel

    def write_spot_measurement(self, spot_id: int, path_m, lit, valid) -> str:
        """Measurements kind: one spot's per-pixel two-bounce path (m; 0 where none) and masks."""
        rel = measurement_relpath(spot_id)
        write_exr(self.path(rel), {"path_m": np.asarray(path_m, np.float32),
                                   "lit": np.asarray(lit, np.float16), "valid": np.asarray(valid, np.float16)})
        return rel

    def write_ray_directions(self, dirs: np.ndarray) -> str:
        d = np.asarray(dirs, np.float32)
        write_exr(self.path(RAY_DIRECTIONS_FILE), {c: d[..., i] for i, c in enumerate("XYZ")})
        return RAY_DIRECTIONS_FILE

    def write_depth(self, rel: str, depth: np.ndarray) -> str:
        """Range depth (H, W) or a stack (N, H, W) -> EXR channel 'range' (stack as (N*H, W))."""
        d = np.asarray(depth, dtype=np.float32)
        if d.ndim == 3:
            d = d.reshape(-1, d.shape[-1])
        if np.any(np.isnan(d)) or np.any(d < 0):
            raise ValueError(f"{rel}: depth has NaN or negative values")
        write_exr(self.path(rel), {"range": d})
        return rel

    def write_json(self, rel: str, obj) -> str:
        self.path(rel).write_text(json.dumps(obj, indent=1))
        return rel

    def commit(self, manifest: Manifest) -> Path:
        d = manifest.to_dict()
        Manifest.from_dict(json.loads(json.dumps(d)), file=str(self.out_dir / MANIFEST_NAME))  # validate first
        tmp = self.staging / (MANIFEST_NAME + ".tmp")
        with open(tmp, "w") as f:
            json.dump(d, f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.staging / MANIFEST_NAME)
        Dataset(self.staging)  # every referenced file exists
        self._stage.commit()
        self.committed = True
        return self.out_dir
