"""The dataset cache: simulated datasets (and datasets derived from them) kept under
benchmarks/results/data/, keyed by a hash of the settings, validated before every reuse."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

CACHE_STAMP = "bench_cache.json"


def simulate_args(example: str, resolution: int, spots: int, options: dict) -> list[str]:
    """pipeline/simulate.py arguments: option names with '_' -> '-'; True -> a bare flag; False/None
    -> left out (the simulator's default)."""
    args = ["--example", example, "--resolution", str(int(resolution))]
    args += [] if spots is None else ["--spots", str(int(spots))]     # None: the spots come from --spot-list
    for key in sorted(options):
        value = options[key]
        flag = "--" + key.replace("_", "-")
        if value is True:
            args.append(flag)
        elif value is not None and value is not False:
            # a value starting with '-' (a spot list's negative x) would read as a flag: one token then
            args += [f"{flag}={value}"] if str(value).startswith("-") else [flag, str(value)]
    return args


def simulate_cli(example: str, resolution: int, spots: int, options: dict, out) -> list[str]:
    """The simulator's command line for these settings (pipeline.launch: the one way to start it)."""
    from pipeline.launch import simulate_command
    return simulate_command([*simulate_args(example, resolution, spots, options), "--out", out])


def cached_dataset(ctx, example: str, resolution: int, spots: int, options: dict) -> Path:
    """ctx.dataset: simulate (a subprocess of the real simulator) unless a valid cached copy exists. The key
    holds the scene's fingerprint: an edited example scene is simulated again, not served from the cache."""
    args = simulate_args(example, resolution, spots, options)
    key = [*args, f"scene={scene_fingerprint(example)}"]
    out = ctx.data_dir / f"{example}-{int(resolution)}-{_key(key)}"
    problem = cache_problem(out, key)
    if problem is not None:
        ctx.log(f"  simulating {' '.join(args)} -> {out.name} ({problem})")
        run = ctx.run_cli(simulate_cli(example, resolution, spots, options, out))
        _stamp(out, key, {"simulate_wall_s": run.wall_s, "simulate_cpu_s": run.cpu_s,
                           "simulate_peak_rss_mb": run.peak_rss_mb})
    return out


def scene_fingerprint(example: str) -> str:
    from torch_recon.contract.scenes import EXAMPLES
    return EXAMPLES[example]().fingerprint() if example in EXAMPLES else "not-built-in"


def integrated_dataset(ctx, src: Path, factor: int) -> Path:
    """A cached copy of dataset `src` whose bins are sums of `factor` adjacent bins (the paper's temporal
    resolution ablation), next to `src`."""
    if factor == 1:
        return src
    key = [json.loads((src / CACHE_STAMP).read_text())["files"], "integrate_bins", factor]
    out = src.parent / f"{src.name}-x{factor}"
    if cache_problem(out, key) is not None:
        ctx.log(f"  summing {factor} adjacent bins of {src.name} -> {out.name}")
        integrate_bins(src, out, factor)
        _stamp(out, key, {})
    return out


def _key(args) -> str:
    return hashlib.sha256(json.dumps(args).encode()).hexdigest()[:10]


def _file_sizes(root: Path) -> dict:
    return {str(p.relative_to(root)): p.stat().st_size for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != CACHE_STAMP}


def _stamp(out: Path, args, extra: dict) -> None:
    stamp = {"args": args, **extra, "files": _file_sizes(out)}
    (out / CACHE_STAMP).write_text(json.dumps(stamp, indent=1))


def cache_problem(out: Path, args) -> str | None:
    """Why a cached dataset cannot be reused (None: it can): no stamp, other settings, files missing or
    changed in size since it was written (e.g. truncated), or the dataset does not open."""
    stamp = out / CACHE_STAMP
    if not stamp.is_file():
        return "not cached"
    try:
        recorded = json.loads(stamp.read_text())
    except (OSError, json.JSONDecodeError):
        return "unreadable cache stamp"
    if recorded.get("args") != args:
        return "cached with other settings"
    if _file_sizes(out) != recorded.get("files"):
        return "cached files changed or missing"
    try:
        from torch_recon.contract.dataset import load_dataset
        load_dataset(out)
    except Exception as exc:      # noqa: BLE001 - any failure to open means: make it again
        return f"cached dataset invalid: {exc}"
    return None


def integrate_bins(src, dst, factor: int) -> Path:
    """A new dataset at `dst` whose bins are sums of `factor` adjacent bins of `src` (128 ps -> factor x
    128 ps). Windows are re-aligned to the coarse bins; the pulse width is kept (the laser did not
    change) and the bin width grows by `factor`; ground truth is carried over."""
    from torch_recon.contract.dataset import DatasetWriter, Transient, TransientLayout, load_dataset
    ds = load_dataset(src)
    man = ds.manifest
    s = man.sensor
    if factor < 1 or s.bins < factor:
        raise ValueError(f"factor: expected 1..{s.bins}, got {factor}")
    t_new = s.bins // factor
    sensor = replace(s, bins=t_new, bin_width_ps=s.bin_width_ps * factor, bin_width_m=s.bin_width_m * factor)
    spots, g_new = [], None
    with DatasetWriter(dst) as w:
        for sp in man.spots:
            dense = ds.read_transient(sp.id).dense()[:, :, :t_new * factor]
            coarse = dense.reshape(s.height, s.width, t_new, factor).sum(-1, dtype=np.float64).astype(np.float32)
            tr = Transient.from_dense(coarse, t_new)
            g_new = tr.window_bins
            spots.append(replace(sp, transient_file=w.write_transient(sp.id, tr, man.layout.sample_type),
                                 content_hash=None))
        gt = man.ground_truth
        for rel in filter(None, (gt.train_depth_file, gt.mesh_file, gt.test_views.depth_file if gt.test_views else None,
                                 *(o.mesh_file for o in gt.objects))):     # the labelled objects' meshes too
            w.reuse_file(ds.path(rel), rel)
        layout = TransientLayout("dense" if g_new == t_new else "windowed", g_new, man.layout.sample_type)
        w.commit(replace(man, sensor=sensor, spots=spots, layout=layout))
    return Path(dst)
