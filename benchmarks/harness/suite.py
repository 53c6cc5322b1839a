"""What a benchmark suite is, where suites are found, and how `--set key=value` changes its settings.

A suite is a module benchmarks/suites/<name>.py exposing SUITE (or SUITES, a list, for a family
such as the ablations that shares one file) built from `Suite`.
"""

from __future__ import annotations

import dataclasses
import importlib
import pkgutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from benchmarks.harness.report import ROW_ID
from torch_recon.contract.errors import SettingsError  # noqa: F401 (re-export: the harness CLI catches it)
from torch_recon.contract.settings import parse_assignments, with_values


@dataclass(frozen=True)
class Suite:
    """One benchmark: its quick and full settings (instances of the suite's own dataclass) and the
    function that measures; `run(settings, ctx) -> list[dict]`, one dict per row (report.ROW_KEYS first,
    then the error fields). `plot(rows, settings, path)` draws its PNG (default: report.plot_rows);
    `readme(results) -> str` renders its README table (default: report.markdown_table). `row_id`: the
    fields that name a row when `run --merge` keeps the rows a run did not re-measure."""
    name: str
    description: str
    quick: Any
    full: Any
    run: Callable[[Any, Any], list]
    plot: Callable | None = None
    readme: Callable | None = None
    row_id: tuple = ROW_ID

    def settings(self, quick: bool, overrides=()) -> Any:
        """The quick or full settings with `key=value` overrides (values typed by the dataclass field)."""
        return apply_overrides(self.quick if quick else self.full, overrides)


def apply_overrides(settings, overrides):
    """A copy of the dataclass `settings` with each 'key=value' applied, each value type-checked by the
    project's one settings mechanism (torch_recon/contract/settings.py): 'n=3', 'levels=[1,3]' or
    'levels=1,3', 'budget_s=none'. A bad key or value raises SettingsError naming it."""
    if not dataclasses.is_dataclass(settings):
        raise TypeError(f"suite settings must be a dataclass instance, got {type(settings).__name__}")
    return with_values(settings, parse_assignments(overrides))


SUITES_PACKAGE = "benchmarks.suites"


def all_suites() -> dict[str, Suite]:
    """Every suite of benchmarks/suites/, by name (a module failing to import is reported, not skipped)."""
    pkg = importlib.import_module(SUITES_PACKAGE)
    found: dict[str, Suite] = {}
    for info in sorted(pkgutil.iter_modules([str(Path(pkg.__file__).parent)]), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{SUITES_PACKAGE}.{info.name}")
        suites = list(getattr(mod, "SUITES", [])) + ([mod.SUITE] if hasattr(mod, "SUITE") else [])
        for s in suites:
            if s.name in found:
                raise ValueError(f"suite name {s.name!r} defined twice (benchmarks/suites/{info.name}.py)")
            found[s.name] = s
    return found
