"""Spot advice: an adaptive capture of the issue's 16 spots against the scene's default 16.

Per scene (default: the three whose hidden space the default 16 spots leave unbounded) and per first-pass
size K in `keeps`: a first pass of K of the scene's spots is simulated and fitted (`first_pass`: "spread", the
simulator's `--spots K`, which keeps the K most spread-out of the scene's spots, contract.spots.select_diverse_spots,
as a user's first pass does; or "first", its first K: a scene's spots beyond the view come last); the advisor
(torch_recon.recon.spot_advice, run as the CLI a user runs) picks `total` - K more from that fit; the scene
is simulated again with the K + advised spots, fitted and evaluated: the two-pass capture (README "Where to
aim the next spots"). Controls (`controls`), each its own simulated dataset and fast fit: the scene's default
spots ("default", `total` of them), and per K the K alone ("alone") and K + the same count of spread-out spots
from the scene's own unused random candidates ("spread"; the same count without the advice). Rows carry the object
metrics (obj F@2cm, hidden recall@2cm, spurious) and the fit's time; the advisor's own time in `advise_wall_s`.
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
    scenes: tuple[str, ...] = ("organic-occluded", "dark-room", "outside-fov")
    resolution: int = 128
    total: int = 16                 # spots of the capture (the scene default's count, the 16)
    keeps: tuple[int, ...] = (12,)  # first-pass sizes K; the advisor adds total - K
    first_pass: str = "spread"      # the first pass's K of the scene's spots: spread-out (--spots K) or its first K
    controls: tuple[str, ...] = ("default", "alone", "spread")   # the scene's default spots; per K: the K alone,
                                    # K + spread-out unused candidates
    beyond_view_deg: str = ""       # scene:deg pairs (none: as far as the first pass's spots lie); other
                                    # scenes: the advisor's default (in view only)
    back_faces: bool = False        # the advisor's --back-faces (aim at the fit's hidden back faces too)
    candidates: int = 300           # the advisor's --candidates
    seed: int = 0
    threads: int = 2                # CPU threads of each fit
    timeout_s: float = 1800.0

    SETTINGS_META = {"first_pass": {"choices": ("spread", "first")}, "total": {"range": (2, None)},
                     "threads": {"range": (1, None)}, "candidates": {"range": (1, None)}}

    def __post_init__(self):
        from torch_recon.contract.errors import SettingsError
        for k in self.keeps:
            if not 1 <= k < self.total:
                raise SettingsError("keeps", f"expected first-pass sizes in [1, total={self.total}), got {k}")
        bad = set(self.controls) - {"default", "alone", "spread"}
        if bad:
            raise SettingsError("controls", f"expected any of default, alone, spread; got {', '.join(sorted(bad))}")


def spot_list(points) -> str:
    """The simulator's --spot-list text for world points (m)."""
    return ";".join(",".join(f"{v:.4f}" for v in p) for p in points)


def scene_spots(dataset) -> tuple[list, list]:
    """(enabled targets, unused random candidates) recorded in a simulated dataset's provenance."""
    meta = json.loads((dataset / "dataset.json").read_text())
    spots = meta["provenance"]["extra"]["config"]["spots"]
    return ([s["target"] for s in spots if s["enabled"]], [s["target"] for s in spots if not s["enabled"]])


def simulated_spots(dataset) -> list:
    """The first-bounce points (world, m) of the spots a dataset holds, in its order."""
    return [s["first_bounce"] for s in json.loads((dataset / "dataset.json").read_text())["spots"]]


def select_diverse(points, count: int, seed: int) -> list:
    from torch_recon.contract.spots import select_diverse_spots
    return list(select_diverse_spots(np.asarray(points, np.float64), None, count, np.random.default_rng(seed)))


def _beyond(s: Settings, scene: str) -> str:
    pairs = dict(p.split(":") for p in s.beyond_view_deg.split(",") if p)
    return pairs.get(scene, "0")


