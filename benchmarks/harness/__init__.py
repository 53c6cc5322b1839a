"""The benchmark harness: suites (benchmarks/suites/*.py) declare quick and full settings and a run
function; the harness gives them cached datasets, timing, the real entry points and one fit / baseline /
evaluate runner, checks their rows and writes results/<name>.json + .png; README tables are rendered
from those JSONs. See docs/benchmarks.md."""

from benchmarks.harness.context import Context, CliError, Timing
from benchmarks.harness.runners import NoSurface, Refused
from benchmarks.harness.suite import Suite

__all__ = ["Suite", "Context", "Timing", "CliError", "Refused", "NoSurface"]
