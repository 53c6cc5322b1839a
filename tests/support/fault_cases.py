"""The fault table: bad inputs and faults at every entry point, what each must answer, what it must leave.

A case runs one command the way a person would and asserts
- the exit code: 2 for bad input (or a size that cannot fit), 130 for an interrupted run, 0 where the
  command can and must do its job;
- the message: exactly one line (no traceback) containing every keyword of `says` (the file,
  field or setting, case-insensitive);
- the files left behind: by default nothing in the case's workspace changed (no file lost, none
  modified, none added, no staging leftovers); `after(ws)` replaces that check where the command
  is expected to write.

`run(ws)` returns the command: ('recon', argv) in-process `python -m torch_recon`, ('sim', argv) a
`pipeline/simulate.py` process, ('call', fn) any callable returning (rc, stderr) (signals, add-on
operators). `prepare(ws, monkeypatch)` breaks an input or injects a fault first. slow: needs renders
or a real training run (pytest -m slow).
"""

from __future__ import annotations

import errno
import sys

import numpy as np

from tests.support.fault_inputs import (DELETE, DS, MESH, NPZ, Case, R, S, W, both, break_transient, edit_manifest,
                                        export_ours, fail_writes, npz_edit, npz_of, read_rgb, set_key, truncate,
                                        write_file, write_image)
from tests.support.fault_runs import (SIM_SMALL, addon_op, after_evaluate_twice, after_reuse_truncated,
                                      after_signal_simulate, after_sim_user_files, both_setup, evaluate_twice,
                                      file_op, fit_other_dataset, fit_unchanged_but_checkpoint,
                                      killed_during_mesh_export, old_or_new_fit, set_props, signal_fit,
                                      signal_simulate, simulate_into_dataset_with_user_files,
                                      simulate_reuse_truncated, with_prefs)
from tests.support.fault_workspace import FIT_FAST, ROOT, SIGINT, SIGTERM

# ------------------------------------------------------------------------------------------ the table

