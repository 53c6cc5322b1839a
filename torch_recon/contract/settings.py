"""The one settings mechanism: dataclasses hold every default; the command line is generated from them.

A stage's settings are a dataclass (sections nest as dataclass fields, e.g. FitConfig.fast). For each
field this module derives:
- the type from the annotation (int, float, bool, str, `X | None`, tuple/list of numbers);
- the help text from the field's trailing comment in the source (or `metadata={"help": ...}`);
- choices / range / unit / extra flag names from the class's `SETTINGS_META` dict
  (`{"field": {"choices": (...), "range": (lo, hi), "unit": "m", "flags": ("--alias",)}}`).

Values are layered: dataclass defaults < `--config FILE` (JSON, or TOML by suffix) < generated flags
< `--set a.b=v` (repeatable). Every value is type- and range-checked, and a bad one raises
SettingsError naming the key: "setting fast.lr: expected a float, got 'abc'". A class's own
`validate()` (or `__post_init__`) then checks relations between fields.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import textwrap
import tokenize
import types
import typing
from functools import lru_cache
from pathlib import Path

from .errors import SettingsError


# -- field description --------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Spec:
    key: str                    # dotted name, e.g. 'fast.lr'
    name: str                   # field name
    kind: type                  # int, float, bool, str, tuple, list or a dataclass (section)
    optional: bool              # None allowed
    default: object
    help: str = ""
    choices: tuple | None = None
    range: tuple | None = None  # (lo, hi), either may be None; inclusive
    unit: str = ""
    flags: tuple = ()           # extra option strings
    item: type | None = None    # element type of a tuple[X, ...] / list[X]

    @property
    def is_section(self) -> bool:
        return dataclasses.is_dataclass(self.kind)


def _comments(cls) -> dict:
    """Trailing '# ...' comment of each field line in the class body, plus the comment-only lines right
    below it (indented past the field names); comments anywhere else (e.g. in methods) are not help."""
    import inspect

    try:
        src = textwrap.dedent(inspect.getsource(cls))     # a class defined inside a function is indented
    except (OSError, TypeError):
        return {}
    out, last, last_line, new_statement = {}, None, -1, True
    names = {f.name for f in dataclasses.fields(cls)}
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type in (tokenize.NL, tokenize.INDENT, tokenize.DEDENT):
            continue
        if tok.type == tokenize.NEWLINE:
            new_statement = True
        elif tok.type == tokenize.COMMENT:
            text = tok.string.lstrip("#").strip()
            alone = tok.line.lstrip().startswith("#")
            if last is not None and not alone and last not in out:
                out[last], last_line = text, tok.start[0]
            elif last in out and alone and tok.start[0] == last_line + 1 and tok.start[1] > 4:
                out[last] += " " + text     # an indented continuation of the comment
                last_line = tok.start[0]
        elif new_statement:             # the first token of a statement: a field, or something else
            new_statement = False
            is_field = tok.type == tokenize.NAME and tok.start[1] == 4 and tok.string in names
            last = tok.string if is_field else None
    return out


def _kind(tp):
    """(base type, optional, element type) of an annotation."""
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        base, _, item = _kind(args[0]) if len(args) == 1 else (object, False, None)
        return base, True, item
    if origin in (tuple, list):
        items = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return origin, False, (items[0] if len(set(items)) == 1 and isinstance(items[0], type) else None)
    return tp, False, None


@lru_cache(maxsize=None)
def specs(cls, prefix: str = "") -> tuple:
    """Spec of every field of a settings dataclass (sections included, not expanded)."""
    hints = typing.get_type_hints(cls)
    meta = getattr(cls, "SETTINGS_META", {})
    notes = {}
    for base in reversed(cls.__mro__):     # a field inherited from a settings base keeps its help
        if dataclasses.is_dataclass(base):
            notes.update(_comments(base))
    out = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        kind, optional, item = _kind(hints[f.name])
        default = f.default if f.default is not dataclasses.MISSING else \
            (f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
        m = {**meta.get(f.name, {}), **f.metadata}
        choices = m.get("choices")
        out.append(Spec(key=prefix + f.name, name=f.name, kind=kind, optional=optional, default=default,
                        help=m.get("help", notes.get(f.name, "")), choices=tuple(choices) if choices else None,
                        range=m.get("range"), unit=m.get("unit", ""), flags=tuple(m.get("flags", ())), item=item))
    return tuple(out)


def all_specs(cls, prefix: str = "") -> list:
    """Every leaf setting, sections expanded (dotted keys)."""
    out = []
    for s in specs(cls, prefix):
        out += all_specs(s.kind, s.key + ".") if s.is_section else [s]
    return out


def _unknown(cls, name: str, by_name: dict, where: str = "known here") -> str:
    """The message for an unknown key: what replaced it, when the section lists it in REMOVED_SETTINGS
    (a saved config from an older version), else the keys the section knows."""
    removed = getattr(cls, "REMOVED_SETTINGS", {}).get(name)
    if removed:
        return f"removed setting: {removed}"
    return f"unknown setting; {where}: {', '.join(sorted(by_name))}"


def find_spec(cls, key: str) -> Spec:
    node, parts = cls, key.split(".")
    for i, part in enumerate(parts):
        by_name = {s.name: s for s in specs(node, ".".join(parts[:i]) + "." if i else "")}
        s = by_name.get(part)
        if s is None:
            where = f"section {'.'.join(parts[:i])}" if i else "settings"
            raise SettingsError(key, _unknown(node, part, by_name, where + " has"))
        if i < len(parts) - 1:
            if not s.is_section:
                raise SettingsError(key, f"{s.key} is a value, not a section")
            node = s.kind
    return s


# -- values ---------------------------------------------------------------------------------------------
_TYPE_WORDS = {int: "an integer", float: "a float", bool: "true or false", str: "a string",
               tuple: "a list", list: "a list"}


def check_value(spec: Spec, value):
    """`value` (from JSON/TOML, or a string from the command line) as the field's type, or SettingsError."""
    if isinstance(value, str) and spec.kind is not str:
        value = _parse_text(spec, value)
    if value is None:
        if spec.optional:
            return None
        raise SettingsError(spec.key, f"expected {_TYPE_WORDS.get(spec.kind, spec.kind.__name__)}, got none")
    kind = spec.kind
    bad = SettingsError(spec.key, f"expected {_TYPE_WORDS.get(kind, getattr(kind, '__name__', str(kind)))}"
                                  f"{' or none' if spec.optional else ''}, got {value!r}")
    if kind is bool:
        if not isinstance(value, bool):
            raise bad
    elif kind is int:
        if isinstance(value, bool) or not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise bad
        value = int(value)
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad
        value = float(value)
        if not math.isfinite(value):
            raise SettingsError(spec.key, f"expected a finite number, got {value!r}")
    elif kind is str:
        if not isinstance(value, str):
            raise bad
    elif kind in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise bad
        if spec.item is not None:
            each = dataclasses.replace(spec, kind=spec.item, item=None, optional=False, choices=None)
            value = [check_value(each, v) for v in value]
        value = kind(value)
    if spec.choices is not None and value not in spec.choices:
        raise SettingsError(spec.key, f"expected one of {', '.join(map(str, spec.choices))}, got {value!r}")
    if spec.range is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
        lo, hi = spec.range
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            span = f">= {lo}" if hi is None else (f"<= {hi}" if lo is None else f"in [{lo}, {hi}]")
            raise SettingsError(spec.key, f"expected a value {span}{' ' + spec.unit if spec.unit else ''}, "
                                          f"got {value!r}")
    return value


