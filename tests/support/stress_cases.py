"""The numerical stress cases (tests/support/stress_fixtures.py says how they are judged).

Simulator cases are named in tests/support/stress_sim_worker.py (SIM_CASES); here each gets an expectation
and a post-check run on the dataset it produced. Data cases build small analytic datasets
(torch_recon.contract.analytic, a 0.6 m box in the paper's room, 16 x 16 pixels) and run preprocessing,
a short fast-mode fit, the mesh export and the evaluation on them.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

REPO_ROOT = Path(__file__).resolve().parents[2]

from tests.support.stress_checks import (CheckFailed, NonFinite, check_dataset, fit_checked, preprocess_checked,
                           reference_shadow_agreement, smooth_sweep, transient_bytes_equal)

PHOTON_LEVELS = (1, 3, 10, 30, 100, 1000, 10000)
# Shadow-mask agreement with the analytic render on 16 x 16 Cycles data, at most this far below what the
# exact footprint-integrated transients (analytic, 16 x 16 samples per pixel) score through the same
# preprocessing. A pixel there spans ~0.25 m of wall at 2 m, its return spreads over many bins and the
# matched-filter confidence of lit pixels falls under the 0.15 threshold: perfect data scores 0.36 on
# the 16 x 16 cave (0.80 with 2 x 2 samples per pixel, which under-sample the footprint).
SIM_SHADOW_AGREEMENT_MARGIN = 0.05

#: cases that fail because of a known bug -> reason (reported; the tests mark them xfail, strict,
#: so a fix makes the test fail until the entry is removed). Found and since fixed: sim-all-shadow (photon scale
#: zeroed the first-bounce return when no two-bounce light existed), sim-grazing-spot (window bound too small).
KNOWN_ISSUES: dict = {}


# ---------------------------------------------------------------- synthetic datasets

def synth(path, size=16, photons=None, seed=0, sample_type="float32", pulse_shape="gaussian", bins=300,
          spots=4, scene="box", only_first_bounce=False, scale_counts=1.0, test_views=2, clip=None):
    """An analytic dataset (noise-free, or Poisson with `photons` for the brightest two-bounce pixel)."""
    from torch_recon.contract import synthetic as sy
    from torch_recon.contract.analytic import range_image, render_two_bounce
    from torch_recon.contract.dataset import (DatasetWriter, GroundTruth, GroundTruthViews, Manifest, NoiseSpec, Provenance,
                                     Spot, Transient, TransientLayout)
    from torch_recon.contract.frames import paper_test_view_cameras
    mesh = {"box": sy.box_room_scene, "empty": lambda: sy.concat(sy.room_mesh())}[scene]()
    sensor = sy.default_sensor(size, size, bins=bins, pulse_shape=pulse_shape)
    dirs = sy.paper_laser_directions()[:spots]
    cubes, parts = render_two_bounce(mesh, sensor, dirs, return_parts=True)
    two = render_two_bounce(mesh, sensor, dirs, include_first_bounce=False)
    if only_first_bounce:
        cubes = cubes - two
    noise = NoiseSpec(seed=seed)
    if photons is not None:
        scale = photons / max(float(two.sum(-1).max()), 1e-30)
        cubes = np.random.default_rng(seed).poisson(cubes * scale).astype(np.float32)
        noise = NoiseSpec(photon_counts=True, photons_per_pixel=float(photons), seed=seed)
    cubes = (cubes * scale_counts).astype(np.float32)
    if clip is not None:   # a saturating detector: counts flatten at `clip`
        cubes = np.minimum(cubes, clip)
    with DatasetWriter(path) as w:
        spot_list = []
        for k, (ld, sp) in enumerate(zip(dirs, parts["spots"])):
            spot_list.append(Spot(id=k, laser_direction=list(map(float, ld)),
                                  transient_file=w.write_transient(k, Transient.from_dense(cubes[k], bins), sample_type),
                                  first_bounce=None if sp.first_bounce is None else list(map(float, sp.first_bounce))))
        mesh.export(w.path("ground_truth/mesh.ply"))
        train = range_image(mesh, sensor.camera_to_world, size, size, sensor.fov_rad, "x")
        gt = GroundTruth(train_depth_file=w.write_depth("ground_truth/train_depth.exr", train),
                         mesh_file="ground_truth/mesh.ply")
        if test_views:
            cams = paper_test_view_cameras(dolly_count=1, orbit_count=test_views - 1)
            d = np.stack([range_image(mesh, c, 16, 16, sensor.fov_rad, "x") for c in cams])
            gt.test_views = GroundTruthViews(width=16, height=16, fov_rad=sensor.fov_rad, fov_axis="x",
                                             camera_to_world=[c.tolist() for c in cams],
                                             depth_file=w.write_depth("ground_truth/test_depth.exr", d))
        w.commit(Manifest(sensor=sensor, spots=spot_list, layout=TransientLayout("dense", bins, sample_type),
                          noise=noise, ground_truth=gt,
                          provenance=Provenance(generator="tests/support/stress_cases.py", generator_version="1",
                                                seed=seed, scene=scene)))
    return Path(path)


def pipeline(path, work: Path, fit=True, **prep) -> dict:
    """Dataset -> checks -> preprocessing -> (fit, mesh, evaluation); metrics of every stage."""
    metrics = check_dataset(path)
    ds, meas, m = preprocess_checked(path, **prep)
    metrics.update(m)
    if fit:
        metrics.update(fit_checked(meas, work / "fit", dataset=ds))
    return metrics


# ---------------------------------------------------------------- data cases

def case_float16(work):
    a = pipeline(synth(work / "f32", photons=1000), work / "a", fit=False)
    b = pipeline(synth(work / "f16", photons=1000, sample_type="float16"), work / "b")
    diff = abs(a["depth_median_err_m"] - b["depth_median_err_m"])
    if b["sample_type"] != "float16" or diff > 0.01:
        raise CheckFailed(f"float16 visible-depth error differs by {diff:.4f} m from float32", b)
    return {**b, "float32_depth_median_err_m": a["depth_median_err_m"]}


def case_float16_overflow(work):
    synth(work / "ds", scale_counts=1e6, sample_type="float16")   # expected radiance x 1e6 > 65504


def case_photon_sweep(work):
    """Visible-depth error against photons per pixel: smooth (no jump), falling as photons grow."""
    rows, errs = [], []
    for p in PHOTON_LEVELS:
        try:
            m = pipeline(synth(work / f"p{p}", photons=p, seed=3), work / f"p{p}", fit=False)
        except ValueError as exc:      # too few photons to find a first bounce: a refusal, not a crash
            rows.append({"photons": p, "refused": str(exc)})
            errs.append(None)
            continue
        rows.append({"photons": p, **{k: m[k] for k in ("depth_median_err_m", "depth_p95_err_m", "depth_coverage",
                                                       "signal_fraction")}})
        errs.append(m["depth_median_err_m"])
    bad = smooth_sweep(PHOTON_LEVELS, errs)
    if sum(e is not None for e in errs) < 4:
        bad.append("fewer than 4 photon levels could be processed")
    if bad:
        raise CheckFailed("; ".join(bad), {"sweep": rows})
    return {"sweep": rows}


def case_same_seed(work):
    """Same seed: identical Poisson transients, measurements and fitted volume."""
    import torch_recon.recon as rc
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import preprocess_dataset
    from tests.support.stress_checks import small_fit_config
    a, b = synth(work / "a", photons=30, seed=5), synth(work / "b", photons=30, seed=5)
    c = synth(work / "c", photons=30, seed=6)
    if not transient_bytes_equal(a, b):
        raise CheckFailed("same seed, different transient bytes")
    if transient_bytes_equal(a, c):
        raise CheckFailed("different seeds gave identical transients (seed ignored?)")
    ma, mb = (preprocess_dataset(load_dataset(p)) for p in (a, b))
    same_meas = all(np.array_equal(x.path_length, y.path_length, equal_nan=True) and np.array_equal(x.signal, y.signal)
                    for x, y in zip(ma.spots, mb.spots))
    va, vb = (rc.fit(m, config=small_fit_config(6), export=False).volume for m in (ma, mb))
    if not same_meas or not np.array_equal(va, vb):
        raise CheckFailed(f"same seed: measurements equal {same_meas}, volumes equal {np.array_equal(va, vb)}")
    return {"identical": True}


def case_end_to_end(work):
    return pipeline(synth(work / "ds", photons=500), work)


def case_no_shadows(work):
    """Empty convex room: no occlusion; pixels on the wall of the spot still get no two-bounce light."""
    m = pipeline(synth(work / "ds", scene="empty"), work)
    if m["shadow_agreement"] < 0.9:
        raise CheckFailed(f"shadow mask agrees with the analytic one on {m['shadow_agreement']:.1%} of pixels", m)
    return m


def case_all_shadow(work):
    m = pipeline(synth(work / "ds", only_first_bounce=True), work, fit=False)
    if m["signal_fraction"] > 0.01:
        raise CheckFailed(f"first bounce only, yet {m['signal_fraction']:.1%} of pixels have a two-bounce signal", m)
    from torch_recon.contract.dataset import load_dataset
    from torch_recon.preprocess import preprocess_dataset
    m.update(fit_checked(preprocess_dataset(load_dataset(work / "ds")), work / "fit"))   # ok or a clear refusal
    return m


def case_saturating(work):
    return pipeline(synth(work / "ds", photons=1e7, clip=2000.0), work, fit=False)


def case_box_pulse(work):
    m = pipeline(synth(work / "ds", pulse_shape="box", photons=300), work, fit=False)
    if m["depth_median_err_m"] is None or m["depth_median_err_m"] > 0.05:
        raise CheckFailed(f"single-bin pulse: visible-depth median error {m['depth_median_err_m']} m", m)
    return m


def case_mesh_degenerate(work):
    """Empty and full volumes: an empty mesh or a clear MeshExportError, never NaN vertices."""
    from torch_recon.mesh_export import MeshExportError, export_mesh
    out = {}
    for name, vol in (("empty", np.zeros((8, 8, 8))), ("full", np.ones((8, 8, 8)))):
        try:
            r = export_mesh(vol, (0, 0, 0), (1, 1, 1), 0.5, work / f"{name}.ply")
            if not np.isfinite(r.mesh.vertices).all():
                raise NonFinite(f"{name} volume: mesh vertices NaN/inf")
            out[name] = f"{r.n_faces} faces"
        except MeshExportError as exc:
            out[name] = f"refused: {exc}"
    return out


def case_mesh_nan(work):
    from torch_recon.mesh_export import export_mesh
    vol = np.zeros((8, 8, 8))
    vol[2:5, 2:5, 2:5] = 1.0
    vol[3, 3, 3] = np.nan
    export_mesh(vol, (0, 0, 0), (1, 1, 1), 0.5, work / "nan.ply")


# ---------------------------------------------------------------- invalid inputs

def _broken(work, how):
    """A valid small dataset, then broken in one way; returns its path."""
    from torch_recon.contract.dataset.store import write_transient_file
    from torch_recon.contract.dataset import Transient
    p = synth(work / "ds", size=8, bins=200, spots=2, test_views=0)
    f = p / "transients" / "spot_0000.exr"
    if how == "nan":
        win = np.ones((8, 8, 200), np.float32)
        win[3, 3, 7] = np.nan
        write_transient_file(f, Transient(np.zeros((8, 8), np.int64), win, 200))
    elif how == "truncated":
        f.write_bytes(f.read_bytes()[: f.stat().st_size // 3])
    elif how == "wrong-shape":
        write_transient_file(f, Transient(np.zeros((4, 8), np.int64), np.ones((4, 8, 200), np.float32), 200))
    elif how == "bins-mismatch":
        man = json.loads((p / "dataset.json").read_text())
        man["sensor"]["bins"] = 150
        (p / "dataset.json").write_text(json.dumps(man))
    elif how == "bad-json":
        (p / "dataset.json").write_text('{"sensor": ')
    return p


def _invalid_case(how):
    def fn(work):
        from torch_recon.contract.dataset import load_dataset
        from torch_recon.preprocess import preprocess_dataset
        preprocess_dataset(load_dataset(_broken(work, how)))
    return fn


def _cli(args, work):
    """Run `python -m torch_recon ARGS`; a refusal is exit 2 with one line and no traceback."""
    proc = subprocess.run([sys.executable, "-m", "torch_recon", *map(str, args)], capture_output=True, text=True,
                          cwd=REPO_ROOT)
    err = proc.stderr.strip()
    lines = [ln for ln in err.splitlines() if ln.strip() and "%|" not in ln]   # progress bars are not messages
    if "Traceback" in err:
        raise RuntimeError(f"traceback from the CLI (exit {proc.returncode}):\n{err[-1500:]}")
    if proc.returncode == 2:
        if len(lines) != 1:
            raise RuntimeError(f"exit 2 with {len(lines)} lines of message:\n{err[-800:]}")
        raise ValueError(lines[0])
    if proc.returncode != 0:
        raise RuntimeError(f"exit {proc.returncode}: {err[-800:]}")
    return {"stdout_tail": proc.stdout.strip()[-200:]}


def _cli_invalid(how):
    def fn(work):
        return _cli(["preprocess", _broken(work, how), "--out", work / "m.npz"], work)
    return fn


def _sim_cli(args, work):
    proc = subprocess.run([sys.executable, str(REPO_ROOT / "pipeline" / "simulate.py"), *args, "--out",
                           str(work / "ds")], capture_output=True, text=True, cwd=REPO_ROOT)
    err = proc.stderr.strip()
    if "Traceback" in err:
        raise RuntimeError(f"traceback from simulate.py (exit {proc.returncode}):\n{err[-1500:]}")
    if proc.returncode == 2:
        msgs = [ln for ln in err.splitlines() if ln.startswith(("simulate: error", "usage:", "simulate.py: error"))]
        raise ValueError(msgs[-1] if msgs else err.splitlines()[-1])
    if proc.returncode:
        raise RuntimeError(f"exit {proc.returncode}: {err[-800:]}")
    if (work / "ds").exists():
        return {"note": "simulated"}


# ---------------------------------------------------------------- post-checks of simulator cases

def post_pipeline(fit=False, max_rel_err=None, max_shadow_shortfall=None):
    """max_shadow_shortfall: how far the shadow agreement may fall below the exact data's (reference_shadow_agreement)."""
    def fn(ds_path, work):
        m = pipeline(ds_path, work / Path(ds_path).name, fit=fit)
        rel = m.get("depth_median_rel_err")
        if max_rel_err is not None and (rel is None or rel > max_rel_err):
            raise CheckFailed(f"visible-depth median relative error {rel} > {max_rel_err}", m)
        if max_shadow_shortfall is None:
            return m
        from torch_recon.contract.dataset import load_dataset
        from torch_recon.preprocess import PreprocessSettings
        agree = m.get("shadow_agreement")
        ref = m["shadow_agreement_reference"] = reference_shadow_agreement(load_dataset(ds_path), PreprocessSettings())
        if agree is None or agree < ref - max_shadow_shortfall:
            raise CheckFailed(f"shadow mask agrees with the analytic one on {agree}, more than "
                              f"{max_shadow_shortfall} below exact footprint-integrated data's {ref}", m)
        return m
    return fn


