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


def run(args) -> int:
    from ..contract.dataset.platonerf_layout import export_platonerf, import_platonerf

    if args.direction == "from-platonerf":
        ds = import_platonerf(args.src, args.dst, bin_width_ps=args.bin_ps, bin_width_m=args.bin_m,
                              pulse_fwhm_ps=args.pulse_fwhm_ps, window_bins=args.window_bins)
        print(f"imported {len(ds.manifest.spots)} spots -> {ds.root}")
    else:
        out = export_platonerf(args.src, args.dst)
        print(f"exported -> {out}")
    return 0
