"""One settings mechanism: dataclass defaults -> command line, --config (JSON/TOML), --set, checked values."""

import argparse
from dataclasses import dataclass, field

import pytest

from torch_recon.contract import settings
from torch_recon.contract.errors import SettingsError
from torch_recon.contract.methods import FIT_METHODS, METHODS, load, method


@dataclass
class Inner:
    lr: float = 0.2                   # learning rate
    steps: int = 10                   # optimisation steps
    box: tuple | None = None          # optional box


@dataclass
class Outer:
    SETTINGS_META = {"mode": {"choices": ("a", "b")}, "threads": {"range": (1, None)}}

    mode: str = "a"                   # which method
    threads: int = 2
    quiet: bool = False
    inner: Inner = field(default_factory=Inner)


def _parse(argv, flags=("mode", "threads", "quiet", "inner.lr")):
    p = argparse.ArgumentParser()
    settings.add_arguments(p, Outer, flags)
    return settings.from_args(Outer, p.parse_args(argv))


def test_defaults_help_and_flags():
    assert _parse([]) == Outer()
    specs = {s.key: s for s in settings.all_specs(Outer)}
    assert specs["inner.lr"].help == "learning rate" and specs["mode"].choices == ("a", "b")
    got = _parse(["--mode", "b", "--threads", "3", "--quiet", "--lr", "0.5", "--set", "inner.steps=4"])
    assert got == Outer(mode="b", threads=3, quiet=True, inner=Inner(lr=0.5, steps=4))


def test_set_wins_over_flags_and_config_files(tmp_path):
    j = tmp_path / "s.json"
    j.write_text('{"threads": 5, "inner": {"steps": 7}}')
    t = tmp_path / "s.toml"
    t.write_text('mode = "b"\n[inner]\nbox = [0, 1, 2]\n')
    assert _parse(["--config", str(j), "--threads", "6"]) == Outer(threads=6, inner=Inner(steps=7))
    assert _parse(["--config", str(t), "--set", "mode=a"]).inner.box == (0, 1, 2)
    assert _parse(["--threads", "6", "--set", "threads=8"]).threads == 8


@pytest.mark.parametrize("argv, message", [
    (["--set", "inner.lr=abc"], "setting inner.lr: expected a float, got 'abc'"),
    (["--set", "inner.nope=1"], "setting inner.nope: unknown setting"),
    (["--set", "inner=1"], "setting inner: is a section"),
    (["--mode", "c"], "setting mode: expected one of a, b, got 'c'"),
    (["--threads", "0"], "setting threads: expected a value >= 1, got 0"),
    (["--threads", "2.5"], "setting threads: expected an integer, got '2.5'"),
    (["--set", "quiet=maybe"], "setting quiet: expected true or false, got 'maybe'"),
    (["--set", "inner.lr=nan"], "setting inner.lr: expected a finite number"),
    (["--set", "novalue"], "expected KEY=VALUE"),
])
def test_bad_values_name_the_key(argv, message):
    with pytest.raises(SettingsError) as exc:
        _parse(argv)
    assert message in str(exc.value)


def test_bad_config_files_name_the_file_and_key(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"inner": {"lr": "fast"}}')
    with pytest.raises(SettingsError, match=r"bad.json: setting inner.lr: expected a float, got 'fast'"):
        _parse(["--config", str(bad)])
    bad.write_text("{not json")
    with pytest.raises(SettingsError, match="bad.json: not valid JSON"):
        _parse(["--config", str(bad)])
    bad.write_text("[1, 2]")
    with pytest.raises(SettingsError, match="expected a table"):
        _parse(["--config", str(bad)])
    with pytest.raises(FileNotFoundError):
        _parse(["--config", str(tmp_path / "missing.json")])


def test_device_names():
    for ok in ("auto", "cpu", "cuda", "cuda:1"):
        assert settings.check_device_name(ok) == ok
    for bad in ("gpu", "cuda:x", "", "CPU"):
        with pytest.raises(SettingsError, match="setting device: expected auto, cpu, cuda or cuda:N"):
            settings.check_device_name(bad)


def test_method_table():
    assert FIT_METHODS == ("fast", "platonerf") and METHODS["bflidar"].command == "baseline"
    with pytest.raises(SettingsError, match="setting mode"):
        method("nerf")
    assert load("torch_recon.contract.methods:method") is method


def test_every_stage_has_generated_options():
    from torch_recon.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for stage in ("preprocess", "baseline", "fit", "evaluate", "convert"):
        opts = {o for a in sub.choices[stage]._actions for o in a.option_strings}
        assert {"--config", "--set"} <= opts, stage


def test_every_command_help_renders():
    """`--help` of every subcommand formats (argparse %-formats help text: a field comment's '14 %,' broke
    `advise-spots --help` with a ValueError)."""
    from torch_recon.cli import build_parser

    def every_parser(parser):
        yield parser
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for child in action.choices.values():
                    yield from every_parser(child)

    parsers = list(every_parser(build_parser()))
    assert len(parsers) > 6 and any(p.prog.endswith("advise-spots") for p in parsers)
    for parser in parsers:
        assert parser.format_help(), parser.prog


def test_convert_settings_from_flags_config_and_set(tmp_path):
    from torch_recon.commands.convert import ConvertSettings

    sub = next(a for a in __import__("torch_recon.cli").cli.build_parser()._actions
               if isinstance(a, argparse._SubParsersAction))
    p = sub.choices["convert"]
    cfg = tmp_path / "c.toml"
    cfg.write_text("ignore = [0, 1]\nbin_ps = 64.0\n")
    args = p.parse_args(["from-platonerf", "a", "b", "--config", str(cfg), "--ignore", "[2,3]",
                         "--set", "window_bins=8", "--float32"])
    assert settings.from_args(ConvertSettings, args) == ConvertSettings(bin_ps=64.0, ignore=(2, 3), window_bins=8,
                                                                        float32=True)
    for argv, message in ((["--bin-m", "0"], "setting bin_m: expected a number > 0"),
                          (["--spots", "0"], "setting spots: expected a value >= 1"),
                          (["--ignore", "1,-2"], "setting ignore: expected a value >= 0")):
        with pytest.raises(SettingsError, match=message):
            settings.from_args(ConvertSettings, p.parse_args(["to-platonerf", "a", "b", *argv]))


def test_help_comes_from_field_comments_only():
    """A field's help is its trailing comment and the comment lines aligned under it, never a comment
    inside a method that follows the fields."""
    @dataclass
    class WithMethod:
        width: float = 1.0            # bin width
                                      # (of optical path)
        count: int = 3                # how many

        def validate(self):
            # not help
            return None

    helps = {s.key: s.help for s in settings.specs(WithMethod)}
    assert helps == {"width": "bin width (of optical path)", "count": "how many"}


def test_inherited_fields_keep_their_help():
    from torch_recon.commands.baseline import BaselineCommand
    from torch_recon.commands.preprocess import PreprocessCommand

    for cls in (PreprocessCommand, BaselineCommand):
        helps = {s.key: s.help for s in settings.specs(cls)}
        assert helps["device"].startswith("torch device") and "CPU threads" in helps["threads"], cls
    with pytest.raises(SettingsError, match="setting threads: expected a value >= 1"):
        settings.with_values(PreprocessCommand(), {"threads": "0"})
