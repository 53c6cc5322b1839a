"""The summary page of an evaluation: metrics tables, shaded renders and error images (HTML + one PNG montage).

Files written into the evaluation's output folder:
  summary.html              the page: scene metrics, per-object metrics, the pictures below
  summary.png               montage: GT | reconstruction | depth error from 4 viewpoints, and the key numbers
  pictures/views.png        the same montage without the table
  pictures/test_views.png   a few test views: GT range, reconstruction range, |error| (titled, colour bars)
The time breakdown comes from the fit's fit.json next to the evaluated mesh (set-up, optimisation,
volume + mesh export) and the evaluation's own eval_seconds.

write_run_summary() makes one page for several methods on one dataset (the demo): a metrics table
with a row per method, the time of every stage as a titled bar chart, and each method's pictures.
"""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

SUMMARY_HTML = "summary.html"
SUMMARY_PNG = "summary.png"
VIEWS_PNG = "pictures/views.png"
TEST_VIEWS_PNG = "pictures/test_views.png"


def load_gt_objects(dataset, gt_mesh) -> tuple[list, str]:
    """([(label, trimesh)], source): the dataset's labelled objects, else split off the room's shell."""
    import trimesh

    from ..contract.scene_objects import split_mesh_objects
    objs = dataset.manifest.ground_truth.objects
    if objs:
        return [(o.name, trimesh.load(dataset.path(o.mesh_file), force="mesh", process=False)) for o in objs], \
            "labelled"
    if gt_mesh is None:
        return [], "none"
    return sorted(split_mesh_objects(gt_mesh).items()), "split from the room's shell (no labels)"


def _fmt(v, f=".3f"):
    if v is None:
        return "n/a"
    if isinstance(v, float) and not np.isfinite(v):
        return "n/a"
    return format(v, f) if isinstance(v, (int, float)) else str(v)


SCENE_ROWS = (("depth L1 (m), valid test views", "depth_l1_m", ".4f"),
              ("depth PSNR (dB)", "depth_psnr_db", ".2f"),
              ("test views valid / invalid", None, None),
              ("Chamfer (m), whole scene", "chamfer_m", ".4f"),
              ("F-score, whole scene", "fscore", ".3f"))
OBJECT_COLUMNS = (("Chamfer m", "chamfer_m", ".4f"), ("F@1cm", "fscore@1cm", ".3f"), ("F@2cm", "fscore@2cm", ".3f"),
                  ("F@5cm", "fscore@5cm", ".3f"), ("P@2cm", "precision@2cm", ".3f"),
                  ("recall vis@2cm", "recall_visible@2cm", ".3f"), ("recall hidden@2cm", "recall_hidden@2cm", ".3f"),
                  ("spurious", "spurious_fraction", ".3f"), ("normals", "normal_consistency", ".3f"))


def scene_lines(report) -> list:
    """(name, value) rows of the scene table."""
    rows = []
    for name, key, f in SCENE_ROWS:
        if key is None:
            rows.append((name, f"{report.get('n_test_views', 0)} / {report.get('n_test_views_invalid', 0)}"))
        else:
            rows.append((name, _fmt(report.get(key), f)))
    surf = report.get("object_metrics", {}).get("scene", {})
    rows += [("spurious surface (> 2 cm), whole mesh", _fmt(surf.get("spurious_fraction"))),
             ("spurious surface, objects' region", _fmt(surf.get("objects_spurious_fraction"))),
             ("room surface off by > 5 mm (dents, bumps)", _fmt(surf.get("room_off_surface_fraction"))),
             ("normal consistency", _fmt(surf.get("normal_consistency"))),
             ("degenerate faces", _fmt(surf.get("degenerate_faces"), "d"))]
    return rows


def fit_report(report) -> dict:
    """The fit.json next to the evaluated mesh (written by `fit`), or {}."""
    import json

    rec = (report.get("extra") or {}).get("reconstruction")
    if not rec:
        return {}
    try:
        return json.loads((Path(rec).parent / "fit.json").read_text())
    except (OSError, ValueError):
        return {}


def time_rows(report) -> list:
    """(stage, seconds) of the reconstruction and its evaluation, as far as they were recorded."""
    fit = fit_report(report)
    rows = []
    if fit.get("run_seconds") is not None:
        setup, train = float(fit.get("setup_seconds", 0.0)), float(fit.get("train_seconds", 0.0))
        rows += [("fit: set-up (measurements, rays, initial field)", setup),
                 (f"fit: optimisation ({fit.get('steps', '?')} steps, {fit.get('stopped', '?')})", train),
                 ("fit: volume + mesh export", max(0.0, float(fit["run_seconds"]) - setup - train))]
    if report.get("eval_seconds") is not None:
        rows.append(("evaluation", float(report["eval_seconds"])))
    return rows