def _parse_text(spec: Spec, text: str):
    t = text.strip()
    if spec.optional and t.lower() in ("none", "null", ""):
        return None
    try:
        if spec.kind is bool:
            low = t.lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ValueError
        if spec.kind is int:
            return int(t)
        if spec.kind is float:
            return float(t)
        if spec.kind in (tuple, list):
            if t.startswith("["):
                return json.loads(t)
            parts = [x.strip() for x in t.split(",")] if t else []
            return parts if spec.item is not None else [float(x) for x in parts]
    except ValueError:
        raise SettingsError(spec.key, f"expected {_TYPE_WORDS.get(spec.kind, spec.kind.__name__)}, got {text!r}") \
            from None
    return text


def from_dict(cls, data: dict, source: str = "", prefix: str = ""):
    """A settings instance from a (nested) dict; unknown keys and bad values name the key."""
    if not isinstance(data, dict):
        raise SettingsError(prefix.rstrip("."), f"expected a table of settings, got {type(data).__name__}", source)
    by_name = {s.name: s for s in specs(cls, prefix)}
    unknown = sorted(set(data) - set(by_name))
    if unknown:
        raise SettingsError(prefix + unknown[0], _unknown(cls, unknown[0], by_name), source)
    kw = {}
    for name, value in data.items():
        s = by_name[name]
        try:
            kw[name] = from_dict(s.kind, value, source, s.key + ".") if s.is_section else check_value(s, value)
        except SettingsError as exc:
            if source and not exc.source:
                raise SettingsError(exc.key, exc.detail, source) from None
            raise
    return _construct(cls, kw, source)


def _construct(cls, kw: dict, source: str = ""):
    try:
        obj = cls(**kw)
        if hasattr(obj, "validate"):
            obj.validate()
    except SettingsError as exc:
        if source and not exc.source:
            raise SettingsError(exc.key, exc.detail, source) from None
        raise
    return obj


def to_dict(obj) -> dict:
    return dataclasses.asdict(obj)


def merged(base, data: dict, source: str = ""):
    """`base` with the (nested, partial) dict `data` laid over it."""
    def lay(d, over):
        for k, v in over.items():
            d[k] = lay(dict(d[k]), v) if isinstance(v, dict) and isinstance(d.get(k), dict) else v
        return d
    return from_dict(type(base), lay(to_dict(base), data), source)


