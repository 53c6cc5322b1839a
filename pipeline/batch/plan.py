"""A batch plan file (TOML or JSON) -> the list of tasks it asks for (plain data, no engine here).

    [scenes]
    examples = ["cave-chair"]                  # example scene names (torch_recon.contract.scenes)
    blend = ["rooms/kitchen.blend"]            # .blend files (relative to the plan file)
    [scenes.procedural]                        # procedural rooms (torch_recon.contract.procedural)
    count = 100
    first_seed = 0
    settings = { max_objects = 2 }             # ProceduralSettings fields

    [simulate]                                 # SimulationConfig fields (simulate --set), plus the
    resolution = 24                            #   simulate flags resolution, spots, test_views
    [simulate.grid]                            # every combination of these lists is one dataset
    spots = [4, 16]

    [[methods]]                                # each method fits every dataset
    name = "fast"                              # a fit or baseline method of contract/methods.py
    settings = { steps = 200, "fast.resolution" = 64 }   # that command's settings (--set)

    [evaluate]                                 # evaluate every reconstruction against ground truth
    settings = { pictures = false }            # EvalSettings fields (--set); `enabled = false` to skip

Tasks form a graph: simulate (scene x grid point) -> one fit per method -> one evaluate per fit. A
task's key is a content hash of what it depends on: its stage, its inputs (the scene description or
the .blend's bytes, the keys of the tasks it reads), its settings and the code version; so the same
key always means the same result, and a finished key is never run again.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

from torch_recon.contract.errors import PlatolidarError
from torch_recon.contract.methods import METHODS

STAGES = ("simulate", "fit", "evaluate")
#: simulate flags a plan may give by name (everything else is a SimulationConfig field, passed by --set)
SIMULATE_FLAGS = {"resolution": "--resolution", "spots": "--spots", "test_views": "--test-views"}
PLAN_KEYS = {"name", "scenes", "simulate", "methods", "evaluate"}


class PlanError(PlatolidarError, ValueError):
    """A plan file that cannot be expanded: names the file and the field."""

    def __init__(self, source, field_name: str, message: str):
        super().__init__(f"{source}: {field_name}: {message}")


@dataclass
class Task:
    stage: str                      # simulate | fit | evaluate
    key: str                        # content hash (hex)
    label: str                      # for people: scene, grid point, method
    spec: dict                      # what the stage needs (scene, settings); JSON-able
    deps: list = field(default_factory=list)   # keys of the tasks whose outputs it reads

    @property
    def name(self) -> str:
        """Folder name: the label for people, the key's start for uniqueness."""
        return f"{self.label}-{self.key[:12]}"

    def to_dict(self) -> dict:
        return {"stage": self.stage, "key": self.key, "label": self.label, "spec": self.spec, "deps": self.deps}