def post_dataset_only(ds_path, work):
    return check_dataset(ds_path)


def post_all_shadow(ds_path, work):
    m = check_dataset(ds_path)
    _, meas, mm = preprocess_checked(ds_path)
    m.update(mm)
    if m["signal_fraction"] > 0.02:
        raise CheckFailed(f"all-shadow scene: {m['signal_fraction']:.1%} of pixels report a two-bounce signal", m)
    return m


def post_same_seed(ds_path, work):
    other = Path(ds_path).parent / "sim-photons-3-seed7"
    if not other.exists():
        raise CheckFailed("the first run of the same-seed pair is missing (run both cases together)")
    if not transient_bytes_equal(ds_path, other):
        raise CheckFailed("same seed, different transient bytes")
    return {"identical": True, **check_dataset(ds_path)}


def all_cases(Case):
    C = Case
    rel = 0.03   # visible depth within 3 % of the range (16 x 16 pixels, 4 spots)
    return [
        # simulator (one worker)
        C("sim-room-0.1m", "sim", "ok", True, post_pipeline(max_rel_err=rel, max_shadow_shortfall=SIM_SHADOW_AGREEMENT_MARGIN), note="room 0.1 m, 3.2 ps bins"),
        C("sim-room-1m", "sim", "ok", False, post_pipeline(max_rel_err=rel)),
        C("sim-room-4m", "sim", "ok", False, post_pipeline(fit=True, max_rel_err=rel), note="paper scale"),
        C("sim-room-10m", "sim", "ok", False, post_pipeline(max_rel_err=rel)),
        C("sim-room-100m", "sim", "ok", True, post_pipeline(max_rel_err=rel), note="room 100 m, 3.2 ns bins"),
        C("sim-range-too-short", "sim", "refuse", True, must_mention=("bins",), note="100 m room, 15 m of bins"),
        C("sim-grazing-spot", "sim", "ok", False, post_pipeline(), note="~84 deg incidence"),
        C("sim-laser-offset-1mm", "sim", "ok", False, post_pipeline(max_rel_err=rel)),
        C("sim-surface-at-sensor", "sim", "any", False, post_pipeline()),
        C("sim-sensor-inside-box", "sim", "any", False, post_dataset_only),
        C("sim-no-shadows", "sim", "ok", False, post_pipeline(max_rel_err=rel, max_shadow_shortfall=SIM_SHADOW_AGREEMENT_MARGIN)),
        C("sim-all-shadow", "sim", "ok", True, post_all_shadow, note="default photon budget"),
        C("sim-all-shadow-radiance", "sim", "ok", False, post_all_shadow, note="radiance units (photons 0)"),
        C("sim-photons-1", "sim", "any", False, post_pipeline()),
        C("sim-photons-10", "sim", "ok", False, post_pipeline()),
        C("sim-photons-3-seed7", "sim", "any", False, post_dataset_only),
        C("sim-photons-3-seed7-again", "sim", "any", False, post_same_seed),
        C("sim-saturating", "sim", "ok", False, post_pipeline()),
        C("sim-box-pulse", "sim", "ok", True, post_pipeline(max_rel_err=rel), note="single-bin pulse"),
        C("sim-ambient-gated", "sim", "ok", False, post_pipeline()),
        C("sim-zero-spots-hit", "sim", "refuse", False, must_mention=("behind",)),
        C("sim-cli-zero-bins", "cli", "refuse", True, lambda w: _sim_cli(["--example", "cave-chair", "--bins", "0"], w),
          must_mention=("bins",)),
        C("sim-cli-unreadable-blend", "cli", "refuse", False,
          lambda w: (w.mkdir(parents=True, exist_ok=True), (w / "x.blend").write_text("not a blend"),
                     _sim_cli([str(w / "x.blend")], w))[-1], must_mention=("x.blend",)),
        C("sim-cli-unknown-option", "cli", "refuse", False, lambda w: _sim_cli(["--example", "cave-chair", "--warp"], w)),
        # preprocessing / reconstruction on analytic data
        C("data-end-to-end", "data", "ok", True, case_end_to_end, note="preprocess + fit + mesh + evaluate"),
        C("data-float16", "data", "ok", True, case_float16),
        C("data-float16-overflow", "data", "refuse", True, case_float16_overflow, must_mention=("float16",)),
        C("data-photon-sweep", "data", "ok", True, case_photon_sweep, note=f"photons {PHOTON_LEVELS}"),
        C("data-same-seed", "data", "ok", True, case_same_seed),
        C("data-no-shadows", "data", "ok", False, case_no_shadows),
        C("data-all-shadow", "data", "any", True, case_all_shadow),
        C("data-saturating", "data", "ok", False, case_saturating),
        C("data-box-pulse", "data", "ok", True, case_box_pulse),
        C("mesh-degenerate-volumes", "data", "ok", True, case_mesh_degenerate),
        C("mesh-nan-volume", "data", "refuse", True, case_mesh_nan, must_mention=("nan",)),
        # invalid inputs
        C("invalid-nan-transient", "data", "refuse", True, _invalid_case("nan"), must_mention=("spot_0000.exr", "nan")),
        C("invalid-truncated-exr", "data", "refuse", True, _invalid_case("truncated"), must_mention=("spot_0000.exr",)),
        C("invalid-wrong-shape", "data", "refuse", True, _invalid_case("wrong-shape"), must_mention=("8x8",)),
        C("invalid-bins-mismatch", "data", "refuse", False, _invalid_case("bins-mismatch"), must_mention=("bins",)),
        C("invalid-bad-json", "data", "refuse", True, _invalid_case("bad-json"), must_mention=("dataset.json",)),
        C("cli-preprocess-nan", "cli", "refuse", True, _cli_invalid("nan"), must_mention=("spot_0000.exr",)),
        C("cli-preprocess-truncated", "cli", "refuse", False, _cli_invalid("truncated"), must_mention=("spot_0000.exr",)),
        C("cli-preprocess-missing", "cli", "refuse", False,
          lambda w: _cli(["preprocess", w / "nothing", "--out", w / "m.npz"], w), must_mention=("nothing",)),
    ]
