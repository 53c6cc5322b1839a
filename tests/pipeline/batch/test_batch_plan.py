"""Plan files -> tasks: the graph, content keys, and one-line refusals naming the field (no cluster)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.batch.plan import PlanError, expand

REPO = Path(__file__).resolve().parents[3]

PLAN = """
[scenes]
examples = ["cave-chair"]
[scenes.procedural]
count = 2
first_seed = 5
settings = { max_objects = 2 }

[simulate]
resolution = 16
[simulate.grid]
spots = [2, 4]
photons_per_pixel = [100.0, 1000.0]

[[methods]]
name = "fast"
settings = { steps = 10 }
[[methods]]
name = "bflidar"

[evaluate]
settings = { pictures = false }
"""


def _write(tmp_path, text, name="plan.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_expansion_graph(tmp_path):
    tasks = expand(_write(tmp_path, PLAN), version="v1")
    by = {st: [t for t in tasks if t.stage == st] for st in ("simulate", "fit", "evaluate")}
    assert len(by["simulate"]) == 3 * 4            # 3 scenes x 2 x 2 grid points
    assert len(by["fit"]) == 12 * 2 and len(by["evaluate"]) == 24
    keys = {t.key for t in tasks}
    assert len(keys) == len(tasks)
    order = {t.key: i for i, t in enumerate(tasks)}
    for t in tasks:                                  # inputs come first, and exist
        assert all(order[d] < order[t.key] for d in t.deps)
    sims = {t.key: t for t in by["simulate"]}
    grids = sorted((t.spec["grid"]["spots"], t.spec["grid"]["photons_per_pixel"]) for t in sims.values()
                   if t.spec["scene_label"] == "procedural-00006")
    assert grids == [(2, 100.0), (2, 1000.0), (4, 100.0), (4, 1000.0)]
    ev = by["evaluate"][0]
    assert ev.deps[1] in sims and ev.deps[0] in {t.key for t in by["fit"]}


def test_keys_are_content_hashes(tmp_path):
    a = expand(_write(tmp_path, PLAN), version="v1")
    b = expand(_write(tmp_path, PLAN, "other_name.toml"), version="v1")
    assert [t.key for t in a] == [t.key for t in b]          # same content, same keys
    c = expand(_write(tmp_path, PLAN.replace("steps = 10", "steps = 11")), version="v1")
    changed = {t.stage for t, u in zip(a, c) if t.key != u.key}
    assert changed == {"fit", "evaluate"}                     # the simulations stay finished
    d = expand(_write(tmp_path, PLAN), version="v2")
    assert not {t.key for t in a} & {t.key for t in d}        # other code: nothing counts as finished


def test_blend_key_follows_bytes_not_path(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    for sub in ("a", "b"):
        (tmp_path / sub / "room.blend").write_bytes(b"BLENDER-v500 same bytes")
    text = '[scenes]\nblend = ["{}/room.blend"]\n'
    ka = expand(_write(tmp_path, text.format("a")), version="v")[0].key
    kb = expand(_write(tmp_path, text.format("b")), version="v")[0].key
    assert ka == kb
    (tmp_path / "b" / "room.blend").write_bytes(b"BLENDER-v500 other bytes")
    assert expand(_write(tmp_path, text.format("b")), version="v")[0].key != ka


@pytest.mark.parametrize("text, words", [
    ("[scenes]\nexamples = ['nope']\n", ["scenes.examples", "unknown example 'nope'"]),
    ("[scenes]\n", ["scenes", "no scenes"]),
    ("[scenes]\nexamples = ['cave-chair']\n[[methods]]\nname = 'magic'\n", ["methods[0].name", "magic"]),
    ("[scenes]\nexamples = ['cave-chair']\n[simulate.grid]\nspots = 4\n", ["simulate.grid.spots", "list"]),
    ("[scenes.procedural]\ncount = -1\n", ["scenes.procedural.count", ">= 0"]),
    ("[scenes.procedural]\nsettings = { max_objects = 'x' }\n", ["scenes.procedural.settings.max_objects"]),
    ("[scenes]\nblend = ['missing.blend']\n", ["scenes.blend", "no such .blend"]),
    ("[scene]\n", ["scene", "unknown plan entry"]),
    ("[scenes]\nexamples = ['cave-chair']\n[simulate]\nphotons = 3\n", ["simulate.photons", "unknown setting"]),
    ("[scenes]\nexamples = ['cave-chair']\n[simulate.grid]\nbins = [10, 'x']\n", ["simulate.grid.bins", "integer"]),
    ("[scenes\n", ["file", "TOML"]),
])
def test_bad_plans_name_the_field(tmp_path, text, words):
    p = _write(tmp_path, text)
    with pytest.raises(PlanError) as err:
        expand(p, version="v")
    msg = str(err.value)
    assert msg.startswith(str(p)) and all(w in msg for w in words), msg


def _cli(*args, cwd=REPO):
    env = {"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"}
    return subprocess.run([sys.executable, "-m", "torch_recon", "batch", *map(str, args)], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=120)


def test_cli_bad_input_one_line_exit_2(tmp_path):
    r = _cli(_write(tmp_path, "[scenes]\nexamples = ['nope']\n"), "--out", tmp_path / "out")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "scenes.examples" in r.stderr, r.stderr
    r = _cli(_write(tmp_path, PLAN), "--out", tmp_path / "out", "--set", "workers=0")
    assert r.returncode == 2 and "setting workers" in r.stderr, r.stderr
    r = _cli(tmp_path / "absent.toml", "--out", tmp_path / "out")
    assert r.returncode == 2 and "absent.toml" in r.stderr and "Traceback" not in r.stderr


def test_cli_dry_run_lists_tasks(tmp_path):
    r = _cli(_write(tmp_path, PLAN), "--out", tmp_path / "out", "--dry-run")
    assert r.returncode == 0, r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.strip().startswith("todo")]
    assert len(lines) == 12 + 24 + 24
    plan = json.loads((tmp_path / "out" / "plan.json").read_text())
    assert len(plan["tasks"]) == 60 and plan["code_version"]