def object_rows(report) -> list:
    objs = report.get("object_metrics", {}).get("objects", {})
    return [(name, [_fmt(o.get(k), f) for _, k, f in OBJECT_COLUMNS]) for name, o in objs.items()]


def table_text(report) -> str:
    lines = [f"{n:<42s} {v}" for n, v in scene_lines(report)]
    times = time_rows(report)
    if times:
        lines.append("")
        lines += [f"{n:<42s} {t:.1f} s" for n, t in times]
    obj = object_rows(report)
    if obj:
        lines.append("")
        width = [max(len(c), 7) + 2 for c, _, _ in OBJECT_COLUMNS]     # each column as wide as its title
        lines.append(f"{'object':<16s}" + "".join(f"{c:>{w}s}" for (c, _, _), w in zip(OBJECT_COLUMNS, width)))
        for name, vals in obj:
            lines.append(f"{name[:16]:<16s}" + "".join(f"{v:>{w}s}" for v, w in zip(vals, width)))
    return "\n".join(lines)


def write_summary(out_dir, report, gt_mesh, recon, objects, sensor_c2w, preds=None, gts=None, size=192) -> list:
    """Pictures + summary.html + summary.png into out_dir; returns the relative paths written."""
    from .render import picture_grid, picture_viewpoints, plot_grid, plot_test_view_errors

    out = Path(out_dir)
    (out / "pictures").mkdir(parents=True, exist_ok=True)
    written = []
    views = picture_viewpoints(gt_mesh, [m for _, m in objects], sensor_c2w)
    rows = picture_grid(gt_mesh, recon, views, size=size)
    plot_grid(rows, out / VIEWS_PNG)
    written.append(VIEWS_PNG)
    title = f"{report.get('scene') or Path(str(report.get('dataset', ''))).name}: " \
            f"{Path(str((report.get('extra') or {}).get('reconstruction', 'reconstruction'))).name}"
    plot_grid(rows, out / SUMMARY_PNG, table_text=table_text(report), title=title)
    written.append(SUMMARY_PNG)
    if preds is not None and gts is not None and len(preds):
        n = len(preds)
        idx = sorted({0, n // 4, n // 2, (3 * n) // 4} & set(range(n)))
        finite = np.isfinite(gts)
        max_d = float(gts[finite].max()) if finite.any() else 1.0
        plot_test_view_errors(preds, gts, idx, out / TEST_VIEWS_PNG, max_d)
        written.append(TEST_VIEWS_PNG)
    _write_html(out / SUMMARY_HTML, report, written, title)
    written.append(SUMMARY_HTML)
    return written


def _write_html(path, report, pictures, title):
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;margin:0.5em 0}"
             "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}th{background:#eee}"
             "td:first-child{text-align:left}img{max-width:100%;margin:0.5em 0}</style></head><body>",
             f"<h1>{e(title)}</h1>", f"<p>dataset: {e(str(report.get('dataset')))}</p>", "<h2>Scene</h2><table>"]
    parts += [f"<tr><td>{e(n)}</td><td>{e(v)}</td></tr>" for n, v in scene_lines(report)]
    parts.append("</table>")
    times = time_rows(report)
    if times:
        parts.append("<h2>Time</h2><table><tr><th>stage</th><th>seconds</th></tr>")
        parts += [f"<tr><td>{e(n)}</td><td>{t:.1f}</td></tr>" for n, t in times]
        parts.append(f"<tr><td>total</td><td>{sum(t for _, t in times):.1f}</td></tr></table>")
    obj = object_rows(report)
    if obj:
        src = report.get("objects_source", "")
        parts.append(f"<h2>Objects</h2><p>objects: {e(src)}; recall leaves out contact points; hidden = not "
                     "seen by the sensor (occluded, facing away or outside its view)</p><table><tr><th>object</th>")
        parts += [f"<th>{e(c)}</th>" for c, _, _ in OBJECT_COLUMNS]
        parts.append("</tr>")
        for name, vals in obj:
            parts.append(f"<tr><td>{e(name)}</td>" + "".join(f"<td>{e(v)}</td>" for v in vals) + "</tr>")
        parts.append("</table>")
    inv = report.get("test_views_invalid", [])
    if inv:
        parts.append(f"<p>{len(inv)} test views dropped (camera not in free space), e.g. view "
                     f"{inv[0]['index']}: {e(inv[0]['reason'])}</p>")
    for p in pictures:
        if p.endswith(".png") and p != SUMMARY_PNG:
            parts.append(f"<h2>{e(p)}</h2><img src='{e(p)}' alt='{e(p)}'>")
    parts.append("</body></html>")
    Path(path).write_text("\n".join(parts))


# -- one page for several methods (the demo) -------------------------------------------------------
RUN_COLUMNS = (("depth L1 (m)", "depth_l1_m", ".4f"), ("depth PSNR (dB)", "depth_psnr_db", ".2f"),
               ("Chamfer (m)", "chamfer_m", ".4f"), ("F-score", "fscore", ".3f"))


