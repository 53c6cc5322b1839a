"""The one base of user-facing errors, and the one place a command turns them into an exit status.

A `PlatolidarError` is a problem the user can fix (a bad dataset, setting or file): the command
line prints one line naming the file / field / setting and exits 2. An `OSError` (missing file,
read-only or full disk) is reported the same way, with its path. Anything else is a bug and keeps
its traceback. Subclasses that were ValueErrors / RuntimeErrors before keep that base too, so
existing `except ValueError` callers still see them.
"""

from __future__ import annotations

import sys

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class PlatolidarError(Exception):
    """A problem the user can fix; the message names what is wrong and what was expected."""


class SettingsError(PlatolidarError, ValueError):
    """A setting (command-line option, --set, --config file, add-on field) with a bad value.

    `key` is the dotted setting name (e.g. 'fast.lr'); the message starts with it.
    """

    def __init__(self, key: str, message: str, source: str = ""):
        self.key, self.source, self.detail = key, source, message
        where = f"{source}: " if source else ""
        super().__init__(f"{where}setting {key}: {message}" if key else f"{where}{message}")


class MeasurementsError(PlatolidarError, ValueError):
    """Measurements (a preprocessed .npz or their contents) that cannot be used."""


class UnconstrainedMeasurementsError(MeasurementsError):
    """The measurements do not constrain the scene enough for a reconstruction (e.g. no spots,
    no visible depth, every shadow empty): refused rather than returning an empty mesh."""


class PreprocessError(PlatolidarError, ValueError):
    """Input the preprocessing cannot use; the message names the spot and what was expected."""


class EvaluationError(PlatolidarError, ValueError):
    """Evaluation impossible with what was given (e.g. ground truth without a surface in view)."""


class CheckpointError(PlatolidarError, ValueError):
    """A checkpoint that belongs to other settings or another dataset."""


def describe(exc: BaseException) -> str:
    """One line for a user-facing error: OSErrors as 'path: reason'."""
    if isinstance(exc, OSError) and exc.strerror:
        path = exc.filename if exc.filename is not None else ""
        return f"{path}: {exc.strerror}" if path else exc.strerror
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def run_command(fn, *args, prog: str = "", interrupted: str = "interrupted") -> int:
    """Call fn(*args) -> exit code; user-facing errors print 'PROG: error: ...' and return 2."""
    prefix = f"{prog}: " if prog else ""
    try:
        return int(fn(*args) or 0)
    except (PlatolidarError, OSError) as exc:
        print(f"{prefix}error: {describe(exc)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"{prefix}{interrupted}", file=sys.stderr)
        return EXIT_INTERRUPTED
