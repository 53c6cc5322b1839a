"""The paper's ablations with the fast mode: spots, shadow threshold, spatial and temporal resolution, scenes.

Data: Cycles datasets of the example scenes (16 of the paper's spots, 391 bins of 128 ps, 128 x 128 px,
noise-free unless stated), from the harness's dataset cache. Every row runs the same chain through the
harness runners: `torch_recon preprocess` -> measurements .npz (changed in-process where the ablation
needs it: a subset of the spots) -> `torch_recon fit` (the fast mode's own grid and steps unless the
settings say otherwise, the same for every row) -> `torch_recon evaluate` of its mesh on the dataset's
test views (the paper's 139 on cave-chair). Each row: depth L1 / PSNR on the test views and the
object-level numbers of issue 11 (runners.object_fields: object F@2cm, hidden recall@2cm, spurious
fraction). Wall time = preprocess + fit processes (start-up, reading, mesh export included; evaluation
excluded). A level that leaves no two-bounce return is refused by fit and recorded as such.
- spots: 16 / 8 / 4 / 2 spots: every 2nd / 4th / 8th of the 16 (by id), visible depth re-fused
  (paper, its Table: 0.0862 / 0.0912 / 0.1347 / 0.2147 m);
- shadow: matched-filter shadow threshold 0 to 1 in steps of 0.125 (paper default 0.15);
- spatial: sensor resolution 32 / 64 / 128 / 512 px (simulated at each);
- temporal: 128 / 256 / 512 / 1024 ps bins by summing 1 / 2 / 4 / 8 adjacent bins of the 128 ps dataset;
- scenes: cave-chair vs low-albedo walls vs a curved back wall.
(ambient light: suites/ablation_ambient.py.)
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from benchmarks.harness import Refused, Suite, report, runners
from benchmarks.harness.report import fmt
from benchmarks.harness.datasets import integrated_dataset

FIELDS = ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore", "steps", "obj_f2cm", "obj_f5cm", "hidden_recall_2cm",
          "spurious", "degenerate_faces", "n_test_views")


@dataclass(frozen=True)
class Settings:
    levels: tuple[str, ...] = ()         # the ablation's levels (as text; each suite parses its own)
    example: str = "cave-chair"
    resolution: int = 128                # sensor of the base dataset
    grid: int | None = None              # fast-mode grid (None: the mode's own, fast.resolution)
    steps: int | None = None             # fixed steps (None: the mode's own): rows stay comparable on a shared machine
    budget_s: float | None = None        # a wall-clock cap per fit (None: none; a cap makes rows depend on the load)
    test_views: int | None = None        # None: the scene's own test views (cave-chair: the paper's 139)
    test_view_resolution: int | None = None
    threads: int = 2                     # fit --threads (object metrics do not depend on it)


def dataset(ctx, s: Settings, example=None, resolution=None, **options):
    return ctx.dataset(example or s.example, resolution or s.resolution, test_views=s.test_views,
                       test_view_resolution=s.test_view_resolution, **options)


def fit_row(ctx, s: Settings, level, data, prep: dict, tag: str, transform=None, **extra) -> dict:
    """One row: the preprocessed measurements (optionally changed by `transform(meas) -> meas`, saved
    as a new .npz), a fast fit of them and its evaluation on `data`'s test views."""
    from torch_recon.measurements import Measurements
    meas = Measurements.load(prep["measurements"])
    source = prep["measurements"]
    if transform is not None:
        with ctx.timed() as t:
            meas = transform(meas)
            source = meas.save(ctx.work_dir / f"{tag}-changed.npz")
        prep = {**prep, **runners.combined(prep, t.times())}
    info = {"level": level, "signal_fraction": float(np.mean([np.mean(sp.signal) for sp in meas.spots])), **extra}
    try:
        grid = () if s.grid is None else (f"fast.resolution={s.grid}", f"fast.coarse_resolution={max(8, s.grid // 2)}")
        r = runners.fit(ctx, source, tag, dataset=data, steps=s.steps, max_seconds=s.budget_s, sets=grid,
                        threads=s.threads)
    except Refused as exc:
        return runners.refused_row("fast", s.example, exc, runners.combined(prep, exc.times) if exc.times else prep,
                                   **info)
    row = runners.row("fast", s.example, {**r, **runners.combined(prep, r)}, FIELDS, **info,
                      preprocess_wall_s=prep["wall_s"], load_1min=ctx.load_1min())
    ctx.log(f"  {s.example} {level}: L1 {fmt(row['depth_l1_m'], '.4f')} m, F@2cm {fmt(row['obj_f2cm'], '.3f')}, "
            f"hidden R@2cm {fmt(row['hidden_recall_2cm'], '.3f')}, spurious {fmt(row['spurious'], '.4f')}")
    return ctx.keep(row)


