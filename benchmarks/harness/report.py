"""Where a number was measured, what a result row must hold, and how results become files and README tables.

results/<name>.json = {"machine": machine_info(), "suite": {name, description, quick, command, measured},
                       "settings": the settings dataclass as a dict, "rows": [row, ...]}
A row starts with ROW_KEYS (method, scene, wall_s, cpu_s, peak_rss_mb); every other field is the suite's
(error fields, levels, counts). README tables sit between `<!-- bench:NAME -->` and `<!-- /bench:NAME -->`
and are rebuilt from results/NAME.json by `python -m benchmarks readme`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime
import json
import math
import os
import platform
import re
import subprocess
from pathlib import Path

ROW_KEYS = ("method", "scene", "wall_s", "cpu_s", "peak_rss_mb")
TIME_KEYS = ROW_KEYS[2:]


class RowError(ValueError):
    """A suite returned a row that does not follow the row schema."""


def machine_info() -> dict:
    """CPU model, usable cores, RAM, GPU (if torch sees one), library versions, 1-minute load average."""
    import numpy as np
    info = {"cpu": _cpu_model(), "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
            else os.cpu_count(), "ram_gb": _ram_gb(), "gpu": None, "python": platform.python_version(),
            "numpy": np.__version__, "torch": None, "platform": platform.platform(),
            "loadavg_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None}
    try:
        import torch
        info["torch"] = torch.__version__
        if torch.cuda.is_available():
            info["gpu"] = torch.cuda.get_device_name(0)
    except ImportError:
        pass
    return info


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _ram_gb():
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30, 1)
    except (ValueError, OSError, AttributeError):
        return None


def machine_line(info: dict) -> str:
    """One line: what every run prints and every README table names."""
    parts = [info.get("cpu") or "unknown CPU", f"{info.get('cores')} cores"]
    if info.get("ram_gb"):
        parts.append(f"{info['ram_gb']:g} GB RAM")
    parts.append(f"GPU {info['gpu']}" if info.get("gpu") else "no GPU")
    parts.append(f"torch {info.get('torch')}, numpy {info.get('numpy')}")
    load = info.get("loadavg_1min")
    end = info.get("loadavg_1min_end")
    parts.append((f"load average {load:.2f}" + (f" (end {end:.2f})" if isinstance(end, (int, float)) else ""))
                 if isinstance(load, (int, float)) else "load average unknown")
    return ", ".join(parts)


def check_rows(rows, suite: str) -> list[dict]:
    """The rows, or RowError naming the suite, row and field that break the schema."""
    if not isinstance(rows, list) or not rows:
        raise RowError(f"suite {suite}: run() must return a non-empty list of row dicts, got {type(rows).__name__}")
    for i, row in enumerate(rows):
        if not isinstance(row, dict):
            raise RowError(f"suite {suite}, row {i}: expected a dict, got {type(row).__name__}")
        missing = [k for k in ROW_KEYS if k not in row]
        if missing:
            raise RowError(f"suite {suite}, row {i}: missing {', '.join(missing)} (every row needs {', '.join(ROW_KEYS)})")
        for k in ("method", "scene"):
            if not isinstance(row[k], str):
                raise RowError(f"suite {suite}, row {i}: {k} must be a string, got {row[k]!r}")
        for k in TIME_KEYS:
            v = row[k]
            if v is not None and (not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v) or v < 0):
                raise RowError(f"suite {suite}, row {i}: {k} must be a finite number >= 0 or null, got {v!r}")
        try:
            json.dumps(row, allow_nan=False, default=_jsonable)
        except (TypeError, ValueError) as exc:
            raise RowError(f"suite {suite}, row {i}: not writable as JSON ({exc}); use null for a missing number") from None
    return rows


def _jsonable(o):
    if hasattr(o, "tolist"):        # numpy scalars and arrays
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"cannot write {type(o).__name__} as JSON")


def error_fields(rows) -> list[str]:
    """The numeric fields after ROW_KEYS, in first-seen order: what a table or plot shows by default."""
    out = []
    for r in rows:
        for k, v in r.items():
            if k not in ROW_KEYS and k not in out and isinstance(v, (int, float)) and not isinstance(v, bool):
                out.append(k)
    return out


def git_commit(root: Path) -> str | None:
    """HEAD's short hash; BENCH_COMMIT, where set, names the code instead (a GPU machine's copy of the tree
    carries a stale or no .git)."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        head = ""
    return os.environ.get("BENCH_COMMIT") or head or None


