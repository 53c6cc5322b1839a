"""`convert`: the authors' PlatoNeRF layouts (simulated and real captures) <-> our dataset directory."""

from __future__ import annotations


def _indices(text: str) -> list[int]:
    try:
        return [int(v) for v in text.replace("[", "").replace("]", "").split(",") if v.strip()]
    except ValueError:
        raise ValueError(f"--ignore: expected frame indices like 0,1,2,3,10,13,20,22, got {text!r}") from None


def register(sub) -> None:
    p = sub.add_parser("convert", help="import/export the authors' PlatoNeRF dataset layouts",
                       description="from-platonerf / to-platonerf: their simulated layout (transforms_train.json "
                                   "+ float16 .npy cubes); from-platonerf-real: their real-capture .mat files "
                                   "(becomes a measurements-only dataset). Frames: docs/dataset_format.md.")
    p.add_argument("direction", choices=("from-platonerf", "to-platonerf", "from-platonerf-real"))
    p.add_argument("src", help="source directory")
    p.add_argument("dst", help="destination directory")
    p.add_argument("--bin-ps", type=float, default=128.0, help="bin width (ps) when importing (default: paper's 128)")
    p.add_argument("--bin-m", type=float, default=0.0384, help="bin width in metres of optical path (default 0.0384)")
    p.add_argument("--pulse-fwhm-ps", type=float, default=128.0)
    p.add_argument("--window-bins", type=int, default=None,
                   help="store a window of this many bins per pixel instead of the dense cube")
    p.add_argument("--ignore", type=_indices, default=None,
                   help="frames to import as disabled spots, e.g. 0,1,2,3,10,13,20,22 (their chair config); "
                        "default: the 'ignore' list in transforms_train.json, else none")
    p.add_argument("--train-depth", help="a .npy range image of the train view to import as ground truth")
    p.add_argument("--float32", action="store_true",
                   help="to-platonerf: write float32 cubes (lossless) instead of their float16")
    p.add_argument("--spots", type=int, default=16, help="from-platonerf-real: illumination spots (default 16)")
    p.set_defaults(func=run)


#: top-level names of the PlatoNeRF layout this project writes
PLATONERF_ENTRIES = ("transforms_train.json", "transforms_test.json", "platonerf_config.txt", "train", "test",
                     "transients", "ground_truth", "*.json", "*.npy")


def run(args) -> int:
    from ..contract.dataset import load_dataset
    from ..contract.dataset.platonerf_layout import export_platonerf, import_platonerf
    from ..contract.dataset.staging import StagedDir
    from ..contract.errors import SettingsError

    for key, v in (("bin-ps", args.bin_ps), ("bin-m", args.bin_m), ("pulse-fwhm-ps", args.pulse_fwhm_ps)):
        if not v > 0:
            raise SettingsError(key, f"expected a number > 0, got {v}")
    if args.window_bins is not None and args.window_bins < 1:
        raise SettingsError("window-bins", f"expected at least 1, got {args.window_bins}")
    if args.spots < 1:
        raise SettingsError("spots", f"expected at least 1, got {args.spots}")
    if args.direction == "from-platonerf":
        ds = import_platonerf(args.src, args.dst, bin_width_ps=args.bin_ps, bin_width_m=args.bin_m,
                              pulse_fwhm_ps=args.pulse_fwhm_ps, window_bins=args.window_bins, ignore=args.ignore,
                              train_depth=args.train_depth)
        gt = ds.manifest.ground_truth
        print(f"imported {len(ds.manifest.spots)} spots ({len(ds.manifest.enabled_spots)} enabled)"
              + (f", {len(gt.test_views.camera_to_world)} test views" if gt.test_views else "") + f" -> {ds.root}")
    elif args.direction == "from-platonerf-real":
        from ..contract.dataset.platonerf_real import import_platonerf_real

        ds = import_platonerf_real(args.src, args.dst, spots=args.spots)
        s = ds.sensor
        print(f"imported a real capture: {s.width}x{s.height} pixels, {len(ds.manifest.spots)} spots "
              f"(measurements dataset) -> {ds.root}")
    else:
        ds = load_dataset(args.src)
        with StagedDir(args.dst, "PlatoNeRF layout", legacy=PLATONERF_ENTRIES,
                       marker="transforms_train.json") as st:
            export_platonerf(ds, st.path, sample_type="float32" if args.float32 else "float16")  # whole, then swapped in
            out = st.commit()
        print(f"exported -> {out} (their loader: load_tof_data('{out}', ignore) with ignore from "
              f"{out / 'platonerf_config.txt'})")
    return 0
