"""Results of a batch: a few numbers per task, one table (CSV + JSON) and one summary page (HTML).

One row per reconstruction (scene x simulation grid point x method): the scene, the grid values, the
method, the time each stage took and the evaluation's metrics. Written atomically into OUT/:
results.csv, results.json (rows plus every task's record) and summary.html.
"""

from __future__ import annotations

import csv
import html
import io
import json
import os
from pathlib import Path

from .plan import file_hash

#: evaluation metrics copied into the table (report.json keys)
EVAL_METRICS = ("depth_l1_m", "depth_psnr_db", "chamfer_m", "fscore", "n_test_views")


def stage_metrics(stage: str, out: Path) -> dict:
    """The numbers a finished stage's output holds (raises OSError/ValueError/KeyError when it is not there)."""
    out = Path(out)
    if stage == "simulate":     # the dataset is read back through the validating reader
        from torch_recon.contract.dataset import load_dataset

        ds = load_dataset(out)
        s = ds.manifest.sensor
        return {"width": s.width, "height": s.height, "bins": s.bins, "spots": len(ds.manifest.enabled_spots),
                "dataset_hash": ds.content_hash()[:16]}
    if stage == "fit":
        if not (out / "mesh.ply").is_file():
            raise ValueError(f"{out}: no mesh.ply")
        mesh_hash = file_hash(out / "mesh.ply")[:16]
        if (out / "fit.json").is_file():
            f = json.loads((out / "fit.json").read_text())
            return {"steps": f.get("steps"), "stopped": f.get("stopped"), "fit_run_s": f.get("run_seconds"),
                    "mesh_hash": mesh_hash}
        meta = json.loads((out / "mesh.mesh.json").read_text())     # baseline
        return {"stopped": "done", "fit_run_s": sum((meta.get("seconds") or {}).values()) or None,
                "mesh_hash": mesh_hash}
    r = json.loads((out / "report.json").read_text())
    om = (r.get("object_metrics") or {}).get("summary") or {}
    return {**{k: r.get(k) for k in EVAL_METRICS}, "object_fscore_2cm": om.get("fscore@2cm")}


def rows(tasks: list, records: dict) -> list:
    """One dict per fit task: scene, grid values, method, stage times and status, metrics."""
    by_key = {t.key: t for t in tasks}
    evals = {t.deps[0]: t for t in tasks if t.stage == "evaluate"}
    out = []
    for t in tasks:
        if t.stage != "fit":
            continue
        sim = by_key[t.deps[0]]
        ev = evals.get(t.key)
        rs, rf = records.get(sim.key, {}), records.get(t.key, {})
        re_ = records.get(ev.key, {}) if ev else {}
        row = {"scene": sim.spec["scene_label"], **{f"sim.{k}": v for k, v in sim.spec["grid"].items()},
               "method": t.spec["method_label"]}
        row["status"] = next((r.get("status", "not run") for r in (rs, rf, re_) if r and r.get("status") != "done"),
                             "done" if rs and rf and (re_ or not ev) else "not run")
        for name, r in (("simulate", rs), ("fit", rf), ("evaluate", re_)):
            row[f"{name}_wall_s"] = r.get("wall_s")
        row.update({k: v for k, v in (rs.get("metrics") or {}).items() if k in ("width", "height", "spots",
                                                                                 "dataset_hash")})
        row["mesh_hash"] = (rf.get("metrics") or {}).get("mesh_hash")
        row.update({k: v for k, v in (re_.get("metrics") or {}).items()})
        row["fit_folder"] = rf.get("folder")
        out.append(row)
    if not any(t.stage == "fit" for t in tasks):      # simulate-only plans: one row per dataset
        for t in tasks:
            r = records.get(t.key, {})
            out.append({"scene": t.spec["scene_label"], **{f"sim.{k}": v for k, v in t.spec["grid"].items()},
                        "status": r.get("status", "not run"), "simulate_wall_s": r.get("wall_s"),
                        **(r.get("metrics") or {}), "dataset": r.get("output")})
    return out


def _atomic_text(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def write_results(root, tasks: list, records: dict, summary: dict) -> dict:
    """results.csv, results.json, summary.html under `root`; returns their paths."""
    root = Path(root)
    table = rows(tasks, records)
    cols = list(dict.fromkeys(k for r in table for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols)
    w.writeheader()
    w.writerows(table)
    paths = {"csv": root / "results.csv", "json": root / "results.json", "html": root / "summary.html"}
    _atomic_text(paths["csv"], buf.getvalue())
    _atomic_text(paths["json"], json.dumps({"summary": summary, "rows": table,
                                            "tasks": [{**t.to_dict(), "record": records.get(t.key)} for t in tasks]},
                                           indent=1, default=str) + "\n")
    _atomic_text(paths["html"], summary_html(table, cols, tasks, records, summary))
    return paths


def _cell(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return html.escape("" if v is None else str(v))


def summary_html(table, cols, tasks, records, summary) -> str:
    """The one page: counts, the table, and each failed task with its log."""
    failed = [t for t in tasks if (records.get(t.key) or {}).get("status") == "failed"]
    shown = [c for c in cols if c != "fit_folder"]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in shown)
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(c))}</td>" for c in shown) + "</tr>" for r in table)
    fails = "".join(f"<li><b>{html.escape(t.stage)} {html.escape(t.label)}</b>: "
                    f"{html.escape(str(records[t.key].get('error', '')))} "
                    f"(<a href='{html.escape(os.path.relpath(records[t.key]['folder'], summary['out']))}/log.txt'>log</a>)"
                    f"</li>" for t in failed)
    counts = ", ".join(f"{k} {v}" for k, v in summary.get("counts", {}).items())
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>batch {html.escape(summary.get('plan', ''))}"
            f"</title><style>body{{font-family:sans-serif}}table{{border-collapse:collapse}}"
            f"td,th{{border:1px solid #ccc;padding:2px 6px;text-align:right}}</style></head><body>"
            f"<h1>Batch: {html.escape(summary.get('plan', ''))}</h1>"
            f"<p>{len(tasks)} tasks ({counts}); code version {html.escape(summary.get('code_version', ''))}; "
            f"{summary.get('workers', '')} worker(s); wall {summary.get('wall_s', 0):.1f} s; "
            f"scenes per hour {_cell(summary.get('scenes_per_hour'))}</p>"
            f"<table><tr>{head}</tr>{body}</table>"
            + (f"<h2>Failed tasks</h2><ul>{fails}</ul>" if fails else "") + "</body></html>\n")