def results_document(suite, settings, rows, quick: bool, machine: dict, command: str, root: Path,
                     commit: str | None = None) -> dict:
    """`commit`: the code the run started from (default: HEAD now; a long run should pass its start's)."""
    measured = {"date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
                "commit": commit or git_commit(root), "by": "python -m benchmarks"}
    return {"machine": machine,
            "suite": {"name": suite.name, "description": suite.description, "quick": quick, "command": command,
                      "measured": measured},
            "settings": dataclasses.asdict(settings), "rows": rows}


def write_json(path: Path, obj) -> Path:
    """Indented JSON, written atomically (temp file + rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=_jsonable) + "\n")     # rows: NaN refused by check_rows
    os.replace(tmp, path)
    return path


def plot_rows(rows, path: Path, title: str = "", y: str | None = None, x: str = "wall_s", kind: str = "scatter",
              label="method", hline: tuple[float, str] | None = None) -> Path:
    """The one plot: each row's error `y` (default its first error field) against time `x` (a scatter, one
    colour per label: the row's `label` field, or `label(row)` when callable), or as bars per row (kind='bar');
    `hline` = (value, label): a reference line such as the paper's error."""
    name_of = label if callable(label) else (lambda r: str(r.get(label)))
    y = y or (error_fields(rows) or [x])[0]
    with figure(path, (6.5, 4)) as ax:
        _plot_rows_on(ax, rows, name_of, y, x, kind, hline, title)
    return Path(path)


@contextlib.contextmanager
def figure(path: Path, figsize=(6.5, 4), dpi: int = 110):
    """`with figure(path) as ax:` one Agg figure, laid out and saved to `path` (folders made) on exit."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=figsize)
    try:
        yield ax
        fig.tight_layout()
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=dpi)
    finally:
        plt.close(fig)


def _plot_rows_on(ax, rows, name_of, y, x, kind, hline, title):
    if kind == "bar":
        names = [f"{name_of(r)}\n{r.get('scene', '')}" for r in rows]
        ax.bar(range(len(rows)), [_num(r.get(y)) for r in rows])
        ax.set_xticks(range(len(rows)), names, fontsize=7, rotation=30, ha="right")
    else:
        for name in dict.fromkeys(map(name_of, rows)):
            rs = [r for r in rows if name_of(r) == name]
            ax.scatter([_num(r.get(x)) for r in rs], [_num(r.get(y)) for r in rs], label=name)
        ax.set_xlabel(x)
        if len(set(map(name_of, rows))) <= 12:
            ax.legend(fontsize=7)
    if hline is not None:
        ax.axhline(hline[0], color="gray", ls="--", lw=1, label=hline[1])
        ax.legend(fontsize=7)
    ax.set_ylabel(y)
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)


def paper_result(spots: int = 16) -> dict:
    """The paper's test-view depth L1 / PSNR with `spots` spots (its supplement's Table 1), from
    torch_recon.contract.reference, the only copy of the paper's numbers."""
    from torch_recon.contract.reference import cave
    r = cave()["paper_figures"]["supplement_table1_spots"][str(spots)]
    return {"depth_l1_m": r["depth_l1_m"], "depth_psnr_db": r["psnr_db"]}


def paper_line() -> tuple[float, str]:
    """plot_rows(hline=...) of the paper's depth L1."""
    return paper_result()["depth_l1_m"], "paper PlatoNeRF (16 spots, 512 px, GPU hours)"


def _num(v):
    return float("nan") if v is None else v


# -- README tables ------------------------------------------------------------------------------

def fmt(v, spec: str | None = None) -> str:
    """A table cell: `spec` (a format spec such as '.1f') for numbers, else floats with 4 decimals below 1
    and 2 above; None as '-'."""
    if v is None:
        return "-"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not math.isfinite(v)):
        return str(v)
    if spec:
        return format(v, spec)
    if not isinstance(v, float):
        return str(v)
    return f"{v:.4f}" if abs(v) < 1 else f"{v:.2f}" if abs(v) < 1000 else f"{v:.0f}"


