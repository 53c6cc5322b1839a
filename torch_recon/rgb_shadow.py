"""Intensity (RGB) shadows: what a camera without time resolution can tell about shadows.

An RGB-shadow method (S3-NeRF, the paper's comparison under ambient light) sees the scene with a
conventional camera: each pixel integrates the whole exposure, i.e. the two-bounce light of spot k
PLUS every ambient photon, and no time gate can remove the latter. This module derives such an
intensity image from the lidar's own transients (photon-consistent with the simulator's ambient
model), labels shadows by the usual intensity ratio, and swaps them into lidar Measurements so a
reconstruction can be run with the SHADOW source changed and everything else kept.

What it is not: a reimplementation of S3-NeRF. S3-NeRF has no distances at all and fits shading;
here the distances (path_length), the first bounces and the visible depth still come from the lidar.
The comparison isolates one question: how good are shadows from integrated intensity vs. from the
time-resolved matched filter, at a given ambient level.

numpy only (no bpy, no torch).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from .contract.dataset import DatasetError
from .contract.dataset.transient import Transient
from .measurements import Measurements

# I_k / max_k I below this -> shadow. The lidar's matched-filter default (0.15, the paper's) is a
# confidence, not an intensity ratio; benchmarks/ablation_rgb.py picks the ratio threshold on the
# ambient-free dataset against the noise-free lidar mask and reports which value it used.
DEFAULT_RATIO_THRESHOLD = 0.15


def integrated_intensity(transient: Transient) -> np.ndarray:
    """(H, W) float64 sum over all T bins: what a non-time-resolved (RGB / intensity) camera with the
    same optics and exposure records.

    A windowed transient only stores G of the T bins per pixel: every photon outside the window
    (ambient light in particular) is lost, so its sum is NOT the camera's intensity. Use time-gate-off
    datasets: the simulator then stores dense cubes, or, without ambient light, a window bounding every
    non-zero bin (lossless storage, whose sum is exact).
    """
    if not isinstance(transient, Transient):
        raise TypeError(f"transient: expected a torch_recon.contract.dataset.Transient, got {type(transient).__name__}")
    return np.asarray(transient.window, np.float64).sum(axis=2)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """Inverse sRGB transfer function of values in [0, 1]."""
    v = np.clip(np.asarray(v, np.float64), 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def read_rgb_luminance(path, field: str = "rgb_files") -> np.ndarray:
    """(H, W) linear luminance (Rec. 709 weights) of an 8/16-bit sRGB PNG such as the simulator's
    `rgb_files` (pipeline/simulate.py --rgb). 8-bit PNGs quantise dark pixels: prefer the transient sum.

    A file that is not such an image raises DatasetError naming the file and `field` (the manifest field
    that lists it); a missing or unreadable file raises the OSError, with its path.
    """
    from skimage.io import imread
    path = Path(path)
    with open(path, "rb"):            # missing / unreadable: the OSError names the path
        pass
    try:
        img = np.asarray(imread(str(path)))
    except (OSError, ValueError, SyntaxError) as exc:    # Pillow: UnidentifiedImageError (an OSError), bad chunks
        raise DatasetError(str(path), field, f"not a readable PNG image ({type(exc).__name__}: "
                                             f"{str(exc).splitlines()[0] if str(exc) else 'no detail'})") from None
    if img.dtype == np.uint8:
        v = img / 255.0
    elif img.dtype == np.uint16:
        v = img / 65535.0
    else:
        raise DatasetError(str(path), field, f"expected an 8- or 16-bit PNG, got samples of type {img.dtype}")
    if v.ndim == 2:
        return srgb_to_linear(v)
    if v.ndim != 3 or v.shape[2] not in (3, 4):
        raise DatasetError(str(path), field, f"expected a grey, RGB or RGBA image, got shape {img.shape}")
    lin = srgb_to_linear(v[..., :3])
    return lin @ np.array([0.2126, 0.7152, 0.0722])


def intensity_shadow_masks(intensities, threshold: float = DEFAULT_RATIO_THRESHOLD, excluded=None):
    """Shadows from intensity ratios: (shadow (K, H, W) bool, labelled (H, W) bool).

    Pixel p is in shadow of spot k where I_k(p) / max_j I_j(p) < threshold: every pixel is lit by most
    spots, so the maximum is its lit reference. Ambient light adds the same offset to every I_k and
    pulls the ratios towards 1, washing shadows out.
    `excluded` ((K, H, W) or (H, W) bool) pixels are never shadow, and take no part in the reference
    maximum (e.g. the pixel seeing spot k directly is far brighter than any two-bounce light).
    A pixel without a positive finite reference (dark in every spot, or NaN) gets no label:
    `labelled` is False there and it is not shadow (and must not be called lit either).
    """
    i = np.asarray(intensities, np.float64)
    if i.ndim != 3 or i.shape[0] < 1:
        raise ValueError(f"intensities: expected shape (K, H, W) with K >= 1, got {i.shape}")
    if not (np.isscalar(threshold) and 0.0 <= float(threshold) <= 1.0):
        raise ValueError(f"threshold: expected a ratio in [0, 1], got {threshold!r}")
    if excluded is None:
        ex = np.zeros(i.shape, bool)
    else:
        ex = np.asarray(excluded, bool)
        if ex.shape == i.shape[1:]:
            ex = np.broadcast_to(ex, i.shape)
        elif ex.shape != i.shape:
            raise ValueError(f"excluded: expected shape {i.shape} or {i.shape[1:]}, got {ex.shape}")
    finite = np.isfinite(i)
    use = finite & ~ex
    ref = np.where(use, i, -np.inf).max(axis=0)
    labelled = np.isfinite(ref) & (ref > 0)
    safe_ref = np.where(labelled, ref, 1.0)
    ratio = np.where(finite, i, np.inf) / safe_ref     # NaN intensity of one spot: no shadow claim for it
    shadow = (ratio < float(threshold)) & labelled[None] & ~ex
    return shadow, labelled


def apply_intensity_shadows(meas: Measurements, shadow_masks) -> Measurements:
    """A copy of `meas` whose shadows come from intensity, distances still from the lidar.

    Per spot k: shadow := intensity shadow and not excluded; signal := not intensity shadow and lidar
    signal with a finite path (and not excluded); path_length NaN where not signal. A pixel the
    intensity calls lit but where the lidar found no two-bounce return stays unlabelled (neither), as
    do unlabelled intensity pixels (pass shadow=False there). excluded, first bounces, pulses and
    visible_depth are kept; shadow_confidence is kept (the lidar's) for reference only.
    """
    masks = np.asarray(shadow_masks)
    k, h, w = len(meas.spots), meas.height, meas.width
    if masks.shape != (k, h, w):
        raise ValueError(f"shadow_masks: expected shape {(k, h, w)} (spots, height, width), got {masks.shape}")
    if masks.dtype != bool:
        raise ValueError(f"shadow_masks: expected a bool array, got dtype {masks.dtype}")
    out = copy.copy(meas)
    out.spots = []
    for s, sh in zip(meas.spots, masks):
        ex = np.asarray(s.excluded, bool)
        path = np.asarray(s.path_length, np.float32)
        sig = ~sh & np.asarray(s.signal, bool) & np.isfinite(path) & ~ex
        t = copy.copy(s)
        t.shadow = sh & ~ex
        t.signal = sig
        t.path_length = np.where(sig, path, np.nan).astype(np.float32)
        out.spots.append(t)
    out.settings = {**meas.settings, "shadow_source": "intensity"}
    return out


def mask_agreement(shadow, reference_shadow, reference_labelled) -> dict:
    """Agreement of `shadow` masks with a reference: precision / recall / F1 of 'shadow' and accuracy,
    over the pixels the reference labels (lit or shadow). A pixel `shadow` leaves unlabelled counts as
    'not shadow'. Empty denominators give NaN (no pixel to judge), never a division by zero."""
    s, r, lab = (np.asarray(x, bool) for x in (shadow, reference_shadow, reference_labelled))
    if not s.shape == r.shape == lab.shape:
        raise ValueError(f"mask_agreement: shapes differ: {s.shape}, {r.shape}, {lab.shape}")
    s, r = s & lab, r & lab
    tp, fp, fn = int((s & r).sum()), int((s & ~r).sum()), int((~s & r).sum())
    n = int(lab.sum())
    prec = tp / (tp + fp) if tp + fp else float("nan")
    rec = tp / (tp + fn) if tp + fn else float("nan")
    f1 = 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else float("nan")
    acc = float(((s == r) & lab).sum()) / n if n else float("nan")
    return {"shadow_precision": prec, "shadow_recall": rec, "shadow_f1": f1, "accuracy": acc, "pixels": n}
