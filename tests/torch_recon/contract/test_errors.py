"""One error base: user-facing errors -> one line, exit 2; anything else keeps its traceback."""

import errno

import pytest

from torch_recon.contract.errors import (PlatolidarError, SettingsError, UnconstrainedMeasurementsError, describe,
                                         run_command)


def _raise(exc):
    raise exc


def test_user_errors_print_one_line_and_exit_2(capsys):
    assert run_command(_raise, SettingsError("fast.lr", "expected a float, got 'abc'"), prog="platolidar") == 2
    assert capsys.readouterr().err == "platolidar: error: setting fast.lr: expected a float, got 'abc'\n"
    assert run_command(_raise, UnconstrainedMeasurementsError("measurements: no spots")) == 2
    assert capsys.readouterr().err == "error: measurements: no spots\n"


def test_os_errors_name_the_path(capsys):
    exc = PermissionError(errno.EACCES, "Permission denied", "/data/out/mesh.ply")
    assert run_command(_raise, exc) == 2
    assert capsys.readouterr().err == "error: /data/out/mesh.ply: Permission denied\n"
    assert describe(FileExistsError("x: a dataset is already there")) == "x: a dataset is already there"


def test_bugs_keep_their_traceback():
    with pytest.raises(ValueError, match="a bug"):
        run_command(_raise, ValueError("a bug"))
    with pytest.raises(KeyError):
        run_command(_raise, KeyError("k"))


def test_project_errors_share_the_base():
    from pipeline.config import ConfigError
    from torch_recon.contract.dataset import DatasetError
    from torch_recon.mesh_export import MeshExportError
    from torch_recon.preprocess import PreprocessError

    for cls in (ConfigError, DatasetError, MeshExportError, PreprocessError, UnconstrainedMeasurementsError):
        assert issubclass(cls, PlatolidarError) and issubclass(cls, ValueError), cls
    assert str(ConfigError("cfg.json", "bins", "expected >= 1")) == "cfg.json: setting bins: expected >= 1"


def test_cli_reports_a_missing_dataset_in_one_line(tmp_path, capsys):
    from torch_recon.cli import main

    assert main(["evaluate", str(tmp_path / "nope.ply"), "--dataset", str(tmp_path / "missing"),
                 "--out", str(tmp_path / "eval")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and str(tmp_path) in err[0], err