def run(s: Settings, ctx) -> list:
    rows = []

    def measure(scene, label, ds, **extra):
        try:
            res = runners.fit(ctx, ds, f"{scene}-{label}", threads=s.threads, timeout=s.timeout_s)
        except runners.Refused as exc:  # e.g. an advised spot beyond the view whose light the sensor never sees
            rows.append(ctx.keep(runners.refused_row(label, scene, exc, load_1min=ctx.load_1min(), **extra)))
            return
        rows.append(ctx.keep({"method": label, "scene": scene, **{k: res.get(k) for k in TIMES},
                              "load_1min": ctx.load_1min(), "depth_l1_m": res.get("depth_l1_m"),
                              **{k: res.get(k) for k in runners.OBJECT_FIELDS}, **extra}))
        ctx.log(f"  {scene} {label}: F@2cm {fmt(res.get('obj_f2cm'))}, hidden R {fmt(res.get('hidden_recall_2cm'))}, "
                f"spurious {fmt(res.get('spurious'))}, L1 {fmt(res.get('depth_l1_m'))}")

    def simulated(scene, points):
        return ctx.dataset(scene, s.resolution, None, spot_list=spot_list(points))

    for scene in s.scenes:
        default = ctx.dataset(scene, s.resolution, s.total)
        enabled, unused = scene_spots(default)
        if "default" in s.controls:
            measure(scene, f"{len(enabled)} spots (scene default)", default)
        for keep in s.keeps:
            add = s.total - keep
            if s.first_pass == "first":
                kept = enabled[:keep]
                first, first_label = simulated(scene, kept), f"{keep} spots"
            else:   # the simulator's own spread-out choice, what a user's `simulate --spots K` captures
                first = ctx.dataset(scene, s.resolution, keep)
                kept, first_label = simulated_spots(first), f"{keep} spots (--spots {keep})"
            first_fit = ctx.work_dir / f"{scene}-{first_label}"
            if "alone" in s.controls:
                measure(scene, first_label, first)
            else:       # the advisor needs the first pass's fit; not a row of its own
                runners.fit(ctx, first, first_fit.name, threads=s.threads, timeout=s.timeout_s)
            advice_json = ctx.work_dir / f"{scene}-{keep}-advice.json"
            run_adv = ctx.run_cli([*runners.RECON, "advise-spots", first, first_fit, "--add", add,
                                   "--beyond-view-deg", _beyond(s, scene), "--seed", s.seed, "--threads", s.threads,
                                   "--candidates", s.candidates, "--back-faces" if s.back_faces else "--no-back-faces",
                                   "--out", advice_json], timeout=s.timeout_s)
            advised = [a["point"] for a in json.loads(advice_json.read_text())["advised"]]
            if "spread" in s.controls:
                spread = [unused[i] for i in select_diverse(unused, add, s.seed)]
                measure(scene, f"{first_label.replace(' spots', '')} + {add} spread-out",
                        simulated(scene, kept + spread))
            measure(scene, f"{first_label.replace(' spots', '')} + {len(advised)} advised",
                    simulated(scene, kept + advised),
                    advise_wall_s=run_adv.wall_s, advised=spot_list(advised), first_pass=spot_list(kept))
    return rows


COLUMNS = (("scene", "scene"), ("method", "spots"), ("obj_f2cm", "obj F@2cm", ".3f"),
           ("hidden_recall_2cm", "hidden R@2cm", ".3f"), ("spurious", "spurious", ".3f"),
           ("depth_l1_m", "L1 m", ".4f"), ("wall_s", "fit s", ".0f"), ("advise_wall_s", "advise s", ".0f"),
           ("load_1min", "load", ".1f"), ("run", "run"))


def readme(results: dict) -> str:
    rows = results["rows"]
    first = {r["scene"]: i for i, r in reversed(list(enumerate(rows)))}    # merged runs: each scene's rows together
    return markdown_table(sorted(rows, key=lambda r: first[r["scene"]]), COLUMNS)


def plot(rows, settings, path):
    plot_rows(rows, path, title="spot advice: object F@2cm against fit time", y="obj_f2cm")


SUITE = Suite("spot_advice", "two-pass capture: K spots, a fast fit, 16 - K advised spots (advise-spots; issue 11)",
              quick=Settings(scenes=("organic-occluded",)), full=Settings(), run=run, readme=readme, plot=plot)
