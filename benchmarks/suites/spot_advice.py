"""Spot advice: does aiming spots where `platolidar advise-spots` says beat spots chosen without it?

Per scene (default: the three whose hidden space the default 16 spots leave unbounded) and at the issue's spot
count: the scene's first `keep` spots are simulated and fitted; the advisor (torch_recon.recon.spot_advice, run
as the CLI a user runs) picks `add` more from that fit; the scene is simulated again with the `keep` + advised
spots, fitted and evaluated. Controls, each its own simulated dataset and fast fit: the `keep` spots alone, the
scene's default spots (16), and `keep` + `add` spread-out spots from the scene's own unused random candidates
(contract.spots.select_diverse_spots, seeded): the same count without the advice. Rows carry the object metrics
(obj F@2cm, hidden recall@2cm, spurious) and the fit's time; the advisor's own time in `advise_wall_s`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Suite, runners
from benchmarks.harness.report import fmt, markdown_table, plot_rows

TIMES = ("wall_s", "cpu_s", "peak_rss_mb")


@dataclass
class Settings:
    scenes: tuple = ("organic-occluded", "dark-room", "outside-fov")
    resolution: int = 128
    keep: int = 12                  # the scene's first spots kept (its default is 16)
    add: int = 4                    # spots advised (or spread-out random ones in the control)
    beyond_view_deg: str = "outside-fov:30"   # scene:deg pairs; other scenes advise in view only
    seed: int = 0
    timeout_s: float = 1800.0


def spot_list(points) -> str:
    """The simulator's --spot-list text for world points (m)."""
    return ";".join(",".join(f"{v:.4f}" for v in p) for p in points)


def scene_spots(dataset) -> tuple[list, list]:
    """(enabled targets, unused random candidates) recorded in a simulated dataset's provenance."""
    meta = json.loads((dataset / "dataset.json").read_text())
    spots = meta["provenance"]["extra"]["config"]["spots"]
    return ([s["target"] for s in spots if s["enabled"]], [s["target"] for s in spots if not s["enabled"]])


def _beyond(s: Settings, scene: str) -> float:
    pairs = dict(p.split(":") for p in s.beyond_view_deg.split(",") if p)
    return float(pairs.get(scene, 0.0))


def run(s: Settings, ctx) -> list:
    from torch_recon.contract.spots import select_diverse_spots

    rows = []

    def measure(scene, label, ds, **extra):
        res = runners.fit(ctx, ds, f"{scene}-{label}", timeout=s.timeout_s)
        rows.append(ctx.keep({"method": label, "scene": scene, **{k: res.get(k) for k in TIMES},
                              "load_1min": ctx.load_1min(), "depth_l1_m": res.get("depth_l1_m"),
                              **{k: res.get(k) for k in runners.OBJECT_FIELDS}, **extra}))
        ctx.log(f"  {scene} {label}: F@2cm {fmt(res.get('obj_f2cm'))}, hidden R {fmt(res.get('hidden_recall_2cm'))}, "
                f"spurious {fmt(res.get('spurious'))}, L1 {fmt(res.get('depth_l1_m'))}")

    for scene in s.scenes:
        default = ctx.dataset(scene, s.resolution, 16)
        enabled, unused = scene_spots(default)
        kept = enabled[:s.keep]
        measure(scene, f"{len(enabled)} spots (scene default)", default)
        first = ctx.dataset(scene, s.resolution, None, spot_list=spot_list(kept))
        measure(scene, f"{s.keep} spots", first)
        advice_json = ctx.work_dir / f"{scene}-advice.json"
        run_adv = ctx.run_cli([*runners.RECON, "advise-spots", first, ctx.work_dir / f"{scene}-{s.keep} spots",
                               "--add", s.add, "--beyond-view-deg", _beyond(s, scene), "--seed", s.seed,
                               "--out", advice_json], timeout=s.timeout_s)
        advised = [a["point"] for a in json.loads(advice_json.read_text())["advised"]]
        pick = select_diverse_spots(np.asarray(unused, np.float64), None, s.add, np.random.default_rng(s.seed))
        spread = [unused[i] for i in pick]
        measure(scene, f"{s.keep} + {s.add} spread-out",
                ctx.dataset(scene, s.resolution, None, spot_list=spot_list(kept + spread)))
        measure(scene, f"{s.keep} + {len(advised)} advised",
                ctx.dataset(scene, s.resolution, None, spot_list=spot_list(kept + advised)),
                advise_wall_s=run_adv.wall_s, advised=spot_list(advised))
    return rows


COLUMNS = (("scene", "scene"), ("method", "spots"), ("obj_f2cm", "obj F@2cm", ".3f"),
           ("hidden_recall_2cm", "hidden R@2cm", ".3f"), ("spurious", "spurious", ".3f"),
           ("depth_l1_m", "L1 m", ".4f"), ("wall_s", "fit s", ".0f"), ("advise_wall_s", "advise s", ".0f"),
           ("load_1min", "load", ".1f"), ("run", "run"))


def readme(results: dict) -> str:
    return markdown_table(results["rows"], COLUMNS)


def plot(rows, settings, path):
    plot_rows(rows, path, title="spot advice: object F@2cm against fit time", y="obj_f2cm")


SUITE = Suite("spot_advice", "advised laser spots vs the same count spread out (advise-spots; issue 11)",
              quick=Settings(scenes=("organic-occluded",)), full=Settings(), run=run, readme=readme, plot=plot)
