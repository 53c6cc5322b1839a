"""One fit setting swept on the Cycles-simulated cave-chair: fit wall time against test-view error per value.

This is how the fast mode's defaults were chosen (docs/reconstruction.md). Each value is a separate
`torch_recon fit DATASET --set KEY=VALUE` process followed by `torch_recon evaluate` of its mesh on every
test view of the dataset, exactly what a user runs. One suite per swept setting (settings_<key>); any
other FitConfig key can be swept with `--set key=... --set values=[...]` on one of them.
"""

from __future__ import annotations

from dataclasses import dataclass

from benchmarks.harness import Refused, Suite, report, runners


@dataclass(frozen=True)
class Settings:
    key: str = "fast.lr"
    values: tuple[str, ...] = ("0.01", "0.05", "0.2", "0.5")
    example: str = "cave-chair"
    resolution: int = 128
    steps: int | None = None             # None: the mode's default
    max_seconds: float = 300.0           # fit budget per value
    extra: tuple[str, ...] = ()          # more KEY=VALUE settings for every run
    test_views: int | None = None        # None: the simulator's default (the paper's 139)
    test_view_resolution: int | None = None


def run(s: Settings, ctx) -> list[dict]:
    ds = ctx.dataset(s.example, s.resolution, test_views=s.test_views, test_view_resolution=s.test_view_resolution)
    rows = []
    for v in s.values:
        tag = f"{s.key}={v}".replace("/", "_")
        try:
            r = runners.fit(ctx, ds, tag, steps=s.steps, max_seconds=s.max_seconds, sets=(*s.extra, f"{s.key}={v}"),
                            uv=True)     # as a user runs fit: the wall time includes the UV atlas
        except Refused as exc:
            rows.append(runners.refused_row("fast", s.example, exc, key=s.key, value=v))
            continue
        rows.append(runners.row("fast", s.example, r, (*runners.METRICS, "steps", "stopped", "train_s"),
                                key=s.key, value=v))
    return rows


def plot(rows, settings, path):
    report.plot_rows(rows, path, y="depth_l1_m", label=lambda r: f"{r['key']}={r['value']}", kind="bar",
                     title=f"fast mode, {settings.example} {settings.resolution} px: {settings.key} sweep")


def readme(results) -> str:
    return report.markdown_table(results["rows"], [
        ("value", results["rows"][0]["key"]), ("wall_s", "fit wall s"), ("steps", "steps"),
        ("depth_l1_m", "depth L1 m"), ("depth_psnr_db", "PSNR dB"), ("chamfer_m", "Chamfer m"),
        ("fscore", "F-score"), ("n_reconstruction_misses", "misses")])


def _sweep(key, values, quick_values=None, **full):
    name = "settings_" + key.replace(".", "_")
    quick = Settings(key=key, values=quick_values or values[:2], resolution=32, max_seconds=60.0, test_views=6,
                     steps=None if key == "steps" else 20,      # --steps would override the swept steps
                     test_view_resolution=32, extra=("fast.resolution=48", "fast.coarse_resolution=24"))
    return Suite(name, f"fast mode: {key} swept over {', '.join(values)} (fit + evaluate per value)",
                 quick=quick, full=Settings(key=key, values=values, **full), run=run, plot=plot, readme=readme)


SUITES = [
    _sweep("fast.lr", ("0.01", "0.05", "0.2", "0.5"), steps=200),
    _sweep("steps", ("0", "200"), quick_values=("0", "20")),
    _sweep("fast.carve_min_lit", ("1", "1000000")),
    _sweep("fast.occupancy_threshold", ("0.01", "-1"), max_seconds=400.0),
]
