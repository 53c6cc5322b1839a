"""What a benchmark suite is, where suites are found, and how `--set key=value` changes its settings.

A suite is a module benchmarks/suites/<name>.py exposing SUITE (or SUITES, a list, for a family
such as the ablations that shares one file) built from `Suite`.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import pkgutil
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable


@dataclass(frozen=True)
class Suite:
    """One benchmark: its quick and full settings (instances of the suite's own dataclass) and the
    function that measures; `run(settings, ctx) -> list[dict]`, one dict per row (report.ROW_KEYS first,
    then the error fields). `plot(rows, settings, path)` draws its PNG (default: report.plot_rows);
    `readme(results) -> str` renders its README table (default: report.markdown_table)."""
    name: str
    description: str
    quick: Any
    full: Any
    run: Callable[[Any, Any], list]
    plot: Callable | None = None
    readme: Callable | None = None

    def settings(self, quick: bool, overrides=()) -> Any:
        """The quick or full settings with `key=value` overrides (values typed by the dataclass field)."""
        return apply_overrides(self.quick if quick else self.full, overrides)


class SettingsError(ValueError):
    """A --set override that names no field or whose value does not fit the field's type."""


def apply_overrides(settings, overrides):
    """A copy of the dataclass `settings` with each 'key=value' applied. Values are JSON when they parse
    as JSON (numbers, lists, true/false/null), else strings; then checked against the field's type."""
    if not dataclasses.is_dataclass(settings):
        raise TypeError(f"suite settings must be a dataclass instance, got {type(settings).__name__}")
    hints = typing.get_type_hints(type(settings))
    changes = {}
    for item in overrides:
        key, sep, text = item.partition("=")
        if not sep or key not in hints:
            raise SettingsError(f"--set {item}: expected KEY=VALUE with KEY one of "
                                f"{', '.join(f.name for f in dataclasses.fields(settings))}")
        try:
            value = json.loads(text)
        except json.JSONDecodeError:
            value = text
        changes[key] = _coerce(key, value, hints[key])
    return dataclasses.replace(settings, **changes)


def _coerce(key, value, hint):
    """`value` as the field type `hint` (int, float, str, bool, tuple/list of those, Optional of those)."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", ())):
        if value is None and type(None) in args:
            return None
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(key, value, a)
            except SettingsError:
                pass
        raise SettingsError(f"--set {key}: {value!r} does not fit {hint}")
    if origin in (tuple, list):
        items = value if isinstance(value, list) else [value]
        inner = args[0] if args else typing.Any
        out = [_coerce(key, v, inner) for v in items]
        return tuple(out) if origin is tuple else out
    if hint is typing.Any:
        return value
    if hint is bool:
        if isinstance(value, bool):
            return value
    elif hint is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif hint is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif hint is str:
        return value if isinstance(value, str) else json.dumps(value)
    elif isinstance(hint, type) and isinstance(value, hint):
        return value
    raise SettingsError(f"--set {key}: expected {getattr(hint, '__name__', hint)}, got {value!r}")


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