def markdown_table(rows, columns) -> str:
    """`columns`: [(field, header) or (field, header, format spec), ...]."""
    cols = [(c[0], c[1], c[2] if len(c) > 2 else None) for c in columns]
    lines = ["| " + " | ".join(h for _, h, _ in cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(fmt(r.get(k), spec) for k, _, spec in cols) + " |" for r in rows]
    return "\n".join(lines)


def default_table(results: dict) -> str:
    rows = results["rows"]
    cols = [(k, k) for k in ROW_KEYS] + [(k, k) for k in error_fields(rows)[:6] if k != "run"]
    cols += [("run", "run")] if len(results.get("runs") or ()) > 1 else []
    return markdown_table(rows, cols)


def provenance(results: dict) -> str:
    """The line under every README table: command, machine, load, when and by whom it was measured; for
    a merged document (several runs) one such line per run, numbered as the rows' `run` field."""
    runs = results.get("runs") or [run_record(results)]
    if len(runs) == 1:
        return f"<sub>{_run_line(runs[0])}</sub>"
    return "<sub>" + "<br>".join(f"run {i}: {_run_line(r)}" for i, r in enumerate(runs, 1)) + "</sub>"


def _run_line(run: dict) -> str:
    meas = run.get("measured") or {}
    by = meas.get("by", "")
    stale = "" if by == "python -m benchmarks" else f" ({by})"
    commit = f", commit {meas['commit']}" if meas.get("commit") else ""
    return (f"`{run.get('command')}`{' (quick)' if run.get('quick') else ''}; {machine_line(run.get('machine') or {})}; "
            f"{meas.get('date', 'unknown date')}{commit}{stale}")


# -- merging runs: some methods re-measured, the other rows kept with their own provenance ------

ROW_ID = ("method", "scene")


def run_record(doc: dict) -> dict:
    """One run's provenance from its results document: command, quick, date, commit, machine (load at its
    start and end), settings, total wall time."""
    s = doc["suite"]
    return {"command": s.get("command"), "quick": s.get("quick"), "measured": s.get("measured", {}),
            "machine": doc.get("machine", {}), "settings": doc.get("settings"), "total_wall_s": s.get("total_wall_s")}


def merge_results(old: dict, new: dict, row_id=ROW_ID) -> dict:
    """`new` (one run's document) with the rows of `old` it did not re-measure, rows keyed by `row_id`
    (default method and scene; a suite may add fields, Suite.row_id):
    a new row replaces the old one in place, new keys follow. Each row's `run` (1-based) points into the
    document's `runs`, the provenance of the run that measured it; runs no row comes from are dropped.
    Top-level machine/suite/settings are the new run's. A key twice in one document raises RowError."""
    old_runs = old.get("runs") or [run_record(old)]
    new_run = run_record(new)
    fresh = rows_by_id(new["rows"], "the new run", row_id)
    rows_by_id(old["rows"], "the existing results", row_id)
    pairs = []
    for r in old["rows"]:
        k = tuple(r.get(f) for f in row_id)
        pairs.append((fresh.pop(k), new_run) if k in fresh else (r, old_runs[int(r.get("run") or 1) - 1]))
    pairs += [(r, new_run) for r in fresh.values()]
    runs, rows = [], []
    for r, run in pairs:
        idx = next((i for i, x in enumerate(runs) if x is run), None)
        if idx is None:
            runs.append(run)
            idx = len(runs) - 1
        rows.append({**{k: v for k, v in r.items() if k != "run"}, "run": idx + 1})
    return {**new, "runs": runs, "rows": rows}


def rows_by_id(rows, what: str, row_id=ROW_ID) -> dict:
    """{key: row}, key = the row's `row_id` fields; RowError naming the first key seen twice (such rows
    cannot be merged)."""
    out = {}
    for r in rows:
        k = tuple(r.get(f) for f in row_id)
        if k in out:
            named = ", ".join(f"{f} {v!r}" for f, v in zip(row_id, k))
            raise RowError(f"cannot merge: {what} has two rows for {named} (rows are merged by {', '.join(row_id)})")
        out[k] = r
    return out


MARKER = re.compile(r"(<!-- bench:(?P<name>[\w-]+) -->\n)(?P<body>.*?)(<!-- /bench:(?P=name) -->)", re.S)


def render_readme(text: str, load_results, render) -> tuple[str, list[str]]:
    """`text` with every marked block replaced by render(name, load_results(name)); also the names done.
    load_results(name) -> dict or None (no JSON: the block is left as it is)."""
    done = []

    def sub(m):
        res = load_results(m["name"])
        if res is None:
            return m.group(0)
        done.append(m["name"])
        return f"{m.group(1)}{render(m['name'], res).rstrip()}\n{m.group(4)}"
    return MARKER.sub(sub, text), done
