"""The authors' PlatoNeRF dataset layout, both ways (frame table: docs/dataset_format.md).

What their preprocessing writes and their loader / training assume:
- ``transforms_train.json``: ``camera_angle_x`` in DEGREES (the loader applies np.radians);
  ``walls`` (a list of planes) and per frame ``file_path`` WITHOUT ``.npy`` (the loader appends it),
  ``transform_matrix``, ``light_origin``, ``light_direction``, ``wall_idx_cam``, ``wall_idx_light``.
- ``transform_matrix`` is the OpenGL camera-to-world in the paper's (Mitsuba) y-up world. Their
  training negates rows 0 and 2 before casting rays, i.e. works in the paper's world turned half
  about y ("training frame"); lights are written directly in that frame (preprocessing negates x
  and z of the light origin and aimed-at point). ``light_direction`` is the aimed-at point with the
  laser at the origin, normalised on load: we write a unit direction (the same thing there).
- one float16 cube (H, W, T) per frame, row 0 at the image top, bins of 0.0384 m of optical path
  from 0 (their code hard-codes the width and reads bin k as the path (k + 1) * width).
- all 24 frames; the config's ``ignore`` list drops some (chair: [0, 1, 2, 3, 10, 13, 20, 22]):
  our ``enabled`` flags. Ignored frames need no cube (their loader skips them before loading).
- their rays go through pixel corners (column i -> x = i - W/2), ours through centres (i + 0.5):
  the cube data is the same pixels either way (Mitsuba samples the pixel area); their rays are
  off by half a pixel, which we document and do not bake into the data.

On export we add a ``platolidar`` block (full manifest, cube scale, bin padding) so our data
round-trips; on import we keep their raw values in ``provenance.extra['platonerf']`` so their
data round-trips bit-exactly.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..frames import (blender_to_paper_c2w, blender_to_platonerf_train_points, paper_to_blender_c2w,
                      platonerf_train_to_blender_points)
from ..units import bin_widths_consistent, deg_to_rad, rad_to_deg
from .platonerf_truth import export_ground_truth, import_ground_truth
from .schema import DatasetError, Manifest, NoiseSpec, Provenance, PulseSpec, SensorSpec, Spot, TimeGate, \
    TransientLayout
from .field_reader import FieldReader
from .store import Dataset, DatasetWriter, check_array, read_json, transient_relpath
from .transient import Transient

TRANSFORMS = "transforms_train.json"
CONFIG_TXT = "platonerf_config.txt"
PAPER_BIN_WIDTH_PS = 128.0
PAPER_BIN_WIDTH_M = 0.0384          # their TIME_RES_M
FLOAT16_TARGET_MAX = 2.0 ** 14      # exported cubes: the brightest bin lands in [2^13, 2^14]
WALL_HALF_EXTENT_M = 0.5


def _camera_angle_x_deg(s: SensorSpec) -> float:
    fov = s.fov_rad if s.fov_axis == "x" else 2.0 * math.atan(math.tan(0.5 * s.fov_rad) * s.width / s.height)
    return rad_to_deg(fov)


def cube_scale_for(max_value: float) -> float:
    """A power of two (exact in float arithmetic) taking `max_value` to [2^13, 2^14]: float16-safe."""
    if not max_value > 0 or not math.isfinite(max_value):
        return 1.0
    return 2.0 ** (math.log2(FLOAT16_TARGET_MAX) - math.ceil(math.log2(max_value)))


def _frame_slots(m: Manifest, s: SensorSpec):
    """(frame index, our spot or None, direction): the imported frames, the paper's 24, or one per spot.

    The paper's scenes index 24 laser targets and keep 16; our datasets keep the simulated ones with
    their index as the spot id. With the paper's sensor and every spot on its paper direction, all 24
    frames are written (missing ones without a cube, in `ignore`); otherwise one frame per spot.
    """
    from ..frames import paper_to_blender_points
    from ..synthetic import paper_laser_directions

    by_id = {sp.id: sp for sp in m.spots}
    raw = (m.provenance.extra.get("platonerf") or {}).get("frames") or []
    if raw and all(sp.id < len(raw) for sp in m.spots):     # imported from their layout: its frames
        return [(i, by_id.get(i), np.asarray(by_id[i].laser_direction) if i in by_id else
                 platonerf_train_to_blender_points(np.asarray(r["light_direction"]) /
                                                   np.linalg.norm(r["light_direction"])))
                for i, r in enumerate(raw)]
    try:
        dirs = paper_laser_directions(origin=s.laser_origin, used_only=False)
    except (OSError, KeyError, ValueError):
        dirs = None
    forward = -np.asarray(s.camera_to_world)[:3, 2]
    paper_forward = paper_to_blender_points([0.0, 0.0, 1.0])
    if (dirs is not None and np.allclose(forward, paper_forward, atol=1e-6)
            and all(sp.id < len(dirs) and np.allclose(sp.laser_direction, dirs[sp.id], atol=1e-6)
                    for sp in m.spots)):
        return [(i, by_id.get(i), np.asarray(by_id[i].laser_direction) if i in by_id else dirs[i])
                for i in range(len(dirs))]
    return [(i, sp, np.asarray(sp.laser_direction)) for i, sp in enumerate(sorted(m.spots, key=lambda q: q.id))]


def first_bounce_their_way(cube: np.ndarray, light_origin, light_direction, bin_width_m=PAPER_BIN_WIDTH_M):
    """l_k as their training derives it (extract_first = 1): the brightest pixel's brightest bin k read
    as the round-trip path (k + 1) * bin width, half of it along the laser. Training frame in and out."""
    flat = np.asarray(cube, np.float32).reshape(-1, cube.shape[-1])
    k = int(np.argmax(flat[int(np.argmax(flat.max(axis=1)))]))
    d = np.asarray(light_direction, np.float64)
    return np.asarray(light_origin, np.float64) + 0.5 * (k + 1) * bin_width_m * d / np.linalg.norm(d)


def _wall(point, direction) -> dict:
    """A plane through l_k facing the laser: their debug path (extract_first = 0) then finds l_k exactly."""
    p = [float(v) for v in point]
    h = WALL_HALF_EXTENT_M
    return {"plane": [float(-v) for v in direction], "point": p, "x": p[0],
            "y_min": p[1] - h, "y_max": p[1] + h, "z_min": p[2] - h, "z_max": p[2] + h}


def export_platonerf(dataset: Dataset | str | os.PathLike, out_dir: str | os.PathLike,
                     sample_type: str = "float16") -> Path:
    """Write `dataset` as their preprocessing would (their loader reads it unmodified).

    sample_type 'float16' (theirs; cubes scaled by a recorded power of two) or 'float32' (lossless).
    """
    ds = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    m, s = ds.manifest, ds.sensor
    if m.kind != "transients":
        raise DatasetError(str(ds.root), "kind", f"only transient datasets have a PlatoNeRF layout, got {m.kind!r}")
    if sample_type not in ("float16", "float32"):
        raise ValueError(f"sample_type must be 'float16' or 'float32', got {sample_type!r}")
    prior = m.provenance.extra.get("platonerf") or {}
    pad = s.start_m / s.bin_width_m
    if abs(pad - round(pad)) > 1e-6:
        raise DatasetError(str(ds.root), "sensor.start_m", f"{s.start_m} m is not a whole number of bins: "
                                                            "their bins start at 0")
    pad = int(round(pad))
    slots = _frame_slots(m, s)
    scale = 1.0
    if sample_type == "float16":
        vmax = max((float(ds.read_transient(sp.id).window.max()) for _, sp, _ in slots if sp is not None),
                   default=0.0)
        scale = prior.get("cube_scale", 0.0)
        if not (scale > 0 and vmax * scale <= FLOAT16_TARGET_MAX * 2):
            scale = cube_scale_for(vmax)
    out = Path(out_dir)
    (out / "train").mkdir(parents=True, exist_ok=True)
    lo_t = blender_to_platonerf_train_points(s.laser_origin)
    raw_frames = prior.get("frames") or []
    frames, walls, ignore = [], [], []
    for i, sp, d in slots:
        d_t = blender_to_platonerf_train_points(d)
        raw = raw_frames[i] if i < len(raw_frames) else {}
        light_d = raw.get("light_direction")
        if light_d is None or not np.allclose(np.asarray(light_d) / np.linalg.norm(light_d), d_t, atol=1e-9):
            light_d = d_t.tolist()
        rel = raw.get("file_path") or f"./train/{i:03d}"
        if sp is not None:
            cube = ds.read_transient(sp.id).dense(np.float32)
            if pad:
                cube = np.concatenate([np.zeros(cube.shape[:2] + (pad,), np.float32), cube], axis=-1)
            cube = (cube * np.float32(scale)).astype(np.float16 if sample_type == "float16" else np.float32)
            if not np.all(np.isfinite(cube)):
                raise ValueError(f"spot {sp.id}: the scaled cube overflows {sample_type}")
            np.save(out / (rel + ".npy"), cube)
            l_t = (blender_to_platonerf_train_points(sp.first_bounce) if sp.first_bounce is not None
                   else first_bounce_their_way(cube, lo_t, d_t, s.bin_width_m))
        else:
            l_t = lo_t + 3.0 * d_t     # never read: the frame is ignored and has no cube
        if sp is None or not sp.enabled:
            ignore.append(i)
        walls.append(_wall(l_t, d_t))
        fr = {"file_path": rel, "transform_matrix": blender_to_paper_c2w(s.camera_to_world).tolist(),
              "light_origin": raw["light_origin"] if np.array_equal(raw.get("light_origin"), lo_t) else lo_t.tolist(),
              "light_direction": light_d,
              "wall_idx_cam": i, "wall_idx_light": i}
        if sp is not None:
            fr["platolidar_spot"] = {"id": sp.id, "enabled": sp.enabled, "content_hash": sp.content_hash,
                                     "first_bounce": None if sp.first_bounce is None
                                     else blender_to_platonerf_train_points(sp.first_bounce).tolist()}
        frames.append(fr)
    angle = prior.get("camera_angle_x")
    if angle is None or deg_to_rad(angle) != s.fov_rad or s.fov_axis != "x":
        angle = _camera_angle_x_deg(s)
    extras = {k: v for k, v in m.to_dict().items() if k not in ("spots",)}
    extras.update(cube_scale=scale, pad_bins=pad)
    if isinstance(prior.get("walls"), list) and len(raw_frames) == len(frames) and all(
            "wall_idx_cam" in r and "wall_idx_light" in r for r in raw_frames):   # theirs, as imported
        walls = prior["walls"]
        for fr, raw in zip(frames, raw_frames):
            fr.update(wall_idx_cam=raw["wall_idx_cam"], wall_idx_light=raw["wall_idx_light"])
    doc = {"camera_angle_x": angle, "walls": walls,
           "ignore": ignore, "frames": frames, "platolidar": extras}
    (out / TRANSFORMS).write_text(json.dumps(doc, indent=4))
    _write_config(out / CONFIG_TXT, m, len(frames) - len(ignore), ignore, s)
    export_ground_truth(ds, out, angle)
    return out


def _write_config(path: Path, m: Manifest, n_used: int, ignore: list, s: SensorSpec) -> None:
    """The dataset part of a config for their run_platonerf.py (append their model settings)."""
    name = m.provenance.scene or "platolidar"
    lines = [f"expname = {name}", "basedir = ./logs", f"datadir = ./data/{name}", "dataset_type = dtof",
             f"per_image_thresh = [{','.join(['0.15'] * n_used)}]", f"ignore = [{','.join(map(str, ignore))}]",
             "extract_first = 1", "parallel = 0.05"]
    if not bin_widths_consistent(PAPER_BIN_WIDTH_M, s.bin_width_ps):
        lines.insert(0, f"# bins are {s.bin_width_m} m: set TIME_RES_M in their run_platonerf.py to match")
    path.write_text("\n".join(lines) + "\n")


def _parse_ignore(doc: dict, ignore, f: str) -> set:
    if ignore is None:
        ignore = doc.get("ignore", [])
    if not isinstance(ignore, (list, tuple, set)) or not all(isinstance(i, int) and i >= 0 for i in ignore):
        raise DatasetError(f, "ignore", f"expected a list of frame indices, got {ignore!r}")
    return set(ignore)


def _load_cube(src: Path, rel: str, field: str) -> np.ndarray:
    """Their loader opens file_path + '.npy'; a file_path that already ends in .npy is accepted too."""
    cands = [src / (rel + ".npy"), src / rel]
    p = next((c for c in cands if c.is_file()), None)
    if p is None:
        raise DatasetError(str(cands[0]), field, "transient .npy file is missing")
    try:
        cube = np.load(p, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise DatasetError(str(p), field, f"not a readable .npy array ({exc})") from None
    if cube.ndim != 3:
        raise DatasetError(str(p), field, f"expected a transient cube H x W x T, got shape {cube.shape}")
    if not np.issubdtype(cube.dtype, np.number):
        raise DatasetError(str(p), field, f"expected numbers, got dtype {cube.dtype}")
    check_array(cube, str(p), field, nonneg=True)
    return cube


def _vec(fr: dict, key: str, f: str, i: int) -> np.ndarray:
    try:
        v = np.asarray(fr[key], dtype=np.float64)
    except (TypeError, ValueError):
        raise DatasetError(f, f"frames[{i}].{key}", "expected numbers") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise DatasetError(f, f"frames[{i}].{key}", "expected 3 finite numbers")
    return v


#: import options an export of ours cannot take: its ``platolidar`` block fixes them (option -> flag, field)
FIXED_BY_OUR_EXPORT = {"bin_width_ps": ("--bin-ps", "sensor.bin_width_ps"),
                       "bin_width_m": ("--bin-m", "sensor.bin_width_m"),
                       "pulse_fwhm_ps": ("--pulse-fwhm-ps", "sensor.pulse.fwhm_ps"),
                       "window_bins": ("--window-bins", "layout.window_bins")}


def _refuse_fixed_options(f: str, given: dict, sensor: SensorSpec, layout: TransientLayout) -> None:
    """An export of ours records its bins, pulse and window: an option saying otherwise is refused (naming
    the flag), never silently ignored; one that agrees with the record is harmless."""
    recorded = {"bin_width_ps": sensor.bin_width_ps, "bin_width_m": sensor.bin_width_m,
                "pulse_fwhm_ps": sensor.pulse.fwhm_ps, "window_bins": layout.window_bins}
    for key, value in given.items():
        if value is not None and not np.isclose(float(value), float(recorded[key]), rtol=1e-9, atol=0.0):
            flag, field = FIXED_BY_OUR_EXPORT[key]
            raise DatasetError(f, f"platolidar.{field}", f"{flag} {value} contradicts this export of ours, which "
                                                        f"records {recorded[key]}: leave {flag} out")


def import_platonerf(src_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
                     bin_width_ps: float | None = None, bin_width_m: float | None = None,
                     start_m: float = 0.0, pulse_fwhm_ps: float | None = None,
                     window_bins: int | None = None, ignore=None, train_depth=None) -> Dataset:
    """Convert a PlatoNeRF-layout directory into a dataset of ours at `out_dir` (atomic).

    bin_width_ps / bin_width_m / pulse_fwhm_ps: None takes the paper's values (their cubes do not record
    them); window_bins None stores dense cubes. An export of ours (a ``platolidar`` block) records all four:
    a value given here that differs from the record is refused (FIXED_BY_OUR_EXPORT).
    ignore: frame indices to import as disabled spots (default: the JSON's ``ignore``, else none);
    ignored frames without a cube are skipped. train_depth: a .npy range image of the train view.
    """
    src = Path(src_dir)
    tpath = src / TRANSFORMS
    f = str(tpath)
    if not tpath.is_file():
        raise DatasetError(f, "", "transforms_train.json is missing")
    doc = read_json(tpath)
    if not isinstance(doc, dict):
        raise DatasetError(f, "", "expected a JSON object")
    angle = doc.get("camera_angle_x")
    if isinstance(angle, bool) or not isinstance(angle, (int, float)) or not 0 < angle < 180:
        raise DatasetError(f, "camera_angle_x", f"expected a field of view in (0, 180) degrees, got {angle!r}")
    frames = doc.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f, "frames", "expected a non-empty list")
    skip = _parse_ignore(doc, ignore, f)
    extras = doc.get("platolidar") or {}
    scale = float(extras.get("cube_scale", 1.0))
    pad = int(extras.get("pad_bins", 0))
    c2w0, items, raw_frames = None, [], []
    for i, fr in enumerate(frames):
        for key in ("transform_matrix", "light_origin", "light_direction", "file_path"):
            if not isinstance(fr, dict) or key not in fr:
                raise DatasetError(f, f"frames[{i}].{key}", "missing")
        try:
            c2w = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise DatasetError(f, f"frames[{i}].transform_matrix", "expected numbers") from None
        if c2w.shape != (4, 4) or not np.all(np.isfinite(c2w)):
            raise DatasetError(f, f"frames[{i}].transform_matrix", f"expected a finite 4x4 matrix, got shape {c2w.shape}")
        if c2w0 is None:
            c2w0 = c2w
        elif not np.allclose(c2w, c2w0, atol=1e-6):
            raise DatasetError(f, f"frames[{i}].transform_matrix", "single-view lidar: every frame must share one camera")
        lo, ld = _vec(fr, "light_origin", f, i), _vec(fr, "light_direction", f, i)
        n = np.linalg.norm(ld)
        if n < 1e-9:
            raise DatasetError(f, f"frames[{i}].light_direction", "zero-length direction")
        raw_frames.append({k: fr[k] for k in ("file_path", "light_origin", "light_direction", "wall_idx_cam",
                                              "wall_idx_light") if k in fr})
        if not isinstance(fr["file_path"], str):
            raise DatasetError(f, f"frames[{i}].file_path", "expected a string")
        field = f"frames[{i}].file_path"
        if i in skip and not any((src / p).is_file() for p in (fr["file_path"] + ".npy", fr["file_path"])):
            continue
        cube = _load_cube(src, fr["file_path"], field)
        if items and cube.shape != items[0][1].shape:
            raise DatasetError(str(src / (fr["file_path"] + ".npy")), field,
                               f"shape {cube.shape} differs from the first frame's {items[0][1].shape}")
        # renormalise only when needed, so our own unit directions round-trip bit-exactly
        items.append((i, cube, lo, ld if abs(n - 1.0) < 1e-12 else ld / n, fr.get("platolidar_spot") or {}))
    if not items:
        raise DatasetError(f, "frames", "no frame with a transient cube")
    h, w, t = items[0][1].shape
    t -= pad
    sample_type = "float16" if items[0][1].dtype == np.float16 and scale == 1.0 else "float32"
    if extras:
        ck = FieldReader(f)
        sensor = SensorSpec.from_dict(extras["sensor"], ck, "platolidar.sensor")
        layout = TransientLayout.from_dict(extras["layout"], ck, "platolidar.layout")
        noise = NoiseSpec.from_dict(extras["noise"], ck, "platolidar.noise")
        prov = Provenance.from_dict(extras["provenance"], ck, "platolidar.provenance")
        if (sensor.height, sensor.width, sensor.bins) != (h, w, t):
            raise DatasetError(f, "platolidar.sensor", f"says {sensor.height}x{sensor.width}x{sensor.bins}, "
                                                       f"cubes are {h}x{w}x{t} after {pad} padding bins")
        _refuse_fixed_options(f, {"bin_width_ps": bin_width_ps, "bin_width_m": bin_width_m,
                                  "pulse_fwhm_ps": pulse_fwhm_ps, "window_bins": window_bins}, sensor, layout)
    else:
        g = t if window_bins is None else int(window_bins)
        sensor = SensorSpec(width=w, height=h, fov_rad=deg_to_rad(angle), fov_axis="x",
                            camera_to_world=paper_to_blender_c2w(c2w0).tolist(),
                            laser_origin=platonerf_train_to_blender_points(items[0][2]).tolist(),
                            pulse=PulseSpec("gaussian", PAPER_BIN_WIDTH_PS if pulse_fwhm_ps is None else pulse_fwhm_ps),
                            bin_width_ps=PAPER_BIN_WIDTH_PS if bin_width_ps is None else bin_width_ps,
                            bin_width_m=PAPER_BIN_WIDTH_M if bin_width_m is None else bin_width_m,
                            bins=t, start_m=start_m,
                            time_gate=TimeGate(enabled=g < t, window_bins=g if g < t else 0))
        layout = TransientLayout("dense" if g == t else "windowed", g, sample_type)
        noise = NoiseSpec()
        prov = Provenance(generator="platonerf-import", generator_version="2", seed=0, scene=src.name,
                          extra={"source": str(src), "platonerf": {
                              "camera_angle_x": angle, "cube_scale": 1.0, "frames": raw_frames,
                              "walls": doc.get("walls"), "ignore": sorted(skip)}})
    spots = []
    with DatasetWriter(out_dir) as wr:
        for i, cube, lo, ld, meta in items:
            sid = int(meta.get("id", i))
            x = cube[..., pad:].astype(np.float32)
            if scale != 1.0:
                x = x / np.float32(scale)
            rel = wr.write_transient(sid, Transient.from_dense(x, layout.window_bins), layout.sample_type)
            fb = meta.get("first_bounce")
            spots.append(Spot(id=sid, laser_direction=platonerf_train_to_blender_points(ld).tolist(),
                              transient_file=rel,
                              enabled=i not in skip if ignore is not None else bool(meta.get("enabled", i not in skip)),
                              first_bounce=None if fb is None else platonerf_train_to_blender_points(fb).tolist(),
                              content_hash=meta.get("content_hash")))
        gt = import_ground_truth(src, wr, sensor, train_depth)
        wr.commit(Manifest(sensor=sensor, spots=spots, layout=layout, noise=noise, ground_truth=gt, provenance=prov))
    return Dataset(out_dir)


__all__ = ["export_platonerf", "import_platonerf", "first_bounce_their_way", "cube_scale_for", "transient_relpath"]
