"""Simulator side of the stress suite: adversarial scenes run through the Cycles simulator in ONE process.

Cycles start-up costs seconds per process, so tests/support/stress_fixtures.py runs every simulator
case of a selection through one worker:

    python tests/support/stress_sim_worker.py --cases sim-room-0.1m,sim-all-shadow --work DIR --results FILE.jsonl

Each case builds an example scene (optionally scaled/stretched, with extra boxes or a laser
offset from the camera), applies SimulationConfig settings and calls pipeline.simulator.run
exactly as `pipeline/simulate.py` does, catching what simulate.py turns into exit code 2
(a refusal). Anything else is a crash. One JSON line per case, written as soon as it ends,
so a worker that dies still leaves the cases before it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

# A spec: example scene, optional uniform 'scale' (time settings scale with it so the paths fit),
# 'stretch' (sx, sy, sz), 'keep' (names of parts to keep), 'extra' boxes (name, lo, hi, albedo),
# 'targets' (explicit laser targets, world m, after scaling), 'laser_offset' (m, laser origin
# beside the camera), 'config' (SimulationConfig fields), 'scale_time' (False: keep the
# paper's 128 ps bins whatever the scale).
BASE = {"width": 16, "height": 16, "test_views_dolly": 1, "test_views_orbit": 1, "test_view_resolution": 16,
        "random_keep": 4}
PANEL = ("panel", (-0.3, 2.0, -0.3), (0.3, 2.02, 0.3), 0.7)
BACK = ("back", (-2.0, 4.0, -2.0), (2.0, 4.02, 2.0), 0.7)

SIM_CASES = {
    # rooms from 0.1 m to 100 m: geometry, bin width, pulse and footprint scale together
    "sim-room-0.1m": {"example": "cave-chair", "scale": 0.025},
    "sim-room-1m": {"example": "cave-chair", "scale": 0.25},
    "sim-room-4m": {"example": "cave-chair", "scale": 1.0},
    "sim-room-10m": {"example": "cave-chair", "scale": 2.5},
    "sim-room-100m": {"example": "cave-chair", "scale": 25.0},
    # a 100 m room with the paper's 128 ps x 391 bins (15 m of path): must be refused, naming 'bins'
    "sim-range-too-short": {"example": "cave-chair", "scale": 25.0, "scale_time": False},
    # a 20 m deep corridor; the laser grazes the floor at ~84 degrees of incidence
    "sim-grazing-spot": {"example": "cave-chair", "stretch": (1.0, 5.0, 1.0), "targets": [(0.0, 19.0, -2.0),
                                                                                         (-2.0, 18.0, 0.0)],
                         "config": {"bins": 1200}},
    # laser 1 mm beside the camera: laser rays almost colinear with the pixel rays
    "sim-laser-offset-1mm": {"example": "cave-chair", "laser_offset": (0.001, 0.0, 0.0)},
    # a surface touching the sensor: a slab from y = 0 (the sensor plane) to 5 cm, lower left of the view
    "sim-surface-at-sensor": {"example": "cave-chair", "extra": [("slab", (-2.0, 0.0, -2.0), (-0.01, 0.05, -0.01),
                                                                    0.7)]},
    # the sensor inside a 2 cm box: every pixel sees a surface 1 cm away
    "sim-sensor-inside-box": {"example": "cave-chair", "extra": [("cage", (-0.01, -0.01, -0.01),
                                                                    (0.01, 0.01, 0.01), 0.7)],
                              "targets": [(0.0, 3.0, 0.0)]},
    # the empty room (convex): no shadows at all
    "sim-no-shadows": {"example": "cave-chair", "keep": ("wall", "floor", "ceiling", "back")},
    # a panel facing the sensor in front of the back wall, the laser on the panel: every two-bounce
    # path is blocked (the wall sees the panel's back), only the first-bounce return remains
    "sim-all-shadow": {"example": "cave-chair", "keep": (), "extra": [BACK, PANEL], "targets": [(0.0, 2.0, 0.0)]},
    "sim-all-shadow-radiance": {"example": "cave-chair", "keep": (), "extra": [BACK, PANEL],
                                "targets": [(0.0, 2.0, 0.0)], "config": {"photons_per_pixel": 0.0}},
    # photon-starved and saturating sensors, single-bin pulse, ambient with a time gate
    "sim-photons-1": {"example": "cave-chair", "config": {"photon_counts": True, "photons_per_pixel": 1.0}},
    "sim-photons-10": {"example": "cave-chair", "config": {"photon_counts": True, "photons_per_pixel": 10.0}},
    "sim-photons-3-seed7": {"example": "cave-chair", "config": {"photon_counts": True, "photons_per_pixel": 3.0,
                                                                "seed": 7}},
    "sim-photons-3-seed7-again": {"example": "cave-chair", "config": {"photon_counts": True,
                                                                      "photons_per_pixel": 3.0, "seed": 7}},
    "sim-saturating": {"example": "cave-chair", "config": {"photon_counts": True, "photons_per_pixel": 1e9}},
    "sim-box-pulse": {"example": "cave-chair", "config": {"pulse_shape": "box", "photon_counts": True,
                                                          "photons_per_pixel": 200.0}},
    "sim-ambient-gated": {"example": "cave-chair", "config": {"photon_counts": True, "photons_per_pixel": 100.0,
                                                              "ambient_per_bin": 5.0, "time_gate": True,
                                                              "gate_window_bins": 8}},
    "sim-zero-spots-hit": {"example": "cave-chair", "targets": [(0.0, -3.0, 0.0)]},   # behind the sensor
}


def scaled_scene(spec):
    """The example scene of `spec` with its geometry transformed, filtered and extended."""
    import numpy as np

    from torch_recon.contract import scenes

    ex = scenes.example(spec["example"])
    s = np.asarray(spec.get("stretch", (1.0, 1.0, 1.0)), float) * float(spec.get("scale", 1.0))
    keep = spec.get("keep")
    parts = []
    for p in ex.parts:
        if keep is not None and not any(k in p.name for k in keep):
            continue
        p.vertices = np.asarray(p.vertices, float) * s      # sensor at the origin: scaling keeps it in place
        parts.append(p)
    for name, lo, hi, alb in spec.get("extra", ()):
        parts.append(scenes.box(name, np.asarray(lo, float) * s, np.asarray(hi, float) * s, alb))
    ex.parts = parts
    ex.spot_targets = [list(np.asarray(t, float) * s) for t in ex.spot_targets]
    for light in ex.lights:
        light.location = tuple(np.asarray(light.location, float) * s)
    return ex


def run_case(name, out: Path) -> dict:
    import bpy

    from pipeline import blender_scene as bs
    from pipeline import simulator
    from torch_recon.contract.simulation import ConfigError, SpotConfig

    spec = SIM_CASES[name]
    ex = scaled_scene(spec)
    bs.build_example(ex)
    cfg = bs.stored_config()
    scale = float(spec.get("scale", 1.0))
    for k, v in BASE.items():
        setattr(cfg, k, v)
    if spec.get("scale_time", True) and scale != 1.0:
        cfg.bin_ps *= scale
        cfg.pulse_fwhm_ps *= scale
        cfg.footprint_radius_m *= scale
    for k, v in spec.get("config", {}).items():
        setattr(cfg, k, v)
    if "targets" in spec:
        cfg.spots = [SpotConfig(target=list(map(float, t)), name=f"stress_{i}") for i, t in enumerate(spec["targets"])]
        cfg.random_keep = min(cfg.random_keep, len(cfg.spots))
    if "laser_offset" in spec:
        laser = bpy.data.objects.new("laser", None)
        bpy.context.scene.collection.objects.link(laser)
        laser.location = spec["laser_offset"]
        cfg.laser_object = "laser"
        bpy.context.view_layer.update()
    refusals = (ConfigError, simulator.SimulationError, bs.SceneError, FileExistsError)
    t0 = time.perf_counter()
    try:
        cfg.validate(f"stress case {name}")
        simulator.run(cfg, str(out), f"stress:{name}", keep_requested=True)
    except refusals as exc:
        return {"status": "refused", "message": str(exc), "seconds": time.perf_counter() - t0}
    except Exception as exc:  # noqa: BLE001 - anything else is what simulate.py would show as a traceback
        from torch_recon.contract.dataset import DatasetError
        if isinstance(exc, DatasetError):
            return {"status": "refused", "message": str(exc), "seconds": time.perf_counter() - t0}
        return {"status": "crash", "message": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=6), "seconds": time.perf_counter() - t0}
    return {"status": "ok", "dataset": str(out), "seconds": time.perf_counter() - t0,
            "settings": {"bin_ps": cfg.bin_ps, "bins": cfg.bins, "scale": scale}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", required=True, help="comma-separated case names")
    ap.add_argument("--work", required=True, help="folder for the datasets")
    ap.add_argument("--results", required=True, help="JSON-lines file to append results to")
    args = ap.parse_args()
    from pipeline.simulate import _add_venv_site_packages
    _add_venv_site_packages()
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    with open(args.results, "a") as f:
        for name in args.cases.split(","):
            if name not in SIM_CASES:
                res = {"status": "crash", "message": f"unknown simulator case {name!r}"}
            else:
                res = run_case(name, work / name)
            f.write(json.dumps({"name": name, **res}) + "\n")
            f.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
