"""The platform zip installed the way Blender installs extensions, into a clean user folder, with
no checkout anywhere: its Simulate writes a valid dataset using only the bundled wheels.

"Blender's Python" here is this interpreter run with -S (no site-packages) and only what a
Blender build bundles on its path (bpy, numpy, requests, zstandard and their helpers): so
OpenEXR, scipy, trimesh, embreex and tqdm can come only from the wheels the extension installed
into <user>/extensions/.local/lib/python3.11/site-packages. The zip goes in through
bpy.ops.extensions.package_install_files, Blender's own installer (it unpacks the wheels);
the background Blender is a shim running pipeline/simulate.py from the installed extension
with that same Python. Slow: it downloads the wheels once (skipped when that is impossible).
"""

import inspect
import os
import platform
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.support.addon_fixtures import REPO

sys.path.insert(0, str(REPO / "addon"))
import blender_wheels  # noqa: E402
import build_zip  # noqa: E402

pytestmark = pytest.mark.slow

#: what a Blender build's own Python holds besides the standard library
BLENDER_BUNDLED = ("bpy", "numpy", "numpy.libs", "requests", "zstandard", "certifi", "idna", "urllib3",
                   "charset_normalizer")


def this_platform() -> str | None:
    machine = platform.machine().lower()
    arch = "arm64" if machine in ("arm64", "aarch64") else "x64" if machine in ("x86_64", "amd64") else ""
    name = {"Linux": "linux", "Darwin": "macos", "Windows": "windows"}.get(platform.system(), "")
    p = f"{name}-{arch}"
    return p if p in blender_wheels.PLATFORMS else None


def blender_like_site(dest: Path) -> Path:
    """A folder holding links to only what Blender's Python bundles."""
    import numpy
    site = Path(numpy.__file__).resolve().parents[1]
    dest.mkdir()
    for name in BLENDER_BUNDLED:
        if (site / name).exists():
            (dest / name).symlink_to(site / name)
    return dest


INSTALL_AND_SIMULATE = '''
import os, sys
assert not any(p.endswith("site-packages") and "extensions" not in p for p in sys.path), sys.path
for mod in ("scipy", "trimesh", "OpenEXR", "embreex", "tqdm", "torch_recon", "pipeline"):
    try:
        __import__(mod)
    except ImportError:
        pass
    else:
        raise SystemExit(f"{{mod}} is importable before the extension is installed")
import bpy
r = bpy.ops.extensions.package_install_files(filepath={zip!r}, repo="user_default", enable_on_install=True)
assert r == {{"FINISHED"}}, r
key = "bl_ext.user_default.platolidar"
assert key in bpy.context.preferences.addons, list(bpy.context.preferences.addons.keys())
site = os.path.join(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib", "python3.11", "site-packages")
print("WHEELS", sorted(n for n in os.listdir(site) if n.endswith(".dist-info")))

import math
{room_code}
scene = bpy.context.scene
cam = build_room(scene)
s = scene.platolidar
s.camera = cam
s.width = s.height = 20
s.bin_ps, s.bins = 64.0, 1000
s.subpixel_grid = 1
s.test_views_dolly = s.test_views_orbit = 0
for p in ((1.2, 2.0, 0.0), (1.5, 3.0, 2.0)):
    scene.cursor.location = p
    assert bpy.ops.platolidar.add_spot_cursor() == {{"FINISHED"}}
bpy.context.preferences.addons[key].preferences.blender_path = {shim!r}
s.output_dir = {out!r}
r = bpy.ops.platolidar.simulate()   # execute: blocking
print("SIMULATE", r)
# no checkout: the reconstruction environment gets the zip's reconstructor and its requirements
import importlib
_project = importlib.import_module(key + "._project")
kind, src = _project.reconstructor_source("")
assert kind == "requirements" and src.endswith("_reconstructor/requirements.txt") and os.path.isfile(src), src
assert _project.reconstruction_pythonpath("") == [str(_project.RECONSTRUCTOR_DIR)]
print("RECONSTRUCTOR_OK")
'''

BLENDER_SHIM = '''
import os, sys
a = sys.argv[1:]
blend, script, rest = a[1], a[a.index("-P") + 1], a[a.index("--") + 1:]
assert "/extensions/user_default/platolidar/" in script, script
os.execv({python!r}, [{python!r}, "-S", "-s", script, blend, *rest])
'''


@pytest.fixture(scope="module")
def platform_zip(tmp_path_factory):
    plat = this_platform()
    if plat is None:
        pytest.skip(f"no wheels defined for {platform.system()} {platform.machine()}")
    try:
        wheels = blender_wheels.ensure_wheels(plat, quiet=True)
    except blender_wheels.WheelError as exc:
        pytest.skip(f"the {plat} wheels cannot be downloaded here: {str(exc)[:200]}")
    return build_zip.build(tmp_path_factory.mktemp("dist"), platform=plat, wheels=wheels)


def test_installed_zip_simulates_without_the_checkout(platform_zip, tmp_path):
    import tests.support.addon_fixtures as addon_fixtures
    from tests.support.addon_fixtures import fake_executable
    from torch_recon.contract.dataset import load_dataset

    site = blender_like_site(tmp_path / "blender_python")
    shim = fake_executable(tmp_path / "blender", BLENDER_SHIM.format(python=sys.executable))
    out = tmp_path / "ds"
    room_code = "\n".join(inspect.getsource(f) for f in (addon_fixtures._mesh_object, addon_fixtures.box,
                                                          addon_fixtures.build_room))
    code = INSTALL_AND_SIMULATE.format(zip=str(platform_zip), room_code=room_code, shim=str(shim), out=str(out))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update(PYTHONPATH=str(site), BLENDER_USER_RESOURCES=str(tmp_path / "user"), PYTHONNOUSERSITE="1")
    r = subprocess.run([sys.executable, "-S", "-s", "-c", textwrap.dedent(code)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=600)
    log = r.stdout[-3000:] + r.stderr[-3000:]
    assert r.returncode == 0 and "SIMULATE {'FINISHED'}" in r.stdout and "RECONSTRUCTOR_OK" in r.stdout, log
    for dist in ("scipy", "trimesh", "openexr", "embreex", "tqdm"):
        assert f"'{dist}-" in r.stdout.lower(), (dist, log)
    ds = load_dataset(out)
    assert ds.manifest.sensor.width == 20 and len(ds.manifest.spots) == 2
    for spot in ds.manifest.spots:
        tr = ds.read_transient(spot.id).dense()
        assert tr.shape[-1] == 1000 and tr.sum() > 0
    assert (out / ds.manifest.ground_truth.mesh_file).is_file()
