"""`convert`: PlatoNeRF public layout <-> this project's dataset directory."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("convert", help="import/export the public PlatoNeRF dataset layout")
    p.add_argument("direction", choices=("from-platonerf", "to-platonerf"))
    p.add_argument("src", help="source directory")
    p.add_argument("dst", help="destination directory")
    p.add_argument("--bin-ps", type=float, default=128.0, help="bin width (ps) when importing (default: paper's 128)")
    p.add_argument("--bin-m", type=float, default=0.0384, help="bin width in metres of optical path (default 0.0384)")
    p.add_argument("--pulse-fwhm-ps", type=float, default=128.0)
    p.add_argument("--window-bins", type=int, default=None,
                   help="store a window of this many bins per pixel instead of the dense cube")
    p.set_defaults(func=run)


#: top-level names of the PlatoNeRF layout this project writes
PLATONERF_ENTRIES = ("transforms_train.json", "transforms_test.json", "transients", "ground_truth", "*.json", "*.npy")


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
    if args.direction == "from-platonerf":
        ds = import_platonerf(args.src, args.dst, bin_width_ps=args.bin_ps, bin_width_m=args.bin_m,
                              pulse_fwhm_ps=args.pulse_fwhm_ps, window_bins=args.window_bins)
        print(f"imported {len(ds.manifest.spots)} spots -> {ds.root}")
    else:
        ds = load_dataset(args.src)
        with StagedDir(args.dst, "PlatoNeRF layout", legacy=PLATONERF_ENTRIES,
                       marker="transforms_train.json") as st:
            export_platonerf(ds, st.path)     # written whole, then swapped in
            out = st.commit()
        print(f"exported -> {out}")
    return 0