def _style():
    return ("<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;margin:0.5em 0}"
            "td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}th{background:#eee}"
            "td:first-child{text-align:left}img{max-width:100%;margin:0.5em 0}</style>")


def write_run_summary(out_dir, methods: dict, timings: dict, title: str, note: str = "") -> list:
    """out_dir/summary.html + summary.png for several methods on one dataset.

    methods: {name: evaluation folder (report.json, pictures/)}; timings: {stage: seconds}.
    Returns the written files relative to out_dir; the page links only files that exist.
    """
    import json

    out = Path(out_dir)
    reports, pictures = {}, {}
    for name, d in methods.items():
        d = Path(d)
        try:
            reports[name] = json.loads((d / "report.json").read_text())
        except (OSError, ValueError):
            continue
        pictures[name] = [(d / rel).relative_to(out).as_posix() if (d / rel).resolve().is_relative_to(out.resolve())
                          else str(d / rel) for rel in (VIEWS_PNG, TEST_VIEWS_PNG) if (d / rel).is_file()]
    _plot_run_summary(out / SUMMARY_PNG, reports, pictures, timings, title, out)
    e = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>{_style()}</head><body>",
             f"<h1>{e(title)}</h1>", f"<img src='{SUMMARY_PNG}' alt='summary'>"]
    if note:
        parts.append(f"<p>{e(note)}</p>")
    parts.append("<h2>Metrics</h2><table><tr><th>method</th>" + "".join(f"<th>{e(c)}</th>" for c, _, _ in RUN_COLUMNS)
                 + "</tr>")
    for name, rep in reports.items():
        parts.append(f"<tr><td>{e(name)}</td>" + "".join(f"<td>{e(_fmt(rep.get(k), f))}</td>"
                                                         for _, k, f in RUN_COLUMNS) + "</tr>")
    parts.append("</table><h2>Time</h2><table><tr><th>stage</th><th>seconds</th></tr>")
    parts += [f"<tr><td>{e(k)}</td><td>{v:.1f}</td></tr>" for k, v in timings.items()]
    parts.append(f"<tr><td>total</td><td>{sum(timings.values()):.1f}</td></tr></table>")
    for name, pics in pictures.items():
        rel_page = Path(methods[name]) / SUMMARY_HTML
        link = rel_page.relative_to(out).as_posix() if rel_page.is_file() and \
            rel_page.resolve().is_relative_to(out.resolve()) else ""
        parts.append(f"<h2>{e(name)}</h2>" + (f"<p><a href='{e(link)}'>full evaluation page</a></p>" if link else ""))
        parts += [f"<img src='{e(p)}' alt='{e(name)} {e(p)}'>" for p in pics]
    parts.append("</body></html>")
    (out / SUMMARY_HTML).write_text("\n".join(parts))
    return [SUMMARY_PNG, SUMMARY_HTML]


def _plot_run_summary(path, reports, pictures, timings, title, out):
    """The montage: metrics table and time bars on top, then each method's GT | reconstruction | error rows."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    views = [(name, plt.imread(out / pics[0] if not Path(pics[0]).is_absolute() else pics[0]))
             for name, pics in pictures.items() if pics]
    heights = [2.2] + [11.0 * img.shape[0] / img.shape[1] for _, img in views]
    fig = plt.figure(figsize=(11, sum(heights) + 0.6))
    gs = fig.add_gridspec(len(heights), 2, height_ratios=heights, width_ratios=[1.2, 1])
    ax = fig.add_subplot(gs[0, 0])
    ax.axis("off")
    ax.set_title("metrics on the test views / surface", fontsize=10)
    if reports:
        cells = [[_fmt(rep.get(k), f) for _, k, f in RUN_COLUMNS] for rep in reports.values()]
        tab = ax.table(cellText=cells, rowLabels=list(reports), colLabels=[c for c, _, _ in RUN_COLUMNS],
                       loc="center")
        tab.auto_set_font_size(False)
        tab.set_fontsize(9)
        tab.scale(1.0, 1.5)
    ax = fig.add_subplot(gs[0, 1])
    names = list(timings)
    ax.barh(range(len(names)), [timings[n] for n in names], color="#4c72b0")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("seconds")
    ax.set_title(f"time per stage (total {sum(timings.values()):.0f} s)", fontsize=10)
    for i, n in enumerate(names):
        ax.text(timings[n], i, f" {timings[n]:.1f}", va="center", fontsize=8)
    for row, (name, img) in enumerate(views, start=1):
        ax = fig.add_subplot(gs[row, :])
        ax.imshow(img)
        ax.axis("off")
        ax.set_title(f"{name}: ground truth | reconstruction | |depth error| (m; blue: no ground-truth surface)",
                     fontsize=10)
    fig.suptitle(title, fontsize=12)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.5 / fig.get_figheight()))   # room for the title
    fig.savefig(path, dpi=80)
    plt.close(fig)