def with_values(base, values: dict):
    """`base` with dotted keys set, each checked: {'fast.lr': '0.1'} or {'seed': 3}."""
    nested = {}
    for key, raw in values.items():
        spec = find_spec(type(base), key)
        if spec.is_section:
            example = all_specs(spec.kind, key + ".")[0].key
            raise SettingsError(key, f"is a section; set one of its values, e.g. {example}")
        node = nested
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = check_value(spec, raw)
    return merged(base, nested)


def parse_assignments(items) -> dict:
    out = {}
    for a in items or ():
        if "=" not in a:
            raise SettingsError("", f"--set {a!r}: expected KEY=VALUE, e.g. fast.resolution=96")
        key, raw = a.split("=", 1)
        out[key.strip()] = raw
    return out


def load_file(path) -> dict:
    """A settings file as a dict: JSON, or TOML when the name ends in .toml."""
    p = Path(path)
    text = p.read_text(encoding="utf-8")        # OSError: reported with its path by the CLI
    try:
        if p.suffix.lower() == ".toml":
            import tomllib
            data = tomllib.loads(text)
        else:
            data = json.loads(text)
    except (ValueError, UnicodeDecodeError) as exc:   # JSONDecodeError and TOMLDecodeError are ValueErrors
        raise SettingsError("", f"not valid {'TOML' if p.suffix.lower() == '.toml' else 'JSON'} ({exc})", str(p)) \
            from None
    if not isinstance(data, dict):
        raise SettingsError("", f"expected a table of settings, got {type(data).__name__}", str(p))
    return data


def check_device_name(name, key: str = "device") -> str:
    """A torch device name: 'auto', 'cpu', 'cuda' or 'cuda:N' (checked here, resolved by torch_recon.device)."""
    ok = isinstance(name, str) and (name in ("auto", "cpu", "cuda")
                                    or (name.startswith("cuda:") and name[5:].isdigit()))
    if not ok:
        raise SettingsError(key, f"expected auto, cpu, cuda or cuda:N, got {name!r}")
    return name


# -- the command line -------------------------------------------------------------------------------------
def _flag(spec: Spec) -> str:
    return "--" + spec.name.replace("_", "-")


def add_arguments(parser: argparse.ArgumentParser, cls, flags=(), sets: bool = True) -> None:
    """--config, --set and one option per key in `flags` (dotted keys of `cls`), defaults left to `cls`."""
    dest_keys = getattr(parser, "_settings_flags", {})
    for key in flags:
        spec = find_spec(cls, key)
        dest = "setting__" + key.replace(".", "__")
        unit = f" ({spec.unit})" if spec.unit else ""
        choices = f" (one of {', '.join(map(str, spec.choices))})" if spec.choices else ""
        text = f"{spec.help}{unit}{choices} [default {spec.default}; setting {key}]".lstrip()
        text = text.replace("%", "%%")     # argparse %-formats help ('... 2-14 %, ...' in a field's comment)
        names = (_flag(spec), *spec.flags)
        if spec.kind is bool:
            parser.add_argument(*names, dest=dest, action=argparse.BooleanOptionalAction, default=None, help=text)
        else:
            parser.add_argument(*names, dest=dest, default=None, metavar=spec.name.upper(), help=text)
        dest_keys[dest] = key
    parser._settings_flags = dest_keys
    if sets:
        listing = ", ".join(f"{s.key}={s.default}" for s in all_specs(cls))
        parser.epilog = "settings (--set KEY=VALUE, or --config FILE): " + listing
        parser.epilog = "\n".join(textwrap.wrap(parser.epilog, 100, subsequent_indent="  "))
        parser.formatter_class = argparse.RawDescriptionHelpFormatter
        parser.add_argument("--config", metavar="FILE", help="settings file (JSON, or TOML by suffix): any "
                            "settings by name, sections as nested tables; flags and --set win over it")
        parser.add_argument("--set", dest="set_values", action="append", default=[], metavar="KEY=VALUE",
                            help="one setting by its dotted name, e.g. --set seed=1 (repeatable; wins over flags)")
    parser.set_defaults(_settings_flags=dest_keys)


def from_args(cls, args, base=None, extra: dict | None = None):
    """Settings from defaults < base < --config < flags < `extra` < --set."""
    obj = base if base is not None else _construct(cls, {})
    if getattr(args, "config", None):
        obj = merged(obj, load_file(args.config), str(args.config))
    values = {}
    for dest, key in getattr(args, "_settings_flags", {}).items():
        v = getattr(args, dest, None)
        if v is not None:
            values[key] = v
    values.update(extra or {})
    values.update(parse_assignments(getattr(args, "set_values", None)))   # --set last: it wins
    if values:
        obj = with_values(obj, values)
    return obj
