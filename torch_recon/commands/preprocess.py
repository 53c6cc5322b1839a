"""`preprocess`: dataset -> measurements .npz (first bounces, shadow masks, two-bounce paths, visible depth)."""

from __future__ import annotations


def add_device_arg(p) -> None:
    p.add_argument("--device", default="cpu", help="torch device: cpu, cuda, cuda:1 ... (default cpu)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for torch (default: torch's choice; 1 is faster on a busy machine)")


def resolve_device(name: str, threads: int | None = None) -> str:
    import torch
    if threads is not None:
        if threads < 1:
            raise ValueError(f"--threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(f"--device {name}: CUDA is not available in this torch build/machine; use --device cpu")
    return name


def add_preprocess_args(p) -> None:
    p.add_argument("--shadow-threshold", type=float, default=0.15,
                   help="matched-filter confidence below which a pixel is in shadow (paper 0.15)")
    p.add_argument("--parallel-sin", type=float, default=0.05,
                   help="exclude pixels within asin(this) of the ray to the laser spot (paper 0.05)")
    p.add_argument("--refine", choices=("lut", "gaussian", "parabola", "none"), default="lut",
                   help="sub-bin peak refinement (default lut: pulse-model lookup table)")
    p.add_argument("--background", choices=("none", "median"), default="none",
                   help="subtract each pixel's median (ambient) before the matched filter")
    p.add_argument("--gate-max-m", type=float, default=None, help="ignore returns beyond this optical path (m)")


def settings_from_args(args):
    from ..preprocess import PreprocessSettings
    s = PreprocessSettings(shadow_threshold=args.shadow_threshold, parallel_sin=args.parallel_sin,
                           refine=args.refine, background=args.background, gate_max_m=args.gate_max_m)
    s.validate()
    return s


def register(sub) -> None:
    p = sub.add_parser("preprocess", help="transients -> measurements (.npz)",
                       description="First bounce, pulse, time gate, matched filter (shadow masks), sub-bin "
                                   "two-bounce paths and the closed-form visible depth, for every enabled spot.")
    p.add_argument("dataset", help="dataset directory (dataset.json)")
    p.add_argument("--out", required=True, help="output .npz")
    add_preprocess_args(p)
    add_device_arg(p)
    p.set_defaults(func=run)


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
    from ..preprocess import preprocess_dataset

    settings = settings_from_args(args)
    device = resolve_device(args.device, args.threads)
    out = Path(args.out)
    if out.suffix != ".npz":
        raise ValueError(f"--out {out}: expected a .npz file name")
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
