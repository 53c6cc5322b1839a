"""Simulator fidelity against mitransient (an independent path tracer), per spot and pooled, optional.

Listed only where mitransient is installed. The fidelity suite's run and metrics
(benchmarks/suites/fidelity.py, reference='mitransient'); the reference renderer is
benchmarks/mitransient_reference.py. Per spot: `reference_seeds` renders of `reference_spp`
jittered samples per pixel; the reference is their mean, and seed 0 against seed 1
(at reference_spp each) measures the reference's own noise in the same metrics (ref_self_*). The
histogram peak is ill-posed where a pixel's path spreads over several bins (a plateau: noise picks
the peak), so mean_bin_within_half (energy-weighted mean bin within +-0.5 bin) is given beside it.
Where the simulator and the reference differ: misses of the +-1-bin test whose reference histogram
spreads over more than 3 bins (sqrt(12) x its bin standard deviation: grazing views) or that sit
next to a reference-dark pixel (shadow edge or silhouette), and the footprint coverage of the
shadow-mask disagreements (a pixel's energy / the brightest of its 3 x 3 neighbourhood in the cube
that lights it).
"""

from __future__ import annotations

import numpy as np

from benchmarks.mitransient_reference import installed
from benchmarks.suites import fidelity

SPREAD_BINS = 3.0


def reference_spots(s, sensor, spots, ctx) -> list[dict]:
    """Per spot: the mean mitransient cube, its noise check, render time and laser geometry."""
    from benchmarks.mitransient_reference import MitransientRenderer
    from torch_recon.contract import scenes

    ex = scenes.example(s.example)
    mesh, _ = ex.trimesh()
    renderer = MitransientRenderer(ex.parts, sensor, ctx.work_dir / "mitransient_parts")
    origin = np.asarray(sensor.laser_origin, np.float64)
    out = []
    for spot, cube in spots:
        d = np.asarray(spot.laser_direction, np.float64)
        with ctx.timed() as t:
            renders = [renderer.render(origin + d, s.reference_spp, seed=k) for k in range(s.reference_seeds)]
        hits, _, tris = mesh.ray.intersects_location(origin[None], d[None], multiple_hits=False)
        cos_in = abs(float(np.dot(mesh.face_normals[tris[0]], d)))
        fb = np.unravel_index(np.argmax(cube.sum(-1)), cube.shape[:2])   # the simulated first-bounce pixel
        noise = fidelity.compare(renders[1], renders[0], fb) if len(renders) > 1 else None
        out.append({"cube": np.mean(renders, axis=0), "wall_s": t.wall_s, "cpu_s": t.cpu_s, "noise": noise,
                    "distance_m": float(np.linalg.norm(hits[0] - origin)), "cos_in": cos_in,
                    "spp": s.reference_spp * s.reference_seeds})
        ctx.log(f"  mitransient spot {spot.id}: {s.reference_seeds} x {s.reference_spp} spp, {t.wall_s:.1f} s wall "
                f"{t.cpu_s:.1f} s CPU" + (f"; seed 0 vs 1: within +-1 bin {100 * noise['within_1_bin']:.2f} %, "
                                          f"IoU {noise['shadow_iou']:.4f}" if noise else ""))
    return out


def compare_to_mitransient(cube: np.ndarray, ref: dict) -> tuple[dict, dict]:
    """fidelity.compare after one factor per spot (energies summed over the pixels both light), and the
    extra row fields: the factor, the laser constant, the reference's noise check and where they differ."""
    e = cube.sum(-1, dtype=np.float64)
    fb = np.unravel_index(np.argmax(e), e.shape)
    e_ref = ref["cube"].sum(-1)
    both = (e > 0) & (e_ref > 0)
    both[fb] = False
    scale = float(e[both].sum() / e_ref[both].sum())
    rc = ref["cube"] * scale
    m = fidelity.compare(cube, rc, fb)
    extra = {"reference_spp": ref["spp"], "reference_wall_s": round(ref["wall_s"], 2),
             "reference_cpu_s": round(ref["cpu_s"], 2),
             "scale": scale, "laser_constant": scale * ref["cos_in"] / ref["distance_m"] ** 2,
             **({"ref_self_within_1_bin": ref["noise"]["within_1_bin"], "ref_self_iou": ref["noise"]["shadow_iou"]}
                if ref["noise"] else {}),
             **where_they_differ(cube, rc, m)}
    return m, extra


