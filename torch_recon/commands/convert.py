"""`convert`: the authors' PlatoNeRF layouts (simulated and real captures) <-> our dataset directory."""

from __future__ import annotations

from dataclasses import dataclass

from ..contract.dataset.platonerf_layout import PAPER_BIN_WIDTH_M, PAPER_BIN_WIDTH_PS


@dataclass
class ConvertSettings:
    """Settings of `convert` (each direction reads the ones it needs)."""

    bin_ps: float = PAPER_BIN_WIDTH_PS        # from-platonerf: bin width in ps (their cubes do not record it)
    bin_m: float = PAPER_BIN_WIDTH_M          # from-platonerf: bin width in metres of optical path (their TIME_RES_M)
    pulse_fwhm_ps: float = PAPER_BIN_WIDTH_PS  # from-platonerf: laser pulse width (FWHM)
    window_bins: int | None = None            # from-platonerf: store a window of this many bins per pixel
                                              # instead of the dense cube
    ignore: tuple[int, ...] | None = None     # from-platonerf: frames imported as disabled spots, e.g.
                                              # 0,1,2,3,10,13,20,22 (their chair config); default: the
                                              # 'ignore' list in transforms_train.json, else none
    train_depth: str | None = None            # from-platonerf: a .npy range image of the train view (ground truth)
    float32: bool = False                     # to-platonerf: float32 cubes (lossless) instead of their float16
    spots: int = 16                           # from-platonerf-real: illumination spots

    SETTINGS_META = {"bin_ps": {"unit": "ps"}, "bin_m": {"unit": "m"}, "pulse_fwhm_ps": {"unit": "ps"},
                     "window_bins": {"range": (1, None)}, "ignore": {"range": (0, None)},
                     "spots": {"range": (1, None)}}

    def validate(self):
        from ..contract.errors import SettingsError

        for key in ("bin_ps", "bin_m", "pulse_fwhm_ps"):    # widths must be > 0 (a range is inclusive)
            if not getattr(self, key) > 0:
                raise SettingsError(key, f"expected a number > 0, got {getattr(self, key)}")


DIRECTIONS = ("from-platonerf", "to-platonerf", "from-platonerf-real")


def register(sub) -> None:
    from . import add_stage

    add_stage(sub, "convert", run, ConvertSettings, ("bin_ps", "bin_m", "pulse_fwhm_ps", "window_bins", "ignore",
                                                     "train_depth", "float32", "spots"),
              help="import/export the authors' PlatoNeRF dataset layouts",
              description="from-platonerf / to-platonerf: their simulated layout (transforms_train.json + float16 "
                          ".npy cubes); from-platonerf-real: their real-capture .mat files (becomes a "
                          "measurements-only dataset). Frames: docs/dataset_format.md.",
              arguments=((("direction",), {"choices": DIRECTIONS}), (("src",), {"help": "source directory"}),
                         (("dst",), {"help": "destination directory"})))


#: top-level names of the PlatoNeRF layout this project writes
PLATONERF_ENTRIES = ("transforms_train.json", "transforms_test.json", "platonerf_config.txt", "train", "test",
                     "transients", "ground_truth", "*.json", "*.npy")


def _given_keys(args) -> set:
    """Settings the user gave (flag, --set or --config), as opposed to defaults."""
    from ..contract.settings import load_file, parse_assignments

    given = {key for dest, key in getattr(args, "_settings_flags", {}).items() if getattr(args, dest, None) is not None}
    given |= set(parse_assignments(getattr(args, "set_values", None)))
    if getattr(args, "config", None):
        given |= set(load_file(args.config))
    return given


def run(args) -> int:
    from ..contract.dataset import load_dataset
    from ..contract.dataset.platonerf_layout import export_platonerf, import_platonerf
    from ..contract.dataset.staging import StagedDir
    from ..contract.settings import from_args

    s = from_args(ConvertSettings, args)
    if args.direction == "from-platonerf":
        # only what the user gave reaches the import: an export of ours refuses a width that contradicts it
        given = _given_keys(args)
        ds = import_platonerf(args.src, args.dst,
                              **{name: getattr(s, key) if key in given else None
                                 for name, key in (("bin_width_ps", "bin_ps"), ("bin_width_m", "bin_m"),
                                                   ("pulse_fwhm_ps", "pulse_fwhm_ps"), ("window_bins", "window_bins"))},
                              ignore=None if s.ignore is None else list(s.ignore), train_depth=s.train_depth)
        gt = ds.manifest.ground_truth
        print(f"imported {len(ds.manifest.spots)} spots ({len(ds.manifest.enabled_spots)} enabled)"
              + (f", {len(gt.test_views.camera_to_world)} test views" if gt.test_views else "") + f" -> {ds.root}")
    elif args.direction == "from-platonerf-real":
        from ..contract.dataset.platonerf_real import import_platonerf_real

        ds = import_platonerf_real(args.src, args.dst, spots=s.spots)
        sensor = ds.sensor
        print(f"imported a real capture: {sensor.width}x{sensor.height} pixels, {len(ds.manifest.spots)} spots "
              f"(measurements dataset) -> {ds.root}")
    else:
        ds = load_dataset(args.src)
        with StagedDir(args.dst, "PlatoNeRF layout", legacy=PLATONERF_ENTRIES,
                       marker="transforms_train.json") as st:
            export_platonerf(ds, st.path, sample_type="float32" if s.float32 else "float16")  # whole, then swapped in
            out = st.commit()
        print(f"exported -> {out} (their loader: load_tof_data('{out}', ignore) with ignore from "
              f"{out / 'platonerf_config.txt'})")
    return 0