def dataset_row(ctx, s, level, data, tag, **prep_settings) -> dict:
    return fit_row(ctx, s, level, data, runners.preprocess(ctx, data, f"{tag}-meas", **prep_settings), tag)


def spots(s: Settings, ctx) -> list[dict]:
    from torch_recon.visible_depth import fuse_visible_depth
    data = dataset(ctx, s)
    prep = runners.preprocess(ctx, data, "meas")

    def keep(k):
        def subset(meas):
            m = copy.copy(meas)
            m.spots = meas.spots[::max(1, len(meas.spots) // k)][:k]
            fused = fuse_visible_depth(m)
            m.visible_depth, m.visible_confidence = fused.depth, fused.confidence
            return m
        return subset
    return [fit_row(ctx, s, int(k), data, prep, f"spots{k}", transform=keep(int(k)),
                    paper_depth_l1_m=paper_l1(int(k)) if s.example == PAPER_SCENE else None) for k in s.levels]


PAPER_SCENE = "cave-chair"      # the paper's spots table is measured on its chair scene only


def paper_l1(spots: int):
    try:
        return report.paper_result(spots)["depth_l1_m"]
    except KeyError:        # the paper reports 16 / 8 / 4 / 2 spots only
        return None


def shadow(s: Settings, ctx) -> list[dict]:
    data = dataset(ctx, s)
    return [dataset_row(ctx, s, float(t), data, f"shadow{t}", shadow_threshold=t) for t in s.levels]


def spatial(s: Settings, ctx) -> list[dict]:
    return [dataset_row(ctx, s, int(r), dataset(ctx, s, resolution=int(r)), f"res{r}") for r in s.levels]


def temporal(s: Settings, ctx) -> list[dict]:
    base = dataset(ctx, s)
    return [dataset_row(ctx, s, f"{128 * int(f)} ps", integrated_dataset(ctx, base, int(f)), f"bins{f}")
            for f in s.levels]


def scenes(s: Settings, ctx) -> list[dict]:
    return [{**dataset_row(ctx, s, name, dataset(ctx, s, example=name), name), "scene": name} for name in s.levels]


def plot(rows, settings, path):
    """Per level, one colour per scene: test-view depth L1 (bars; the paper's L1 as black dashes where it has
    one) and object F@2cm (solid) / hidden recall@2cm (dashed); refused levels are left empty."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    levels = list(dict.fromkeys(str(r["level"]) for r in rows))
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    x, width = np.arange(len(levels)), 0.8 / len(scenes)

    def values(rs, key):
        by_level = {str(r["level"]): r.get(key) for r in rs}
        return np.array([np.nan if by_level.get(lv) is None else float(by_level[lv]) for lv in levels])
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    for i, scene in enumerate(scenes):
        rs, colour = [r for r in rows if r["scene"] == scene], f"C{i}"
        xs = x + (i - (len(scenes) - 1) / 2) * width
        ax.bar(xs, values(rs, "depth_l1_m"), width, color=colour, label=f"{scene} (fast mode)")
        if any(r.get("paper_depth_l1_m") is not None for r in rs):
            ax.plot(xs, values(rs, "paper_depth_l1_m"), "k_", ms=14, mew=2, label=f"{scene}: paper (PlatoNeRF)")
        bx.plot(x, values(rs, "obj_f2cm"), "o-", color=colour, label=f"{scene} object F@2cm")
        bx.plot(x, values(rs, "hidden_recall_2cm"), "s--", color=colour, label=f"{scene} hidden recall@2cm")
    ax.set_ylabel("test-view depth L1 (m)")
    bx.set_ylabel("object F@2cm, hidden recall@2cm")
    bx.axhline(0.9, color="grey", lw=0.8, ls=":")
    bx.set_ylim(0, 1)
    for a in (ax, bx):
        a.set_xticks(x, levels)
        a.set_xlabel("level")
        a.grid(alpha=0.3, axis="y")
        a.legend(fontsize=7)
    grid = "the mode's grid" if settings.grid is None else f"grid {settings.grid}"
    steps = "the mode's steps" if settings.steps is None else f"{settings.steps} steps"
    fig.suptitle(f"ablation ({', '.join(scenes)}; {settings.resolution} px sensor unless the level says; {grid}, "
                 f"{steps})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def readme(results) -> str:
    rows = [{**r, "level": str(r["level"]), "depth_l1_m": runners.failure(r) or r.get("depth_l1_m"),
             "spurious_pct": None if r.get("spurious") is None else 100 * r["spurious"]} for r in results["rows"]]
    cols = [("level", "level"), ("depth_l1_m", "depth L1 m", ".4f"), ("depth_psnr_db", "PSNR dB", ".2f"),
            ("obj_f2cm", "obj F@2cm", ".3f"), ("hidden_recall_2cm", "hidden R@2cm", ".3f"),
            ("spurious_pct", "spurious %", ".2f"), ("steps", "steps"), ("wall_s", "wall s", ".0f"),
            ("load_1min", "load", ".1f"), ("signal_fraction", "signal fraction", ".2f")]
    if len({r["scene"] for r in rows}) > 1:
        cols.insert(0, ("scene", "scene"))
    if any(r.get("paper_depth_l1_m") is not None for r in rows):
        cols.append(("paper_depth_l1_m", "paper L1 m", ".4f"))
    if any(r.get("run") for r in rows):
        cols.append(("run", "run"))
    return report.markdown_table(rows, cols)


def ablation(name, fn, full_levels, quick_levels, description):
    quick = Settings(levels=quick_levels, resolution=32, grid=48, steps=20, budget_s=60.0, test_views=6,
                     test_view_resolution=32)
    return Suite(f"ablation_{name}", description, quick=quick, full=Settings(levels=full_levels), run=fn, plot=plot,
                 readme=readme, row_id=("method", "scene", "level"))


SUITES = [
    ablation("spots", spots, ("16", "8", "4", "2"), ("16", "2"), "ablation: 16 / 8 / 4 / 2 spots (fast mode)"),
    ablation("shadow", shadow, tuple(str(i * 0.125) for i in range(9)), ("0.0", "0.125", "1.0"),
             "ablation: matched-filter shadow threshold 0 ... 1 (fast mode)"),
    ablation("spatial", spatial, ("32", "64", "128", "512"), ("16", "32"), "ablation: sensor resolution (fast mode)"),
    ablation("temporal", temporal, ("1", "2", "4", "8"), ("1", "4"),
             "ablation: 128 / 256 / 512 / 1024 ps bins, by summing adjacent bins (fast mode)"),
    ablation("scenes", scenes, ("cave-chair", "low-albedo", "curved-wall"), ("cave-chair", "curved-wall"),
             "ablation: cave-chair vs low-albedo walls vs a curved back wall (fast mode)"),
]
