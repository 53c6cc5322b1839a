"""`preprocess`: dataset -> measurements .npz (first bounces, shadow masks, two-bounce paths, visible depth)."""

from __future__ import annotations

from dataclasses import dataclass, field

from ..preprocess import PreprocessSettings
from . import DEVICE_FLAGS, DeviceSettings, add_stage

PREPROCESS_FLAGS = ("preprocess.shadow_threshold", "preprocess.parallel_sin", "preprocess.refine",
                    "preprocess.return_centroid_fraction",
                    "preprocess.background", "preprocess.gate_max_m")


@dataclass
class PreprocessCommand(DeviceSettings):
    """Settings of `preprocess` (also the first part of `baseline`)."""

    preprocess: PreprocessSettings = field(default_factory=PreprocessSettings)


def register(sub) -> None:
    add_stage(sub, "preprocess", run, PreprocessCommand, PREPROCESS_FLAGS + DEVICE_FLAGS,
              help="transients -> measurements (.npz)",
              description="First bounce, pulse, time gate, matched filter (shadow masks), sub-bin two-bounce "
                          "paths and the closed-form visible depth, for every enabled spot.",
              arguments=((("dataset",), {"help": "dataset directory (dataset.json)"}),
                         (("--out",), {"required": True, "help": "output .npz"})))


def summarize(meas) -> str:
    import numpy as np
    lines = [f"{len(meas.spots)} spots, {meas.width}x{meas.height} pixels, shadow threshold {meas.shadow_threshold}"]
    lines.append("  spot  first bounce (m)               lit %  shadow %  excluded")
    for s in meas.spots:
        n = s.signal.size
        lines.append(f"  {s.spot_id:4d}  {np.array2string(np.asarray(s.first_bounce), precision=3):30s} "
                     f"{100 * s.signal.sum() / n:5.1f}  {100 * s.shadow.sum() / n:8.1f}  {int(s.excluded.sum()):8d}")
    if meas.visible_depth is not None:
        ok = np.isfinite(meas.visible_depth)
        lines.append(f"visible depth on {100 * ok.mean():.1f} % of pixels"
                     + (f" (median {np.median(meas.visible_depth[ok]):.3f} m)" if ok.any() else ""))
    return "\n".join(lines)


def run(args) -> int:
    import time
    from pathlib import Path

    from ..contract.dataset import load_dataset
    from ..contract.errors import SettingsError
    from ..contract.settings import from_args
    from ..device import resolve_device
    from ..preprocess import preprocess_dataset

    cmd = from_args(PreprocessCommand, args)
    settings = cmd.preprocess
    device = resolve_device(cmd.device, cmd.threads)
    out = Path(args.out)
    if out.suffix != ".npz" or out.is_dir():
        raise SettingsError("out", f"expected a .npz file name, got {out}" + (" (a folder)" if out.is_dir() else ""))
    ds = load_dataset(args.dataset)
    t0 = time.perf_counter()
    meas = preprocess_dataset(ds, settings, device=device, progress=True)
    secs = time.perf_counter() - t0
    meas.settings["dataset_hash"] = ds.content_hash()
    meas.settings["seconds"] = round(secs, 3)
    out.parent.mkdir(parents=True, exist_ok=True)
    meas.save(out)
    print(summarize(meas))
    print(f"preprocessed in {secs:.2f} s -> {out}")
    return 0