CASES = [
    # --- preprocess: the dataset and the settings
    Case("pre-missing-dataset", R("preprocess", W("nothing"), "--out", W("m.npz")), says=("nothing",)),
    Case("pre-empty-folder", R("preprocess", W("empty"), "--out", W("m.npz")), says=("dataset.json",),
         prepare=lambda ws, mp: ws.p("empty/").mkdir()),
    Case("pre-manifest-bad-json", R("preprocess", DS, "--out", W("m.npz")), says=("dataset.json", "json"),
         prepare=write_file("ds/dataset.json", '{"sensor": ')),
    Case("pre-manifest-no-sensor", R("preprocess", DS, "--out", W("m.npz")), says=("dataset.json", "sensor"),
         prepare=edit_manifest(set_key("sensor", DELETE))),
    Case("pre-manifest-bins-mismatch", R("preprocess", DS, "--out", W("m.npz")), says=("bins",),
         prepare=edit_manifest(set_key("sensor.bins", 150))),
    Case("pre-manifest-width-string", R("preprocess", DS, "--out", W("m.npz")), says=("sensor.width",),
         prepare=edit_manifest(set_key("sensor.width", "sixteen"))),
    Case("pre-manifest-1e12-pixels", R("preprocess", DS, "--out", W("m.npz")), says=("sensor", "pixels"),
         prepare=edit_manifest(lambda d: d["sensor"].update(width=1_000_000, height=1_000_000))),
    Case("pre-manifest-huge-bins", R("preprocess", DS, "--out", W("m.npz")), says=("sensor.bins",),
         prepare=edit_manifest(set_key("sensor.bins", 10 ** 12))),
    Case("pre-manifest-no-spots", R("preprocess", DS, "--out", W("m.npz")), says=("spots",),
         prepare=edit_manifest(set_key("spots", []))),
    Case("pre-transient-missing", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0001.exr", "missing"),
         prepare=lambda ws, mp: (ws.ds / "transients/spot_0001.exr").unlink()),
    Case("pre-transient-truncated", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr",),
         prepare=break_transient("truncated")),
    Case("pre-transient-garbage", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr",),
         prepare=break_transient("garbage")),
    Case("pre-transient-nan", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr", "nan"),
         prepare=break_transient("nan")),
    Case("pre-transient-wrong-shape", R("preprocess", DS, "--out", W("m.npz")), says=("spot_0000.exr", "16x16"),
         prepare=break_transient("shape")),
    Case("pre-gt-depth-missing", R("preprocess", DS, "--out", W("m.npz")), says=("train_depth.exr",),
         prepare=lambda ws, mp: (ws.ds / "ground_truth/train_depth.exr").unlink()),
    Case("pre-out-not-npz", R("preprocess", DS, "--out", W("m.txt")), says=("out", ".npz")),
    Case("pre-out-is-folder", R("preprocess", DS, "--out", W("dir.npz")), says=("dir.npz",),
         prepare=lambda ws, mp: ws.p("dir.npz/x").write_text("x")),
    Case("pre-device-unknown", R("preprocess", DS, "--out", W("m.npz"), "--device", "tpu"), says=("device", "tpu")),
    Case("pre-threads-zero", R("preprocess", DS, "--out", W("m.npz"), "--threads", "0"), says=("threads",)),
    Case("pre-shadow-threshold-range", R("preprocess", DS, "--out", W("m.npz"), "--shadow-threshold", "2"),
         says=("shadow_threshold",)),
    Case("pre-refine-unknown", R("preprocess", DS, "--out", W("m.npz"), "--refine", "cubic"), says=("refine", "cubic")),
    Case("pre-out-read-only", R("preprocess", DS, "--out", W("ro/m.npz")), says=("ro", "read-only"),
         prepare=fail_writes(errno.EROFS, "ro")),
    Case("pre-disk-full", R("preprocess", DS, "--out", W("full/m.npz")), says=("full", "no space left"),
         prepare=both(lambda ws, mp: ws.p("full/").mkdir(), fail_writes(errno.ENOSPC, "full"))),
    Case("pre-existing-npz-replaced-whole", R("preprocess", DS, "--out", NPZ), says=("spot_0000.exr",),
         prepare=break_transient("nan")),

    # --- fit: settings, measurements files, outputs, checkpoints, interrupts
    Case("fit-missing-source", R("fit", W("nothing"), "--out", W("out")), says=("nothing",)),
    Case("fit-steps-negative", R("fit", NPZ, "--out", W("out"), "--steps", "-3"), says=("steps",)),
    Case("fit-max-seconds-negative", R("fit", NPZ, "--out", W("out"), "--max-seconds", "-1"), says=("max_seconds",)),
    Case("fit-threads-zero", R("fit", NPZ, "--out", W("out"), "--threads", "0"), says=("threads",)),
    Case("fit-set-wrong-type", R("fit", NPZ, "--out", W("out"), "--set", "fast.resolution=abc"),
         says=("fast.resolution",)),
    Case("fit-set-float-for-int", R("fit", NPZ, "--out", W("out"), "--set", "fast.steps=2.5"), says=("fast.steps",)),
    Case("fit-set-unknown-key", R("fit", NPZ, "--out", W("out"), "--set", "fast.nosuch=1"), says=("nosuch",)),
    Case("fit-set-no-equals", R("fit", NPZ, "--out", W("out"), "--set", "seed"), says=("key=value",)),
    Case("fit-set-device-unknown", R("fit", NPZ, "--out", W("out"), "--set", "device=tpu"), says=("device", "tpu")),
    Case("fit-set-voxels-huge", R("fit", NPZ, "--out", W("out"), "--set", "fast.resolution=100000"),
         says=("fast.resolution", "need")),
    Case("fit-set-lr-negative", R("fit", NPZ, "--out", W("out"), "--set", "fast.lr=-1"), says=("fast.lr",)),
    Case("fit-config-missing", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("cfg.json",)),
    Case("fit-config-bad-json", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("cfg.json", "json"),
         prepare=write_file("cfg.json", "{seed: 1")),
    Case("fit-config-not-object", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")), says=("config",),
         prepare=write_file("cfg.json", "[1, 2]")),
    Case("fit-config-wrong-type", R("fit", NPZ, "--out", W("out"), "--config", W("cfg.json")),
         says=("threads",), prepare=write_file("cfg.json", '{"threads": "two"}')),
    Case("fit-npz-truncated", R("fit", NPZ, "--out", W("out")), says=("m.npz",), prepare=truncate(NPZ)),
    Case("fit-npz-garbage", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz",),
         prepare=write_file("odd.npz", "not a zip")),
    Case("fit-npz-foreign-arrays", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz",),
         prepare=npz_of(x=np.zeros(3))),
    Case("fit-npz-nan-camera", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz", "camera_to_world"),
         prepare=lambda ws, mp: npz_edit(ws, camera_to_world=np.full((4, 4), np.nan))),
    Case("fit-npz-huge-claim", R("fit", W("odd.npz"), "--out", W("out")), says=("odd.npz", "pixels"),
         prepare=lambda ws, mp: npz_edit(ws, meta_i=np.array([10 ** 6, 10 ** 6]))),
    Case("fit-out-is-file", R("fit", NPZ, "--out", W("out")), says=("out",), prepare=write_file("out", "x")),
    Case("fit-out-foreign-folder", R("fit", NPZ, "--out", W("photos"), *FIT_FAST), says=("photos", "not empty"),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("fit-checkpoint-other-data", fit_other_dataset, says=("checkpoint", "--no-resume")),
    Case("fit-out-read-only", R("fit", NPZ, "--out", W("ro/out"), *FIT_FAST), says=("ro", "read-only"),
         prepare=fail_writes(errno.EROFS, "ro")),
    Case("fit-killed-during-mesh-export", killed_during_mesh_export, rc=137, says=("killed",), after=old_or_new_fit,
         slow=True),
    Case("fit-sigint", signal_fit(SIGINT), rc=130, says=("interrupted",), after=fit_unchanged_but_checkpoint,
         slow=True),
    Case("fit-sigterm", signal_fit(SIGTERM), rc=130, says=("interrupted",), after=fit_unchanged_but_checkpoint,
         slow=True),

    # --- baseline
    Case("base-voxels-huge", R("baseline", DS, "--out", W("out"), "--voxels", "100000"), says=("voxels", "need")),
    Case("base-voxels-zero", R("baseline", DS, "--out", W("out"), "--voxels", "0"), says=("voxels",)),
    Case("base-occupancy-range", R("baseline", DS, "--out", W("out"), "--occupancy-threshold", "1.5"),
         says=("occupancy",)),
    Case("base-measurements-garbage", R("baseline", DS, "--out", W("out"), "--measurements", W("bad.npz")),
         says=("bad.npz",), prepare=write_file("bad.npz", "zzz")),
    Case("base-measurements-other-dataset", R("baseline", lambda ws: ws.ds_b, "--out", W("out"), "--measurements", NPZ),
         says=("m.npz", "dataset")),
    Case("base-grid-search-no-gt", R("baseline", lambda ws: ws.ds_nogt, "--out", W("out"), "--grid-search"),
         says=("test_views",)),
    Case("base-device-unknown", R("baseline", DS, "--out", W("out"), "--device", "gpu0"), says=("device", "gpu0")),
    Case("base-out-foreign-folder", R("baseline", DS, "--out", W("photos"), "--voxels", "16"), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),

    # --- evaluate
    Case("eval-no-ground-truth", R("evaluate", MESH, "--dataset", lambda ws: ws.ds_nogt, "--out", W("ev")),
         says=("ground truth",)),
    Case("eval-mesh-missing", R("evaluate", W("none.ply"), "--dataset", DS, "--out", W("ev")), says=("none.ply",)),
    Case("eval-mesh-garbage", R("evaluate", W("bad.ply"), "--dataset", DS, "--out", W("ev")), says=("bad.ply",),
         prepare=write_file("bad.ply", "ply\nformat nonsense\n")),
    Case("eval-mesh-empty", R("evaluate", W("empty.obj"), "--dataset", DS, "--out", W("ev")), says=("empty.obj",),
         prepare=write_file("empty.obj", "# nothing\n")),
    Case("eval-mesh-unknown-suffix", R("evaluate", W("mesh.xyz"), "--dataset", DS, "--out", W("ev")),
         says=("mesh.xyz",), prepare=write_file("mesh.xyz", "1 2 3\n")),
    Case("eval-gt-mesh-corrupt", R("evaluate", MESH, "--dataset", DS, "--out", W("ev")), says=("mesh.ply",),
         prepare=write_file("ds/ground_truth/mesh.ply", "garbage")),
    Case("eval-test-depth-truncated", R("evaluate", MESH, "--dataset", DS, "--out", W("ev")), says=("test_depth.exr",),
         prepare=truncate(lambda ws: ws.ds / "ground_truth/test_depth.exr", 0.3)),
    Case("eval-samples-zero", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--samples", "0"),
         says=("n_surface_samples",)),
    Case("eval-fscore-negative", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--fscore-threshold", "-1"),
         says=("fscore_threshold_m",)),
    Case("eval-object-settings-unknown-key", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--config",
                                               W("c.json")), says=("c.json", "object_metric_settings.nokey"),
         prepare=write_file("c.json", '{"object_metric_settings": {"nokey": 1}}')),
    Case("eval-object-threshold-negative", R("evaluate", MESH, "--dataset", DS, "--out", W("ev"), "--config",
                                             W("c.json")), says=("object_metric_settings.thresholds_m",),
         prepare=write_file("c.json", '{"object_metric_settings": {"thresholds_m": [-0.01]}}')),
    Case("eval-out-foreign-folder", R("evaluate", MESH, "--dataset", DS, "--out", W("photos")), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("eval-replaces-old-report-whole", evaluate_twice, rc=0, after=after_evaluate_twice),
    Case("eval-disk-full", R("evaluate", MESH, "--dataset", DS, "--out", W("full/ev"), "--samples", "500"),
         says=("no space left",), prepare=both(lambda ws, mp: ws.p("full/").mkdir(), fail_writes(errno.ENOSPC, "full"))),

    # --- convert
    Case("conv-from-missing", R("convert", "from-platonerf", W("nothing"), W("out")), says=("nothing",)),
    Case("conv-from-empty", R("convert", "from-platonerf", W("src"), W("out")), says=("transforms_train.json",),
         prepare=lambda ws, mp: ws.p("src/").mkdir()),
    Case("conv-from-bad-json", R("convert", "from-platonerf", W("src"), W("out")), says=("transforms_train.json",),
         prepare=write_file("src/transforms_train.json", "{")),
    Case("conv-from-bin-negative", R("convert", "from-platonerf", W("src"), W("out"), "--bin-ps", "-5"),
         says=("bin",), prepare=write_file("src/transforms_train.json", "{}")),
    # an export of ours records bins, pulse and window: a contradicting option is refused, not ignored
    Case("conv-ours-window-bins", R("convert", "from-platonerf", W("pn"), W("out"), "--window-bins", "4"),
         says=("--window-bins", "platolidar.layout.window_bins"), prepare=export_ours("pn")),
    Case("conv-ours-bin-ps", R("convert", "from-platonerf", W("pn"), W("out"), "--bin-ps", "64"),
         says=("--bin-ps", "bin_width_ps"), prepare=export_ours("pn")),
    Case("conv-ours-bin-m", R("convert", "from-platonerf", W("pn"), W("out"), "--bin-m", "0.02"),
         says=("--bin-m", "bin_width_m"), prepare=export_ours("pn")),
    Case("conv-ours-pulse-by-set", R("convert", "from-platonerf", W("pn"), W("out"), "--set", "pulse_fwhm_ps=50"),
         says=("--pulse-fwhm-ps", "pulse.fwhm_ps"), prepare=export_ours("pn")),
    Case("conv-to-missing-dataset", R("convert", "to-platonerf", W("nothing"), W("out")), says=("nothing",)),
    Case("conv-to-foreign-folder", R("convert", "to-platonerf", DS, W("photos")), says=("photos",),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("conv-to-broken-dataset", R("convert", "to-platonerf", DS, W("out")), says=("spot_0000.exr",),
         prepare=break_transient("truncated")),

    # --- intensity images (torch_recon.rgb_shadow, a library call behind the CLI's error handling)
    Case("rgb-png-missing", read_rgb("rgb/none.png"), says=("none.png", "no such file")),
    Case("rgb-png-garbage", read_rgb("rgb/spot_0000.png"), says=("spot_0000.png", "rgb_files", "png"),
         prepare=write_file("rgb/spot_0000.png", "not a png")),
    Case("rgb-png-float", read_rgb("rgb/spot_0000.tif"), says=("spot_0000.tif", "rgb_files", "16-bit"),
         prepare=write_image("rgb/spot_0000.tif", np.zeros((5, 6), np.float32))),
    Case("rgb-png-grey-alpha", read_rgb("rgb/spot_0000.png"), says=("spot_0000.png", "rgb_files", "shape"),
         prepare=write_image("rgb/spot_0000.png", np.zeros((5, 6, 2), np.uint8))),

    # --- command line
    Case("cli-unknown-command", R("reconstruct", DS), says=("reconstruct",)),
    Case("cli-unknown-option", R("fit", NPZ, "--out", W("out"), "--fast"), says=("--fast",)),

    # --- simulate (pipeline/simulate.py, a process each)
    Case("sim-zero-bins", S("--example", "cave-chair", "--bins", "0", "--out", W("sim")), says=("bins",)),
    Case("sim-resolution-huge", S("--example", "cave-chair", "--resolution", "100000", "--out", W("sim")),
         says=("width", "would need")),
    Case("sim-bins-huge", S("--example", "cave-chair", "--bins", "100000000", "--out", W("sim")), says=("bins", "need")),
    Case("sim-unknown-example", S("--example", "nosuch", "--out", W("sim")), says=("nosuch",)),
    Case("sim-blend-garbage", S(W("x.blend"), "--out", W("sim")), says=("x.blend",),
         prepare=write_file("x.blend", "not a blend")),
    Case("sim-blend-missing", S(W("y.blend"), "--out", W("sim")), says=("y.blend",)),
    Case("sim-unknown-option", S("--example", "cave-chair", "--warp", "--out", W("sim")), says=("--warp",)),
    Case("sim-config-bad-json", S("--example", "cave-chair", "--config", W("c.json"), "--out", W("sim")),
         says=("c.json",), prepare=write_file("c.json", "{")),
    Case("sim-config-wrong-type", S("--example", "cave-chair", "--config", W("c.json"), "--out", W("sim")),
         says=("bins",), prepare=write_file("c.json", '{"bins": "many"}')),
    Case("sim-spot-list-bad", S("--example", "cave-chair", "--spot-list", "1,2", "--out", W("sim")),
         says=("--spot-list",)),
    Case("sim-test-views-bad", S("--example", "cave-chair", "--test-views", "x", "--out", W("sim")),
         says=("--test-views",)),
    Case("sim-photons-negative", S("--example", "cave-chair", "--photons", "-1", "--out", W("sim")), says=("photons",)),
    Case("sim-out-foreign-folder", S(*SIM_SMALL, "--out", W("photos")), says=("photos", "not empty"),
         prepare=write_file("photos/holiday.jpg", b"x")),
    Case("sim-out-is-file", S(*SIM_SMALL, "--out", W("file")), says=("file",), prepare=write_file("file", "x")),
    # spots outside the view are allowed (preprocessing fits them) as long as one lies inside
    Case("sim-spots-outside-view", S("--example", "cave-chair", "--width", "20", "--height", "10", "--spot-list",
                                     "2,0.3,0;1.2,0.15,-2", "--test-views", "0", "--out", W("sim")),
         says=("every spot", "view", "at least one")),
    Case("sim-keeps-user-files", simulate_into_dataset_with_user_files, rc=0, after=after_sim_user_files),
    Case("sim-rerun-validates-reused", simulate_reuse_truncated, rc=0, after=after_reuse_truncated, slow=True),
    Case("sim-sigint-during-render", signal_simulate(SIGINT, lambda t: "spot 1/" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),
    Case("sim-sigterm-during-render", signal_simulate(SIGTERM, lambda t: "spot 1/" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),
    Case("sim-sigint-at-start", signal_simulate(SIGINT, lambda t: "geometry" in t or "spot" in t), rc=130,
         says=("interrupted",), after=after_signal_simulate, slow=True),

    # --- add-on operators (one line in the ERROR report, CANCELLED, nothing touched)
    Case("addon-import-mesh-missing",
         addon_op("import_reconstruction", set_props(import_path=lambda ws: str(ws.root / "no.ply"))), says=("no.ply",)),
    Case("addon-import-mesh-garbage", addon_op("import_reconstruction",
                                               set_props(import_path=lambda ws: str(ws.write("bad.ply", "zz")))),
         says=("bad.ply",)),
    Case("addon-import-depth-garbage", addon_op("import_visible_depth",
                                                set_props(measurements_path=lambda ws: str(ws.write("bad.npz", "zz")))),
         says=("bad.npz",)),
    Case("addon-import-depth-foreign-npz", addon_op("import_visible_depth", set_props(
        measurements_path=lambda ws: (np.savez(ws.p("odd.npz"), x=np.zeros(2)), str(ws.root / "odd.npz"))[1])),
        says=("odd.npz",)),
    Case("addon-load-config-bad-json", addon_op("load_config", file_op(filepath=lambda ws: ws.write("c.json", "{"))),
         says=("c.json",)),
    Case("addon-load-config-wrong-type", addon_op("load_config", file_op(
        filepath=lambda ws: ws.write("c.json", '{"bins": "many"}'))), says=("bins",)),
    Case("addon-export-config-no-folder", addon_op("export_config", both_setup(
        set_props(spot_source="RANDOM"), file_op(filepath=W("nodir/c.json")))), says=("nodir",)),
    Case("addon-reconstruct-not-a-dataset", addon_op("reconstruct", both_setup(
        with_prefs(python_path=lambda ws: sys.executable, project_dir=lambda ws: str(ROOT)),
        set_props(recon_dataset_dir=lambda ws: str(ws.p("e/x").parent)))), says=("dataset.json",)),
]
