"""`advise-spots`: where to aim the next laser spots, from a dataset and its fast fit (recon/spot_advice.py)."""

from __future__ import annotations

ADVISE_FLAGS = ("add", "candidates", "occupied_prior", "beyond_view_deg", "pixel_stride", "back_faces", "refine_voxels",
                "seed", "device", "threads")


def register(sub) -> None:
    from ..recon.spot_advice import AdviceSettings
    from . import add_stage

    add_stage(sub, "advise-spots", run, AdviceSettings, ADVISE_FLAGS,
              help="where to aim the next laser spots (from a fast fit's shadow hull)",
              description="Finds the shadow hull of a fast fit that no lit segment crosses (space only shadows "
                          "bound) and advises laser spots whose light would pass it: visible surface points "
                          "the laser reaches, scored by the hull voxels their segments to the sensor-visible "
                          "points would carve and the hidden back faces (a table's underside) they would graze. "
                          "Prints one line per spot and the simulator's --spot-list.",
              arguments=((("dataset",), {"help": "dataset directory (dataset.json) the fit was made from"}),
                         (("fit_dir",), {"metavar": "FIT_DIR", "help": "output folder of `platolidar fit --mode "
                                                                       "fast` (volume.npz, fit.json)"}),
                         (("--out",), {"help": "also write the advice as JSON to this file"})))


def run(args) -> int:
    import json
    from pathlib import Path

    from ..contract.errors import SettingsError
    from ..contract.settings import from_args
    from ..recon.api import source_path
    from ..recon.spot_advice import AdviceSettings, advise_spots, load_fit_volume

    s = from_args(AdviceSettings, args)
    s.validate()
    out = Path(args.out) if args.out else None
    if out is not None and (out.is_dir() or out.suffix != ".json"):
        raise SettingsError("out", f"expected a .json file name, got {out}" + (" (a folder)" if out.is_dir() else ""))
    source_path(args.dataset)           # the inputs in argument order, each refused before preprocessing
    load_fit_volume(args.fit_dir)
    advice = advise_spots(args.dataset, args.fit_dir, s)
    print(f"shadow hull no lit segment crosses: {advice.hull_voxels} voxels of {advice.voxel_m * 100:.1f} cm "
          f"({advice.reached_by_existing} reached by the {len(advice.existing)} spots' segments, all shadowed)")
    print("  spot  world x, y, z (m)              pixel (col, row)  hull voxels reached  expected carved")
    for i, sp in enumerate(advice.spots):
        px = "beyond the view" if sp.pixel is None else f"({sp.pixel[0]}, {sp.pixel[1]})"
        print(f"  {i:4d}  {sp.point[0]:8.3f} {sp.point[1]:8.3f} {sp.point[2]:8.3f}   {px:16s}  "
              f"{sp.voxels:19d}  {sp.gain:15.0f}")
    for note in advice.notes:
        print(f"note: {note}")
    if advice.spots:
        print(f"simulate the advised spots: --spot-list={advice.spot_list()}")
        print(f"with the dataset's spots:   --spot-list={advice.spot_list(include_existing=True)}")
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(advice.to_json(), indent=1) + "\n")
        tmp.replace(out)                # never a half-written file
        print(f"advice -> {out}")
    return 0
