"""`python -m benchmarks list | run NAME [--quick] [--methods a,b] [--merge] [--set k=v ...] | all [--quick] | readme`."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
import traceback
from pathlib import Path

from benchmarks.harness import report
from benchmarks.harness.context import REPO_ROOT, RESULTS_DIR, Context

QUICK_DIR = RESULTS_DIR / "quick"
from benchmarks.harness.suite import SettingsError, all_suites


def run_suite(suite, quick: bool, overrides=(), results_dir: Path | None = None, data_dir: Path | None = None,
              log=None, methods=None, merge: bool = False) -> Path:
    """Run one suite, check its rows, write results/<name>.json and .png (quick runs: results/quick/, which
    git ignores, so a smoke run never replaces the measured figures README shows); the JSON's path.
    `methods`: only these (the suite's `methods` setting); `merge`: keep the existing JSON's rows this run
    does not re-measure (keyed by method and scene), each row naming the run that measured it."""
    results_dir = results_dir or (QUICK_DIR if quick else RESULTS_DIR)
    log = log or (lambda msg: print(msg, flush=True))
    sets = list(overrides)
    settings = suite.settings(quick, [*sets, *method_override(suite, methods)])
    target = Path(results_dir) / f"{suite.name}.json"
    machine, commit = report.machine_info(), report.git_commit(REPO_ROOT)     # the code as the run starts
    log(f"== {suite.name} ({'quick' if quick else 'full'}): {suite.description.splitlines()[0]}")
    log(f"machine: {report.machine_line(machine)}")
    ctx = Context(suite.name, quick, **({"data_dir": data_dir} if data_dir else {}), log=log)
    with ctx.timed() as total:
        rows = report.check_rows(suite.run(settings, ctx), suite.name)
    machine["loadavg_1min_end"] = round(os.getloadavg()[0], 2)
    command = " ".join(["python -m benchmarks run", suite.name, *(["--quick"] if quick else []),
                        *([f"--methods {','.join(methods)}"] if methods else []), *(["--merge"] if merge else []),
                        *(f"--set {o}" for o in sets)])
    doc = report.results_document(suite, settings, rows, quick, machine, command, REPO_ROOT, commit)
    doc["suite"]["total_wall_s"] = round(total.wall_s, 2)
    if merge and target.is_file():
        doc = report.merge_results(json.loads(target.read_text()), doc, suite.row_id)
        rows = doc["rows"]
        log(f"merged into {target}: {len(rows)} rows from {len(doc['runs'])} runs")
    path = report.write_json(target, doc)
    png = path.with_suffix(".png")
    if suite.plot is not None:
        suite.plot(rows, settings, png)
    else:
        report.plot_rows(rows, png, title=f"{suite.name}: {report.machine_line(machine)}")
    log(render(suite, doc))
    log(f"({total.wall_s:.0f} s) wrote {path} and {png}")
    return path


def method_override(suite, methods) -> list[str]:
    """`--methods a,b` as the `--set` of the suite's `methods` setting; SettingsError when it has none."""
    if not methods:
        return []
    if "methods" not in {f.name for f in dataclasses.fields(suite.full)}:
        raise SettingsError("methods", f"suite {suite.name} has no methods setting (--methods needs one)")
    return [f"methods={json.dumps(list(methods))}"]


def render(suite, results: dict) -> str:
    """A suite's table (its own renderer or the default) and the provenance line."""
    table = suite.readme(results) if suite is not None and suite.readme is not None else report.default_table(results)
    return f"{table}\n\n{report.provenance(results)}"


def readme(path: Path = REPO_ROOT / "README.md", results_dir: Path = RESULTS_DIR, suites=None) -> list[str]:
    """Regenerate every marked table of README from the results JSONs; the names rendered."""
    suites = all_suites() if suites is None else suites

    def load(name):
        f = Path(results_dir) / f"{name}.json"
        return json.loads(f.read_text()) if f.is_file() else None
    text = Path(path).read_text()
    new, done = report.render_readme(text, load, lambda name, res: render(suites.get(name), res))
    if new != text:
        tmp = Path(path).with_name(Path(path).name + ".tmp")
        tmp.write_text(new)
        os.replace(tmp, path)
    return done


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description="benchmark suites (benchmarks/suites/)")
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="the suites and what each measures")
    r = sub.add_parser("run", help="run one suite -> benchmarks/results/NAME.json and .png")
    r.add_argument("name")
    r.add_argument("--quick", action="store_true", help="the suite's quick settings (minutes)")
    r.add_argument("--methods", type=lambda t: [m.strip() for m in t.split(",") if m.strip()], metavar="A,B",
                   help="run only these methods (the suite's methods setting)")
    r.add_argument("--merge", action="store_true", help="keep the existing results' rows this run does not "
                   "re-measure (by method and scene); each row names its run in the table")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override one setting")
    a = sub.add_parser("all", help="run every suite in turn (one failing does not stop the others)")
    a.add_argument("--quick", action="store_true")
    a.add_argument("--skip", nargs="*", default=[], metavar="NAME")
    sub.add_parser("readme", help="regenerate the marked tables of README.md and docs/*.md from benchmarks/results/*.json")
    args = ap.parse_args(argv)
    suites = all_suites()
    if args.cmd == "list":
        width = max(map(len, suites), default=0)
        for name, s in suites.items():
            print(f"{name:{width}s}  {s.description.splitlines()[0]}")
        return 0
    if args.cmd == "readme":
        for path in [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]:
            done = readme(path, suites=suites)
            if done:
                print(f"{path.relative_to(REPO_ROOT)}: tables regenerated: {', '.join(done)}")
        return 0
    if args.cmd == "run":
        if args.name not in suites:
            print(f"error: no suite {args.name!r}; choose one of {', '.join(suites)}", file=sys.stderr)
            return 2
        suite = suites[args.name]
        try:
            suite.settings(args.quick, [*args.set, *method_override(suite, args.methods)])
            target = (QUICK_DIR if args.quick else RESULTS_DIR) / f"{suite.name}.json"
            if args.merge and target.is_file():
                report.rows_by_id(json.loads(target.read_text())["rows"], str(target.relative_to(REPO_ROOT)), suite.row_id)
        except (SettingsError, report.RowError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        run_suite(suite, args.quick, args.set, methods=args.methods, merge=args.merge)
        return 0
    status = []
    for name, s in suites.items():
        if name in args.skip:
            continue
        t0 = time.perf_counter()
        try:
            run_suite(s, args.quick)
            status.append((name, "ok", time.perf_counter() - t0))
        except Exception:       # noqa: BLE001 - report and go on with the next suite
            traceback.print_exc()
            status.append((name, "FAILED", time.perf_counter() - t0))
    print("\n== summary")
    for name, st, sec in status:
        print(f"  {name:28s} {st:8s} {sec:7.1f} s")
    return 0 if all(st == "ok" for _, st, _ in status) else 1