def where_they_differ(cube, ref, m) -> dict:
    from scipy import ndimage

    bins = np.arange(ref.shape[-1], dtype=np.float64)
    e_ref = np.maximum(ref.sum(-1), 1e-300)
    mean = (ref * bins).sum(-1) / e_ref
    spread = np.sqrt(12.0 * np.maximum((ref * bins ** 2).sum(-1) / e_ref - mean ** 2, 0.0))
    e_sim = np.maximum(cube.sum(-1, dtype=np.float64), 1e-300)
    mean_sim = (cube * bins).sum(-1) / e_sim
    miss = m["lit"] & ~m["peak_ok"]
    by_dark = ndimage.minimum_filter(m["mask_ref"], size=3, mode="nearest") == 0
    e, er = cube.sum(-1, dtype=np.float64), ref.sum(-1, dtype=np.float64)
    coverage = np.where(m["mask"], e / np.maximum(ndimage.maximum_filter(e, 3), 1e-300),
                        er / np.maximum(ndimage.maximum_filter(er, 3), 1e-300))
    differ = m["mask"] ^ m["mask_ref"]
    n = max(int(miss.sum()), 1)
    return {"mean_bin_within_half": float((np.abs(mean_sim - mean)[m["lit"]] < 0.5).mean()),
            "misses": int(miss.sum()), "misses_wide_spread": float((spread[miss] > SPREAD_BINS).sum() / n),
            "misses_by_dark": float(by_dark[miss].sum() / n),
            "lit_wide_spread": float((spread[m["lit"]] > SPREAD_BINS).mean()),
            "mask_differ_coverage_p50": float(np.median(coverage[differ])) if differ.any() else float("nan"),
            "mask_differ_coverage_p90": float(np.percentile(coverage[differ], 90)) if differ.any() else float("nan")}


def readme(results) -> str:
    """Per spot and pooled: the issue's metrics, where they differ, the reference's own noise, both times."""
    lines = ["| scene | sampling | spot | within +-1 bin | mean bin within +-0.5 | shadow IoU | "
             "energy ratio p1 / p50 / p99 | "
             "misses (wide spread / by dark) | mask-differ coverage p50 | reference seed 0 vs 1 (+-1 bin / IoU) | "
             "laser constant | simulate wall s | mitransient wall s (spp) |", "|---" * 13 + "|"]
    rows = results["rows"]
    for r in rows:
        per = [q for q in rows if (q["method"], q["scene"]) == (r["method"], r["scene"]) and q["spot"] != "pooled"]
        if r["spot"] == "pooled":
            w = [q["lit_pixels"] for q in per]
            mean_bin = np.average([q["mean_bin_within_half"] for q in per], weights=w)
            self_bin = np.average([q.get("ref_self_within_1_bin", np.nan) for q in per], weights=w)
            extra = (f"{sum(q['misses'] for q in per)}", "", f"{100 * self_bin:.2f} % / "
                     f"{np.mean([q.get('ref_self_iou', np.nan) for q in per]):.4f}", "",
                     f"{r['wall_s']:.1f}", f"{sum(q['reference_wall_s'] for q in per):.1f}")
        else:
            mean_bin = r["mean_bin_within_half"]
            extra = (f"{r['misses']} ({100 * r['misses_wide_spread']:.0f} % / {100 * r['misses_by_dark']:.0f} %)",
                     f"{r['mask_differ_coverage_p50']:.3f}",
                     f"{100 * r.get('ref_self_within_1_bin', np.nan):.2f} % / {r.get('ref_self_iou', np.nan):.4f}",
                     f"{r['laser_constant']:.4g}", f"{r['wall_s']:.1f}",
                     f"{r['reference_wall_s']:.1f} ({r['reference_spp']})")
        lines.append(f"| {r['scene']} | {r['method']} | {r['spot']} | {100 * r['within_1_bin']:.2f} % | "
                     f"{100 * mean_bin:.2f} % | "
                     f"{r['shadow_iou']:.4f} | {r['energy_ratio_p1']:.3f} / {r['energy_ratio_p50']:.3f} / "
                     f"{r['energy_ratio_p99']:.3f} | " + " | ".join(extra) + " |")
    return "\n".join(lines)


#: listed only where mitransient is installed (elsewhere `run fidelity --set reference=mitransient` says how)
SUITES = [fidelity.FidelitySuite(
    "fidelity_mitransient", __doc__.splitlines()[0], run=fidelity.run, plot=fidelity.plot, readme=readme,
    row_id=("method", "scene", "spot"),
    quick=fidelity.Settings(resolution=64, spots=2, samplings=("default",), reference="mitransient",
                            reference_spp=1024),        # fewer spp: the peak test measures the noise
    full=fidelity.Settings(spots=4, samplings=("default",), reference="mitransient"))] if installed() else []