def content_key(*parts) -> str:
    """sha256 of the canonical JSON of `parts`."""
    text = json.dumps(parts, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def file_hash(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def code_version(root: Path | None = None) -> str:
    """sha256 over the project's Python sources (torch_recon/, pipeline/ but not the batch runner itself):
    results of other code never count as finished."""
    root = Path(root) if root else Path(__file__).resolve().parents[2]
    h = hashlib.sha256()
    for pkg in ("torch_recon", "pipeline"):
        for p in sorted((root / pkg).rglob("*.py")):
            rel = p.relative_to(root)
            if rel.parts[:2] == ("pipeline", "batch") or "__pycache__" in rel.parts:
                continue
            h.update(str(rel).encode() + b"\0" + p.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def load_plan(path) -> dict:
    """The plan file as a dict (JSON, or TOML by suffix); errors name the file."""
    from torch_recon.contract.errors import SettingsError
    from torch_recon.contract.settings import load_file

    try:
        data = load_file(path)
    except SettingsError as exc:
        raise PlanError(path, "file", exc.detail) from None
    unknown = sorted(set(data) - PLAN_KEYS)
    if unknown:
        raise PlanError(path, unknown[0], f"unknown plan entry; known: {', '.join(sorted(PLAN_KEYS))}")
    return data


def _table(data, key, source) -> dict:
    v = data.get(key, {})
    if not isinstance(v, dict):
        raise PlanError(source, key, f"expected a table, got {type(v).__name__}")
    return v


def _scalar_settings(table: dict, where: str, source) -> dict:
    for k, v in table.items():
        if isinstance(v, dict):
            raise PlanError(source, f"{where}.{k}", "expected a value (write nested settings as \"a.b\" = value)")
    return dict(table)


def _scenes(data, source, base: Path) -> list:
    """[(label, scene spec)] in plan order."""
    from torch_recon.contract.procedural import scene_name, settings_from_dict
    from torch_recon.contract.scenes import EXAMPLES
    from torch_recon.contract.errors import SettingsError

    sc = _table(data, "scenes", source)
    unknown = sorted(set(sc) - {"examples", "blend", "procedural"})
    if unknown:
        raise PlanError(source, f"scenes.{unknown[0]}", "unknown entry; known: examples, blend, procedural")
    out = []
    for name in sc.get("examples", []):
        if name not in EXAMPLES:
            raise PlanError(source, "scenes.examples", f"unknown example {name!r} (known: {', '.join(EXAMPLES)})")
        out.append((name, {"kind": "example", "name": name}))
    for rel in sc.get("blend", []):
        p = (base / rel).resolve()
        if not p.is_file():
            raise PlanError(source, "scenes.blend", f"{p}: no such .blend file")
        out.append((p.stem, {"kind": "blend", "path": str(p), "sha256": file_hash(p)}))
    if "procedural" in sc:
        pr = sc["procedural"]
        if not isinstance(pr, dict):
            raise PlanError(source, "scenes.procedural", "expected a table (count, first_seed, settings)")
        bad = sorted(set(pr) - {"count", "first_seed", "settings"})
        if bad:
            raise PlanError(source, f"scenes.procedural.{bad[0]}", "unknown entry; known: count, first_seed, settings")
        count, first = pr.get("count", 1), pr.get("first_seed", 0)
        for k, v in (("count", count), ("first_seed", first)):
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise PlanError(source, f"scenes.procedural.{k}", f"expected an integer >= 0, got {v!r}")
        try:
            settings = settings_from_dict(pr.get("settings", {}), str(source)).to_dict()
        except SettingsError as exc:
            raise PlanError(source, f"scenes.procedural.settings.{exc.key.removeprefix('procedural.')}",
                            exc.detail) from None
        for seed in range(first, first + count):
            out.append((scene_name(seed), {"kind": "procedural", "seed": seed, "settings": settings}))
    if not out:
        raise PlanError(source, "scenes", "no scenes: give examples, blend or procedural")
    return out


def _grid(sim: dict, source) -> list:
    """Every combination of simulate.grid's lists laid over the fixed simulate settings."""
    fixed = {k: v for k, v in sim.items() if k != "grid"}
    _scalar_settings(fixed, "simulate", source)
    grid = sim.get("grid", {})
    if not isinstance(grid, dict):
        raise PlanError(source, "simulate.grid", "expected a table of lists")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise PlanError(source, f"simulate.grid.{k}", f"expected a non-empty list of values, got {v!r}")
    keys = sorted(grid)
    points = []
    for values in itertools.product(*(grid[k] for k in keys)):
        point = dict(zip(keys, values))
        settings = {**fixed, **point}
        for k, v in settings.items():
            _check_simulation_setting(k, v, f"simulate.grid.{k}" if k in point else f"simulate.{k}", source)
        points.append((settings, point))
    return points


def _check_simulation_setting(key, value, where: str, source) -> None:
    """A SimulationConfig field (or simulate flag) with a value of its type, checked before anything runs."""
    from torch_recon.contract.errors import SettingsError
    from torch_recon.contract.settings import check_value, find_spec
    from torch_recon.contract.simulation import SimulationConfig

    if key in SIMULATE_FLAGS:
        if isinstance(value, bool) or not isinstance(value, int) or value < (0 if key == "test_views" else 1):
            raise PlanError(source, where, f"expected a positive integer, got {value!r}")
        return
    try:
        check_value(find_spec(SimulationConfig, key), value)
    except SettingsError as exc:
        raise PlanError(source, where, exc.detail) from None


def _methods(data, source) -> list:
    ms = data.get("methods", [])
    if not isinstance(ms, list):
        raise PlanError(source, "methods", "expected a list of tables ([[methods]])")
    out = []
    for i, m in enumerate(ms):
        if not isinstance(m, dict) or "name" not in m:
            raise PlanError(source, f"methods[{i}]", "expected a table with a name")
        bad = sorted(set(m) - {"name", "settings", "label"})
        if bad:
            raise PlanError(source, f"methods[{i}].{bad[0]}", "unknown entry; known: name, label, settings")
        if m["name"] not in METHODS:
            raise PlanError(source, f"methods[{i}].name", f"expected one of {', '.join(METHODS)}, got {m['name']!r}")
        settings = _scalar_settings(m.get("settings", {}), f"methods[{i}].settings", source)
        out.append({"name": m["name"], "label": str(m.get("label", m["name"])), "settings": settings})
    return out


def _grid_label(point: dict) -> str:
    return "_".join(f"{k}{v}" for k, v in sorted(point.items())).replace("/", "-") or "default"


def expand(path, version: str | None = None) -> list:
    """The plan file at `path` -> tasks in dependency order (simulate, then fit, then evaluate)."""
    path = Path(path)
    data = load_plan(path)
    version = version or code_version()
    scenes = _scenes(data, path, path.parent)
    points = _grid(_table(data, "simulate", path), path)
    methods = _methods(data, path)
    ev = _table(data, "evaluate", path)
    bad = sorted(set(ev) - {"enabled", "settings"})
    if bad:
        raise PlanError(path, f"evaluate.{bad[0]}", "unknown entry; known: enabled, settings")
    evaluate = ev.get("enabled", bool(methods)) and bool(methods)
    eval_settings = _scalar_settings(ev.get("settings", {}), "evaluate.settings", path)
    tasks = {}

    def add(t: Task):
        tasks.setdefault(t.key, t)
        return t

    for scene_label, scene in scenes:
        for settings, point in points:
            spec = {"scene": scene, "settings": settings}
            identity = {"scene": {k: v for k, v in scene.items() if k != "path"}, "settings": settings}  # a .blend
            sim = add(Task("simulate", content_key("simulate", identity, version),     # counts by its bytes
                           f"{scene_label}_{_grid_label(point)}", {**spec, "grid": point, "scene_label": scene_label}))
            for m in methods:
                fspec = {"method": m["name"], "settings": m["settings"]}
                fit = add(Task("fit", content_key("fit", sim.key, fspec, version), f"{sim.label}_{m['label']}",
                               {**fspec, "method_label": m["label"]}, [sim.key]))
                if evaluate:
                    add(Task("evaluate", content_key("evaluate", fit.key, sim.key, eval_settings, version),
                             fit.label, {"settings": eval_settings}, [fit.key, sim.key]))
    return sorted(tasks.values(), key=lambda t: STAGES.index(t.stage))
