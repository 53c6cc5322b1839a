"""An independent two-bounce transient reference: mitransient (Mitsuba 3 path tracer), optional.

Not a project dependency (about 300 MB; ../shared/REFERENCE_RENDERER.md): install it into a
separate target and put that on PYTHONPATH, e.g.
    .venv/bin/pip install --target /work/mi_pkgs mitransient "mitsuba==3.8.0"
    (then remove /work/mi_pkgs/numpy*: pip pulls numpy 2, which would shadow the venv's numpy 1.26)
Used by tests/pipeline/test_sim_mitransient.py (slow) and the fidelity_mitransient benchmark.

Settings that give correct two-bounce transients (REFERENCE_RENDERER.md): `transient_nlos_path`
with laser sampling (each visible point is connected straight to the laser's hit point, so the spot
is a point, as in the simulator), first and last bounces timed, max_depth 2 (no one-bounce return is
recorded), near_clip 1e-4, a box-filtered `transient_hdr_film` on the dataset's bins. The laser is a
projector: the spot's irradiance is proportional to cos(theta_in) / |l - o|^2 in mitransient's own
units, so a cube agrees with the simulator's (collimated beam) up to one factor per spot.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

INSTALL = 'pip install --target DIR mitransient "mitsuba==3.8.0" and put DIR on PYTHONPATH'
VARIANT = "llvm_ad_mono"


def installed() -> bool:
    """mitsuba and mitransient are importable (cheap: nothing is imported)."""
    import importlib.util
    return all(importlib.util.find_spec(m) is not None for m in ("mitsuba", "mitransient"))


def missing() -> str | None:
    """Why mitransient cannot run here (one line), or None when it can."""
    try:
        import mitsuba as mi
        mi.set_variant(VARIANT)
        import mitransient  # noqa: F401  (registers the transient plugins for the variant)
    except Exception as exc:       # noqa: BLE001 - ImportError, or a variant/LLVM failure
        return f"mitransient is not usable ({type(exc).__name__}: {exc}); {INSTALL}"
    return None


def _load_mitsuba():
    import mitsuba as mi
    mi.set_variant(VARIANT)
    import mitransient  # noqa: F401
    return mi


class MitransientRenderer:
    """One scene's shapes (exported once as PLY) rendered per laser target with the dataset's sensor."""

    def __init__(self, parts, sensor, work_dir: Path | None = None):
        import trimesh

        self.mi = _load_mitsuba()
        self.sensor = sensor
        self._tmp = None if work_dir else tempfile.TemporaryDirectory(prefix="mitransient_")
        work_dir = Path(work_dir or self._tmp.name)
        work_dir.mkdir(parents=True, exist_ok=True)
        self.shapes = {}
        for i, p in enumerate(parts):
            fn = str(work_dir / f"part{i}.ply")
            trimesh.Trimesh(p.vertices, p.faces, process=False).export(fn)
            self.shapes[f"s{i}"] = {"type": "ply", "filename": fn, "face_normals": True,
                                    "bsdf": {"type": "diffuse",
                                             "reflectance": {"type": "uniform", "value": float(p.albedo)}}}

    def scene(self, target):
        """The Mitsuba scene with the laser (at sensor.laser_origin) aimed at the world point `target`."""
        mi, s = self.mi, self.sensor
        t = mi.ScalarTransform4f
        c2w = np.asarray(s.camera_to_world, np.float64)
        eye, ahead, up = c2w[:3, 3], c2w[:3, 3] - c2w[:3, 2], c2w[:3, 1]     # camera looks down its -z
        aim = np.asarray(target, np.float64) - np.asarray(s.laser_origin, np.float64)
        laser_up = [0, 0, 1] if abs(aim[2]) < 0.99 * np.linalg.norm(aim) else [0, 1, 0]   # any up not along the beam
        return mi.load_dict({
            "type": "scene",
            "integrator": {"type": "transient_nlos_path", "nlos_laser_sampling": True,
                           "account_first_and_last_bounces": True, "max_depth": 2, "temporal_filter": "box"},
            "sensor": {"type": "perspective", "fov": float(np.degrees(s.fov_rad)), "fov_axis": s.fov_axis,
                       "near_clip": 1e-4,
                       "to_world": t().look_at(origin=eye.tolist(), target=ahead.tolist(), up=up.tolist()),
                       "film": {"type": "transient_hdr_film", "width": s.width, "height": s.height,
                                "temporal_bins": s.bins, "bin_width_opl": s.bin_width_m,
                                "start_opl": s.start_m, "rfilter": {"type": "box"}}},
            "laser": {"type": "projector", "fov": 0.2, "irradiance": 1.0,
                      "to_world": t().look_at(origin=[float(v) for v in s.laser_origin],
                                              target=[float(v) for v in target], up=laser_up)},
            **self.shapes}, optimize=False)

    def render(self, target, spp: int, seed: int = 0) -> np.ndarray:
        """The (H, W, T) float64 transient cube (row 0 at the top) for the laser aimed at `target`."""
        _, transient = self.mi.render(self.scene(target), spp=int(spp), seed=int(seed))
        return np.array(transient, dtype=np.float64)[..., 0]
