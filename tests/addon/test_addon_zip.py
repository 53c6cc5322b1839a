"""The extension zip: manifest + add-on + vendored bpy-free modules, nothing else; valid; self-contained."""

import ast
import subprocess
import sys
import zipfile

import pytest

from tests.support.addon_fixtures import REPO

sys.path.insert(0, str(REPO / "addon"))
import blender_wheels  # noqa: E402
import build_zip  # noqa: E402


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    path = build_zip.build(out)
    with zipfile.ZipFile(path) as z:
        return path, z.namelist(), {n: z.read(n) for n in z.namelist()}


def test_zip_holds_manifest_and_addon_only(built):
    path, names, _ = built
    assert path.name == "platolidar-0.1.0.zip"
    assert "blender_manifest.toml" in names and "__init__.py" in names
    for must in ("props.py", "panels.py", "preferences.py", "draw_spots.py", "operators/__init__.py",
                 "operators/simulate.py", "_vendor/pipeline/config.py", "_vendor/pipeline/simulate.py",
                 "_vendor/torch_recon/contract/units.py", "_vendor/torch_recon/measurements.py"):
        assert must in names, must
    for n in names:
        parts = n.split("/")
        assert "__pycache__" not in parts and not n.endswith((".pyc", ".pyo")), n
        assert not any(p.startswith(".") for p in parts), n
        assert "tests" not in parts and not parts[-1].startswith("conftest"), n   # contract/test_views.py is code
        assert parts[-1] not in ("build_zip.py", "blender_wheels.py"), n
        assert parts[0] in ("_vendor", "_reconstructor", "operators") or "/" not in n, n
    addon_py = {p.relative_to(REPO / "addon").as_posix() for p in (REPO / "addon").rglob("*.py")
                if "__pycache__" not in p.parts} - {"build_zip.py", "blender_wheels.py"}
    assert addon_py <= set(names)


def test_vendored_torch_recon_imports_neither_torch_nor_bpy(built):
    _, names, data = built
    for n in names:
        if n.startswith("_vendor/torch_recon/") and n.endswith(".py"):
            tree = ast.parse(data[n])
            tops = {a.name.split(".")[0] for node in ast.walk(tree) if isinstance(node, ast.Import)
                    for a in node.names}
            tops |= {node.module.split(".")[0] for node in ast.walk(tree)
                     if isinstance(node, ast.ImportFrom) and node.module and not node.level}
            assert not tops & {"torch", "bpy"}, (n, tops)


def test_build_is_deterministic(built, tmp_path):
    path, _, _ = built
    again = build_zip.build(tmp_path)
    assert again.read_bytes() == path.read_bytes()


def test_blender_validates_the_zip(built):
    if build_zip.find_blender_ext() is None:
        pytest.skip("no Blender extension tool (bpy module) here")
    out = build_zip.validate(built[0])
    assert "Success" in out


