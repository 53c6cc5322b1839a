"""Transients -> measurements: first bounce, pulse, time gate, matched filter, sub-bin peaks.

Vectorised torch on CPU or CUDA (`device`); each spot is processed in chunks of
image rows so a dense 512 x 512 x 391 cube never needs more than one extra copy
of a chunk. Windowed transients (start bin + G bins per pixel) are used as they
are: the matched filter runs over the G stored bins only.

Per spot k (paths in metres of optical path, bin centres start_m + (j + 0.5) w):
1. First bounce l_k: the laser ray o + d * ld is sampled in d; each sample is
   projected into the image and the transient of that pixel is read at the
   sample's first-bounce path P(d) = d + |o + d ld - c|. The brightest sample
   names the pixel seeing l_k; its sub-bin peak P1 gives d in closed form:
   (P1 - d)^2 = |q + d ld|^2, q = o - c  ->  d = (P1^2 - |q|^2) / (2 (P1 + q.ld)).
2. Pulse: that pixel's transient around P1, background (median) removed, unit sum.
3. Time gate: two-bounce paths are >= P1 (triangle inequality), so bins before
   P1 - (pulse half width) are ignored, as are bins beyond `gate_max_m`.
4. Matched filter (as the PlatoNeRF code): correlate each pixel with the unit-sum
   pulse, divide by the pixel's (gated) sum; the maximum is the shadow confidence.
   Below `shadow_threshold` -> shadow, otherwise the pixel saw l_k (signal).
   Then the photon counts (torch_recon.shadow_decision): a lit pixel far dimmer than its
   same-surface lit neighbours is partly covered by a thin shadow -> shadow; a dark pixel whose
   darkness is no evidence of shadow under Poisson statistics -> unlabelled (neither).
5. Sub-bin peak: at the raw maximum next to the matched-filter peak, the 3-bin
   ratio r = (x+ - x-) / (x- + x0 + x+) is inverted through a lookup table built
   from a Gaussian pulse model whose width is fitted to the first-bounce return
   ('lut', exact for noise-free Gaussian pulses); 'gaussian' (log-parabola) and
   'parabola' fits are available for comparison.
6. 'Parallel' pixels (the PlatoNeRF filter): pixels whose ray is within
   asin(parallel_sin) of the direction c -> l_k see the first-bounce return
   (and its blur) instead of a two-bounce one; they are marked `excluded`.
Steps 1 and 5 (first bounce, sub-bin peaks) live in torch_recon/first_bounce.py, steps 2 to 5 for a spot
(gate, matched filter, background, the paths of its strongest and earliest returns) in matched_filter.py, the
photon-count shadow tests in shadow_decision.py; this module runs them per spot and over a dataset.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from .contract.dataset.transient import Transient
from .contract.frames import camera_ray_directions
from .contract.errors import PreprocessError
from .first_bounce import FirstBounce, find_first_bounce, fit_out_of_view_spot, fit_pulse_sigma, laser_ray_seen
from .matched_filter import matched_filter_spot
from .measurements import Measurements, SpotMeasurement
from .shadow_decision import partial_shadow_mask, photon_counting, significant_return, unsupported_shadow_mask


@dataclass
class PreprocessSettings:
    shadow_threshold: float = 0.15     # matched-filter confidence below this -> shadow (paper: 0.15)
    parallel_sin: float = 0.05         # exclude pixels within asin(this) of the ray c -> l (paper: 0.05)
    refine: str = "lut"                # sub-bin peak: 'lut' | 'gaussian' | 'parabola' | 'none'
    return_centroid_fraction: float = 0.05  # > 0: a two-bounce path is its return's intensity centroid over the
                                       # bins above this x its maximum (first_bounce.centroid_offset: a grazing
                                       # pixel's flat-topped return); 0: the 3-bin `refine` fit
    pulse_half_width_bins: int = 3     # pulse template = 2 h + 1 bins around the first-bounce peak
    gate_max_m: float | None = None    # ignore returns beyond this optical path (None: end of histogram)
    background: str = "none"           # 'median': subtract each pixel's median before the filter
    first_bounce_tolerance_m: float = 0.05  # warn when l differs this much from a recorded first bounce
    min_first_bounce_snr: float = 5.0  # first-bounce peak must exceed this x the pixel's median (+ floor)
    partial_shadow_ratio: float = 0.5  # lit pixel with under this x the photons of same-surface lit pixels on
                                       # both sides (within 2 px): a thin shadow covers part of it (0: off)
    partial_unlabel_ratio: float = 0.0  # under this (> partial_shadow_ratio) x the neighbours' photons: partly
                                       # shadowed, left unlabelled (neither lit nor shadow); 0: off
    partial_shadow_z: float = 2.0      # ... and the deficit exceeds this many Poisson standard deviations
    partial_shadow_edges: bool = True  # also the rim of a shadow: dimmer than ratio x the lit side
    partial_shadow_rim: str = "near"   # the rim's bound: 'near' = the nearest lit pixel's photons, 'trend' =
                                       # the lit side extrapolated, min(s1, 2 s1 - s2) (session 8; shadow_decision)
    first_return_fraction: float = 0.1  # a pixel's earliest return counts when its filtered peak exceeds this x
                                       # the strongest one's (above background): a thin part in front of a wall
                                       # fills part of the pixel and returns first (0: off)
    photon_statistics: str = "auto"    # 'poisson': values are photon counts; 'none': expected values (no
                                       # counting noise); 'auto': 'poisson' when every stored value is an integer
    shadow_false_alarm: float = 0.05  # a dark pixel next to lit ones is a shadow only where a lit pixel
                                      # that dark has a Poisson probability below this (else unlabelled; 0: off)
    return_false_alarm: float = 1e-3  # photon counts over a background: a pixel is lit only where its peak's
                                      # photons would come from the background alone with a probability below
                                      # this (shadow_decision.significant_return; 0: off)
    same_surface_bins: float = 2.0     # neighbours count as the same surface within this many bins of path
    chunk_elements: int = 1 << 20      # bins per chunk: 4 MB tensors stay in the allocator's heap (1 << 24:
                                       # 64 MB ones were mapped afresh each time, 10.7 of 27 CPU-s at 512 px in page faults)
    compute_visible_depth: bool = True

    SETTINGS_META = {"refine": {"choices": ("lut", "gaussian", "parabola", "none")},
                     "background": {"choices": ("none", "median")},
                     "partial_shadow_rim": {"choices": ("near", "trend")},
                     "photon_statistics": {"choices": ("auto", "poisson", "none")}, "shadow_threshold": {"range": (0.0, 1.0)},
                     "gate_max_m": {"unit": "m"}}

    def validate(self):
        if not 0.0 <= self.shadow_threshold <= 1.0:
            raise PreprocessError(f"shadow_threshold must be in [0, 1], got {self.shadow_threshold}")
        if not 0.0 <= self.parallel_sin < 1.0:
            raise PreprocessError(f"parallel_sin must be in [0, 1), got {self.parallel_sin}")
        if self.refine not in ("lut", "gaussian", "parabola", "none"):
            raise PreprocessError(f"refine must be 'lut', 'gaussian', 'parabola' or 'none', got {self.refine!r}")
        if self.background not in ("none", "median"):
            raise PreprocessError(f"background must be 'none' or 'median', got {self.background!r}")
        if self.partial_shadow_rim not in ("near", "trend"):
            raise PreprocessError(f"partial_shadow_rim must be 'near' or 'trend', got {self.partial_shadow_rim!r}")
        if not 0.0 <= self.partial_shadow_ratio < 1.0:
            raise PreprocessError(f"partial_shadow_ratio must be in [0, 1), got {self.partial_shadow_ratio}")
        if self.photon_statistics not in ("auto", "poisson", "none"):
            raise PreprocessError(f"photon_statistics must be 'auto', 'poisson' or 'none', got {self.photon_statistics!r}")
        if not 0.0 <= self.shadow_false_alarm < 1.0:
            raise PreprocessError(f"shadow_false_alarm must be in [0, 1), got {self.shadow_false_alarm}")
        if not 0.0 <= self.return_false_alarm < 1.0:
            raise PreprocessError(f"return_false_alarm must be in [0, 1), got {self.return_false_alarm}")
        if not 0.0 <= self.first_return_fraction < 1.0:
            raise PreprocessError(f"first_return_fraction must be in [0, 1), got {self.first_return_fraction}")
        if not 0.0 <= self.partial_unlabel_ratio < 1.0:
            raise PreprocessError(f"partial_unlabel_ratio must be in [0, 1), got {self.partial_unlabel_ratio}")
        if not (self.partial_shadow_z >= 0 and self.same_surface_bins > 0):
            raise PreprocessError("partial_shadow_z must be >= 0 and same_surface_bins > 0")
        if not 0.0 <= self.return_centroid_fraction < 1.0:
            raise PreprocessError(f"return_centroid_fraction must be in [0, 1) (0: off), got {self.return_centroid_fraction}")
        if self.pulse_half_width_bins < 1:
            raise PreprocessError("pulse_half_width_bins must be >= 1")


# ---------------------------------------------------------------- input checks

def check_transient(tr: Transient, sensor, spot_id) -> None:
    """Refuse a transient that does not fit the sensor: shape, bins, NaN/inf, negatives, all zero."""
    where = f"spot {spot_id}"
    if tr.bins != sensor.bins:
        raise PreprocessError(f"{where}: transient has {tr.bins} bins, the manifest says sensor.bins={sensor.bins}")
    if tuple(tr.shape) != (sensor.height, sensor.width):
        raise PreprocessError(f"{where}: transient is {tr.shape[0]}x{tr.shape[1]} pixels, the manifest says "
                              f"{sensor.height}x{sensor.width} (sensor.height x sensor.width)")
    w = tr.window
    lo, hi = (float(w.min()), float(w.max())) if w.size else (0.0, 0.0)   # min is NaN if any value is
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise PreprocessError(f"{where}: transient has {int((~np.isfinite(w)).sum())} NaN or infinite value(s)")
    if lo < 0:
        raise PreprocessError(f"{where}: transient has {int((w < 0).sum())} negative count(s)")
    if hi == 0:
        raise PreprocessError(f"{where}: transient is all zeros (no return at all; laser off or hits nothing?)")


# ---------------------------------------------------------------- per spot

def world_pixel_directions(sensor) -> np.ndarray:
    c2w = np.asarray(sensor.camera_to_world, np.float64)
    return camera_ray_directions(sensor.width, sensor.height, sensor.fov_rad, sensor.fov_axis) @ c2w[:3, :3].T


def parallel_mask(dirs: np.ndarray, c, l, parallel_sin: float) -> np.ndarray:
    """Pixels looking (almost) along c -> l, where the first-bounce return swamps the two-bounce one."""
    e = np.asarray(l, np.float64) - np.asarray(c, np.float64)
    e /= max(np.linalg.norm(e), 1e-12)
    sin = np.linalg.norm(np.cross(dirs, e), axis=-1)
    return (sin < parallel_sin) & ((dirs @ e) > 0)


def process_spot(tr: Transient, sensor, spot, settings: PreprocessSettings, device="cpu", dirs=None,
                 recorded_first_bounce=None, fb: FirstBounce | None = None) -> SpotMeasurement:
    """One spot's measurements; `fb` given: its first bounce is already known (an out-of-view spot's fit)."""
    settings.validate()
    check_transient(tr, sensor, spot.id)
    if fb is None:
        fb = find_first_bounce(tr, sensor, spot.laser_direction, spot.id, settings)
    rec = recorded_first_bounce if recorded_first_bounce is not None else getattr(spot, "first_bounce", None)
    if rec is not None:
        err = float(np.linalg.norm(fb.point - np.asarray(rec, np.float64)))
        if err > settings.first_bounce_tolerance_m:
            warnings.warn(f"spot {spot.id}: first bounce estimated from the transient {np.round(fb.point, 4).tolist()} "
                          f"is {err:.4f} m from the recorded one {np.round(rec, 4).tolist()} "
                          f"(tolerance {settings.first_bounce_tolerance_m} m)", stacklevel=2)
    counting = photon_counting(tr, settings)     # expected values: no counting noise, a dark pixel is dark
    mf = matched_filter_spot(tr, sensor, fb, settings, device, counting)
    conf, amp, path = mf.confidence, mf.amplitude, mf.path
    if dirs is None:
        dirs = world_pixel_directions(sensor)
    c = np.asarray(sensor.camera_to_world, np.float64)[:3, 3]
    excluded = parallel_mask(dirs, c, fb.point, settings.parallel_sin)
    if fb.pixel is not None:
        excluded[fb.pixel] = True
    signal = (conf >= settings.shadow_threshold) & ~excluded
    if counting and settings.return_false_alarm > 0:        # under ambient light: a return must outnumber it
        signal &= significant_return(mf, settings.return_false_alarm)
    # darkness is judged against the lit pixels of the matched filter, before partial shadows join the dark
    unlabelled = unsupported_shadow_mask(mf, signal, excluded, settings.shadow_false_alarm) \
        if counting and settings.shadow_false_alarm > 0 else np.zeros_like(signal)
    if settings.partial_shadow_ratio > 0:
        lit = signal
        part = lambda ratio: partial_shadow_mask(mf.counts, mf.variance, path, lit, excluded, sensor.bin_width_m,  # noqa: E731
                                                 settings, poisson=counting, ratio=ratio)
        signal = lit & ~part(settings.partial_shadow_ratio)
        if settings.partial_unlabel_ratio > settings.partial_shadow_ratio:
            dim = signal & part(settings.partial_unlabel_ratio)     # partly shadowed: neither carve nor build
            signal, unlabelled = signal & ~dim, unlabelled | dim
    path = np.where(signal, path, np.nan).astype(np.float32)
    first = None if mf.first_path is None else np.where(signal, np.fmin(mf.first_path, path), np.nan).astype(np.float32)
    ld = np.asarray(spot.laser_direction, np.float64)
    return SpotMeasurement(
        spot_id=int(spot.id), first_bounce=fb.point.astype(np.float64), laser_direction=ld / np.linalg.norm(ld),
        path_length=path, signal=signal, shadow_confidence=conf.astype(np.float32),
        shadow=(~signal) & ~excluded & ~unlabelled, excluded=excluded, first_bounce_pixel=fb.pixel,
        pulse=fb.pulse.astype(np.float32), first_bounce_path_m=float(fb.path_m), amplitude=amp,
        first_bounce_recorded=None if rec is None else np.asarray(rec, np.float64), first_return_path=first)


def preprocess(sensor, spot_transients, settings: PreprocessSettings | None = None, device="cpu",
               progress: bool = False) -> Measurements:
    """(Spot, Transient) pairs -> Measurements (with the fused closed-form visible depth)."""
    settings = settings or PreprocessSettings()
    settings.validate()
    dirs = world_pixel_directions(sensor)
    items = list(spot_transients) if not hasattr(spot_transients, "__len__") else spot_transients
    it = items
    if progress:
        from tqdm import tqdm
        it = tqdm(items, desc="preprocess", unit="spot")
    spots, out_of_view = [], []
    for i, (s, tr) in enumerate(it):   # out-of-view spots wait for the depth the in-view ones measure
        if laser_ray_seen(sensor, s.laser_direction):
            spots.append((i, process_spot(tr, sensor, s, settings, device, dirs)))
        else:       # a lazily read dataset reads it again later: a 512^2 cube per spot is 400 MB
            out_of_view.append((i, s, None if isinstance(items, _LazySpots) else tr))
        del tr
    if out_of_view:
        read = items.dataset.read_transient if isinstance(items, _LazySpots) else None
        spots += _out_of_view_spots(sensor, [m for _, m in spots], out_of_view, settings, device, dirs, read)
    spots = [m for _, m in sorted(spots, key=lambda im: im[0])]
    if not spots:
        raise PreprocessError("no enabled spots to preprocess")
    return _with_visible_depth(_measurements(sensor, spots, settings, settings=asdict(settings)), settings, device)


def _measurements(sensor, spots, prep: PreprocessSettings, **fields) -> Measurements:
    """Measurements of `spots` from the dataset's `sensor` with `prep`'s shadow threshold (`fields`: more of
    Measurements' fields, e.g. the settings to record)."""
    return Measurements(width=sensor.width, height=sensor.height, fov_rad=float(sensor.fov_rad),
                        fov_axis=sensor.fov_axis, camera_to_world=np.asarray(sensor.camera_to_world, np.float64),
                        laser_origin=np.asarray(sensor.laser_origin, np.float64),
                        bin_width_m=float(sensor.bin_width_m), shadow_threshold=float(prep.shadow_threshold),
                        spots=spots, **fields)


def _with_visible_depth(m: Measurements, settings: PreprocessSettings, device) -> Measurements:
    """`m` with the fused closed-form visible depth (`settings.compute_visible_depth`)."""
    if settings.compute_visible_depth:
        from .visible_depth import fuse_visible_depth
        fused = fuse_visible_depth(m, device=device)
        m.visible_depth, m.visible_confidence, m.nearest_depth = fused.depth, fused.confidence, fused.nearest
    return m


def _out_of_view_spots(sensor, spots, out_of_view, settings, device, dirs, read_transient=None) -> list:
    """[(index, SpotMeasurement)] of the out-of-view (index, spot, transient) triples, each located by its
    two-bounce arrival times at pixels whose depth the in-view `spots` measured
    (first_bounce.fit_out_of_view_spot; the laser's pulse is an in-view spot's)."""
    if not spots:
        ids = ", ".join(str(s.id) for _, s, _ in out_of_view)
        raise PreprocessError(f"every spot ({ids}) lies outside the sensor's view: at least one spot inside the view "
                              f"is needed (its first bounce is measured; out-of-view spots are located from the "
                              f"depth it gives)")
    from .visible_depth import fuse_visible_depth     # only scenes with out-of-view spots need it
    fused = fuse_visible_depth(_measurements(sensor, spots, settings), device=device)
    c = np.asarray(sensor.camera_to_world, np.float64)[:3, 3]
    points = c + dirs * np.asarray(fused.depth, np.float64)[..., None]
    pulse = np.asarray(spots[0].pulse, np.float64)
    h = len(pulse) // 2
    # peak_bin 0: the first pass is ungated (l, hence the earliest two-bounce path, is still unknown)
    ungated = FirstBounce(point=spots[0].first_bounce, distance=0.0, path_m=float(sensor.start_m), pixel=None,
                          pulse=pulse, pulse_sigma_bins=fit_pulse_sigma(pulse[h - 2:h + 3]) if h >= 2 else 0.05,
                          peak_bin=0)
    out = []
    for i, s, tr in out_of_view:
        tr = tr if tr is not None else read_transient(s.id)
        check_transient(tr, sensor, s.id)
        mf = matched_filter_spot(tr, sensor, ungated, settings, device)
        path = np.where(mf.confidence >= settings.shadow_threshold, mf.path, np.nan)
        fb = fit_out_of_view_spot(sensor, s.laser_direction, s.id, path, points, ungated)
        out.append((i, process_spot(tr, sensor, s, settings, device, dirs, fb=fb)))
    return out


class _LazySpots:
    """Reads one spot's transient at a time (a 512^2 x 391 cube is 400 MB)."""

    def __init__(self, dataset):
        self.dataset = dataset
        self.spots = dataset.manifest.enabled_spots

    def __len__(self):
        return len(self.spots)

    def __iter__(self):
        for s in self.spots:
            yield s, self.dataset.read_transient(s.id)


def measurements_from_dataset(dataset, settings: PreprocessSettings | None = None, device="cpu") -> Measurements:
    """A measurements-kind dataset (no transients): its stored per-pixel paths and masks as Measurements."""
    settings = settings or PreprocessSettings()
    settings.validate()
    s = dataset.sensor
    rays = dataset.ray_directions()
    dirs = rays if rays is not None else world_pixel_directions(s)
    c = np.asarray(s.camera_to_world, np.float64)[:3, 3]
    spots = []
    for sp in dataset.manifest.enabled_spots:
        d = dataset.read_spot_measurement(sp.id)
        l = np.asarray(sp.first_bounce, np.float64)
        excluded = ~d["valid"] | parallel_mask(dirs, c, l, settings.parallel_sin)
        signal = d["lit"] & ~excluded
        ld = np.asarray(sp.laser_direction, np.float64)
        spots.append(SpotMeasurement(
            spot_id=int(sp.id), first_bounce=l, laser_direction=ld / np.linalg.norm(ld),
            path_length=np.where(signal, d["path_m"], np.nan).astype(np.float32), signal=signal,
            shadow_confidence=signal.astype(np.float32), shadow=~signal & ~excluded, excluded=excluded,
            first_bounce_recorded=l))
    if not spots:
        raise PreprocessError(f"{dataset.root}: no enabled spots")
    m = _measurements(s, spots, settings, settings={**asdict(settings), "source": "measurements dataset"},
                      ray_directions=rays)
    return _with_visible_depth(m, settings, device)


def preprocess_dataset(dataset, settings: PreprocessSettings | None = None, device="cpu",
                       progress: bool = False) -> Measurements:
    """Preprocess every enabled spot of a loaded Dataset (transients read one at a time).

    A measurements-kind dataset (schema 1.1, e.g. an imported real capture) already holds what
    preprocessing extracts; it is read as it is (no matched filter, no first-bounce search)."""
    if dataset.manifest.kind == "measurements":
        return measurements_from_dataset(dataset, settings, device)
    try:
        return preprocess(dataset.sensor, _LazySpots(dataset), settings, device, progress)
    except PreprocessError as exc:
        raise PreprocessError(f"{dataset.root}: {exc}") from None
