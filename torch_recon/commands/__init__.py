"""CLI subcommands of `platolidar` (= `python -m torch_recon`), one module each (see torch_recon/cli.py).

Each module's `register(sub)` calls `add_stage` with its settings dataclass: the options are generated
from it by contract/settings.py (flags for the common keys, --config and --set for all of them).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class DeviceSettings:
    """Where torch runs; the base of the settings of the commands that preprocess (preprocess, baseline)."""

    device: str = "cpu"               # torch device: auto, cpu, cuda, cuda:N
    threads: int | None = None        # CPU threads for torch (None: torch's choice; 1 is faster on a busy machine)

    SETTINGS_META = {"threads": {"range": (1, None)}}

    def validate(self):
        from ..contract.settings import check_device_name

        check_device_name(self.device)


DEVICE_FLAGS = ("device", "threads")


def add_stage(sub, name: str, run, settings, flags, *, help: str, description: str, arguments=()):
    """The parser of one stage: its positional/extra `arguments` ((names, add_argument keywords), ...), the
    options generated from the `settings` dataclass (`flags`: the keys that get a flag), `run` as its func."""
    from ..contract.settings import add_arguments

    p = sub.add_parser(name, help=help, description=description)
    for names, kw in arguments:
        p.add_argument(*names, **kw)
    add_arguments(p, settings, flags)
    p.set_defaults(func=run)
    return p