def test_installed_zip_registers_without_the_checkout(built, tmp_path):
    """Unpacked like Blender installs it, imported with the repository hidden: it must be self-contained."""
    path = built[0]
    ext = tmp_path / "ext"
    with zipfile.ZipFile(path) as z:
        z.extractall(ext / "platolidar")
    code = f"""
import sys
sys.meta_path = [f for f in sys.meta_path if 'editable' not in repr(f).lower()]
sys.path_hooks = [h for h in sys.path_hooks if 'editable' not in repr(h).lower()]
sys.path = [p for p in sys.path if p not in ('', {str(REPO)!r})]
sys.path.insert(0, {str(ext)!r})
import bpy
bpy.ops.wm.read_factory_settings(use_empty=True)
import platolidar
platolidar.register()
import pipeline.config, torch_recon.contract.units
assert pipeline.config.__file__.startswith({str(ext)!r}), pipeline.config.__file__
assert torch_recon.contract.units.__file__.startswith({str(ext)!r}), torch_recon.contract.units.__file__
from platolidar.config_io import settings_to_config
cfg = settings_to_config(bpy.context.scene, strict=False)
assert cfg.bins == 391
from platolidar import _project
assert _project.script_path().is_file() and str(_project.script_path()).startswith({str(ext)!r})
platolidar.unregister()
print("SELF_CONTAINED_OK")
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert "SELF_CONTAINED_OK" in r.stdout, r.stdout[-2000:] + r.stderr[-2000:]


def test_cli_builds_into_a_folder(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "addon" / "build_zip.py"), "--out", str(tmp_path / "d"),
                        "--no-wheels"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "d" / "platolidar-0.1.0.zip").is_file()


# -- per-platform zips with wheels (fake wheels in a cache folder: no network here) ----------------

FAKE_TAGS = {"linux-x64": "cp311-cp311-manylinux_2_28_x86_64", "macos-arm64": "cp311-cp311-macosx_14_0_arm64",
             "macos-x64": "cp311-cp311-macosx_11_0_x86_64", "windows-x64": "cp311-cp311-win_amd64"}


def _fake_wheel(path, dist, version):
    """A minimal valid wheel (Blender's validator opens them)."""
    with zipfile.ZipFile(path, "w") as z:
        info = f"{dist}-{version}.dist-info"
        z.writestr(f"{info}/METADATA", f"Metadata-Version: 2.1\nName: {dist}\nVersion: {version}\n")
        z.writestr(f"{info}/WHEEL", "Wheel-Version: 1.0\nRoot-Is-Purelib: false\n")
        z.writestr(f"{info}/RECORD", "")


@pytest.fixture(scope="module")
def fake_cache(tmp_path_factory):
    cache = tmp_path_factory.mktemp("wheels")
    for plat, tag in FAKE_TAGS.items():
        d = cache / blender_wheels.wheel_platform(plat)
        d.mkdir()
        for req in blender_wheels.REQUIREMENTS.values():
            dist = blender_wheels._requirement_name(req)
            pure = dist in ("trimesh", "tqdm")
            for version in ("1.0", "1.2"):  # two cached versions: the newer one is bundled
                _fake_wheel(d / f"{dist}-{version}-{'py3-none-any' if pure else tag}.whl", dist, version)
    return cache


@pytest.fixture(scope="module")
def platform_zips(fake_cache, tmp_path_factory):
    return build_zip.build_platforms(tmp_path_factory.mktemp("pdist"), cache_dir=fake_cache, offline=True)


def test_one_zip_per_platform_holds_that_platforms_wheels(platform_zips):
    import tomllib
    assert [p.name for p in platform_zips] == [f"platolidar-0.1.0-{blender_wheels.wheel_platform(p)}.zip"
                                               for p in blender_wheels.PLATFORMS]
    for plat, path in zip(blender_wheels.PLATFORMS, platform_zips):
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            manifest = tomllib.loads(z.read("blender_manifest.toml").decode())
            assert all(z.getinfo(n).compress_type == zipfile.ZIP_STORED for n in names if n.endswith(".whl"))
        wheels = sorted(n for n in names if n.startswith("wheels/"))
        assert len(wheels) == len(blender_wheels.REQUIREMENTS), wheels
        assert all("-1.2-" in w for w in wheels), wheels
        for w in wheels:
            assert w.endswith("py3-none-any.whl") or w.endswith(FAKE_TAGS[plat].split("-")[-1] + ".whl"), (plat, w)
        assert manifest["platforms"] == [plat]
        assert sorted(manifest["wheels"]) == sorted(f"./{w}" for w in wheels)
        assert manifest["permissions"]  # the insertion left the tables intact
        assert "_vendor/pipeline/simulate.py" in names and "__init__.py" in names
        assert not any(n.endswith(("build_zip.py", "blender_wheels.py")) for n in names)


def test_blender_validates_a_platform_zip(platform_zips):
    if build_zip.find_blender_ext() is None:
        pytest.skip("no Blender extension tool (bpy module) here")
    assert "Success" in build_zip.validate(platform_zips[0])


def test_every_simulator_import_is_blenders_or_bundled():
    _, third = build_zip.vendored_files()
    assert {"scipy", "OpenEXR", "trimesh"} <= third
    assert not third - blender_wheels.BLENDER_PROVIDES - set(blender_wheels.REQUIREMENTS), third
    assert "numpy" not in " ".join(blender_wheels.REQUIREMENTS.values())  # Blender's numpy must stay first


def test_offline_build_without_cached_wheels_is_one_clear_error(tmp_path):
    r = subprocess.run([sys.executable, str(REPO / "addon" / "build_zip.py"), "--out", str(tmp_path / "d"),
                        "--platform", "windows-x64", "--offline", "--wheel-cache", str(tmp_path / "empty")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "windows-x64" in r.stderr and "--offline" in r.stderr, r.stderr
    assert not (tmp_path / "d" / "platolidar-0.1.0-windows_x64.zip").exists()


def test_pip_download_asks_for_cp311_binaries_of_the_platform():
    cmd = blender_wheels.pip_download_command("macos-arm64", REPO / "x")
    assert cmd[1:4] == ["-m", "pip", "download"]
    assert "--only-binary=:all:" in cmd and "--no-deps" in cmd
    assert cmd[cmd.index("--python-version") + 1] == "3.11"
    assert cmd[cmd.index("--platform") + 1].endswith("arm64")
