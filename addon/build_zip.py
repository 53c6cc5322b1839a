"""Build the extension zips: the manifest, the add-on, the bpy-free project modules it runs, and
the third-party wheels the simulator needs in Blender's Python, one zip per platform.

    python addon/build_zip.py --out dist                  # dist/platolidar-0.1.0-<platform>.zip x 4
    python addon/build_zip.py --out dist --platform linux-x64 --offline   # one platform, cached wheels only
    python addon/build_zip.py --out dist --no-wheels      # dist/platolidar-0.1.0.zip, code only
    python addon/build_zip.py --out dist --blender blender   # Blender's own builder:
        blender --command extension build --source-dir STAGE --output-filepath ZIP

Both builders start from the same staging folder, so both zips hold the same files:
- blender_manifest.toml (from the repository root; a platform build adds its `platforms` and
  `wheels` lists) and addon/* at the zip root (the extension's main module is addon/__init__.py),
  without the build scripts, caches or tests;
- _vendor/pipeline, _vendor/torch_recon: the project modules that the add-on and
  pipeline/simulate.py import, found by following their imports (never the torch parts),
  plus torch_recon/contract/data. addon/_project.py puts _vendor on sys.path inside Blender;
- wheels/*.whl: one platform's wheels (addon/blender_wheels.py: which, and the download cache).
One zip per platform, as `blender --command extension build --split-platforms` makes them: a
zip with every platform's wheels would be four times as large.
`--validate` also checks each zip with Blender's extension validator (blender_ext.py from
a Blender binary or the bpy module) when one is found.
"""

from __future__ import annotations

import argparse
import ast
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import blender_wheels  # noqa: E402  (next to this script; not shipped)

REPO = Path(__file__).resolve().parents[1]
ADDON = REPO / "addon"
MANIFEST = "blender_manifest.toml"
VENDOR = "_vendor"
VENDORED_PACKAGES = ("pipeline", "torch_recon")
#: scripts run inside Blender whose imports are followed too
ENTRY_SCRIPTS = ("pipeline/simulate.py",)
#: package data shipped with the vendored code
DATA_DIRS = ("torch_recon/contract/data",)
SKIP_NAMES = {"build_zip.py", "blender_wheels.py", "__pycache__", VENDOR}
#: the whole reconstructor for the external Python (the environment set-up installs its dependencies)
RECONSTRUCTOR = "_reconstructor"
WHEELS = "wheels"
SKIP_SUFFIXES = (".pyc", ".pyo", ".blend1", ".zip")
#: fixed timestamp: the same sources give the same zip bytes
ZIP_DATE = (2024, 1, 1, 0, 0, 0)


class BuildError(RuntimeError):
    pass


def _module_file(name: str) -> Path | None:
    """Source file of a project module name (package -> its __init__.py), or None."""
    parts = name.split(".")
    if parts[0] not in VENDORED_PACKAGES:
        return None
    base = REPO.joinpath(*parts)
    if (base / "__init__.py").is_file():
        return base / "__init__.py"
    if base.with_suffix(".py").is_file():
        return base.with_suffix(".py")
    return None


def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Absolute names of every module `path` imports (top level or inside functions)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    is_pkg = path.name == "__init__.py"
    here = _module_name(path) if path.is_relative_to(REPO) and path.parts[len(REPO.parts)] in VENDORED_PACKAGES \
        else ""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                if not here:
                    continue  # relative import inside the add-on itself: not a project module
                pkg = here.split(".") if is_pkg else here.split(".")[:-1]
                pkg = pkg[:len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)  # `from pkg import module`
    return out


def vendored_files() -> tuple[list[Path], set[str]]:
    """Project modules reachable from the add-on and the entry scripts; also third-party names seen."""
    todo = [p for p in ADDON.rglob("*.py") if not (SKIP_NAMES & set(p.relative_to(ADDON).parts))]
    todo += [REPO / s for s in ENTRY_SCRIPTS if (REPO / s).is_file()]
    seen, files, third_party = set(), set(), set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        if path.parts[len(REPO.parts)] in VENDORED_PACKAGES:
            files.add(path)
        for name in _imports(path):
            top = name.split(".")[0]
            if top in VENDORED_PACKAGES:
                # every package on the way needs its __init__.py
                parts = name.split(".")
                for i in range(1, len(parts) + 1):
                    f = _module_file(".".join(parts[:i]))
                    if f is not None and f not in seen:
                        todo.append(f)
            elif top and top not in sys.stdlib_module_names:
                third_party.add(top)
    for d in DATA_DIRS:
        files.update(p for p in (REPO / d).rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    return sorted(files), third_party


def _addon_files() -> list[Path]:
    out = []
    for p in sorted(ADDON.rglob("*")):
        rel = p.relative_to(ADDON)
        if p.is_dir() or SKIP_NAMES & set(rel.parts) or p.name.startswith(".") or p.suffix in SKIP_SUFFIXES \
                or rel.parts[0] == "tests" or p.name.startswith("test_"):
            continue
        out.append(p)
    return out


def manifest_text(platform: str | None = None, wheels=()) -> str:
    """The repository's manifest; a platform build adds `platforms` and `wheels` before the first table."""
    text = (REPO / MANIFEST).read_text(encoding="utf-8")
    if platform is None:
        return text
    lines = [f'platforms = ["{platform}"]', "wheels = ["] + [f'  "./{WHEELS}/{w.name}",' for w in wheels] + ["]", ""]
    head, sep, tail = text.partition("\n[")
    return head.rstrip("\n") + "\n\n# Added by addon/build_zip.py for this platform's zip\n" + "\n".join(lines) \
        + sep + tail


def stage(dest: Path, platform: str | None = None, wheels=()) -> dict[str, Path]:
    """Lay out the extension in `dest`; returns {archive name: source} (the manifest is written, not copied)."""
    if not (REPO / MANIFEST).is_file():
        raise BuildError(f"{REPO / MANIFEST} is missing")
    layout = {}
    for p in _addon_files():
        layout[p.relative_to(ADDON).as_posix()] = p
    vendored, _ = vendored_files()
    for p in vendored:
        layout[f"{VENDOR}/{p.relative_to(REPO).as_posix()}"] = p
    for p in sorted((REPO / "torch_recon").rglob("*")):
        if p.is_file() and "__pycache__" not in p.parts and p.suffix not in SKIP_SUFFIXES:
            layout[f"{RECONSTRUCTOR}/{p.relative_to(REPO).as_posix()}"] = p
    for w in wheels:
        layout[f"{WHEELS}/{w.name}"] = Path(w)
    for name, src in layout.items():
        (dest / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src, dest / name)
    (dest / RECONSTRUCTOR / "requirements.txt").write_text(reconstructor_requirements(), encoding="utf-8")
    layout[f"{RECONSTRUCTOR}/requirements.txt"] = REPO / "pyproject.toml"
    text = manifest_text(platform, wheels)
    tomllib.loads(text)  # a broken insertion fails here, not in Blender
    (dest / MANIFEST).write_text(text, encoding="utf-8")
    layout[MANIFEST] = REPO / MANIFEST
    return layout


def reconstructor_requirements() -> str:
    """pyproject.toml's dependencies without torch (installed first, from the chosen build)."""
    with open(REPO / "pyproject.toml", "rb") as f:
        deps = tomllib.load(f)["project"]["dependencies"]
    keep = [d for d in deps if not d.replace(" ", "").lower().startswith("torch")]
    return "# the reconstructor's dependencies (from pyproject.toml; torch is installed before, its build chosen)\n" \
        + "\n".join(keep) + "\n"


def check_third_party():
    """Every module the vendored code imports is Blender's own or bundled as a wheel."""
    _, third = vendored_files()
    missing = sorted(third - blender_wheels.BLENDER_PROVIDES - set(blender_wheels.REQUIREMENTS))
    if missing:
        raise BuildError("the simulator imports " + ", ".join(missing) + ", which neither Blender's Python "
                         "nor addon/blender_wheels.py REQUIREMENTS provides: add the wheel there")


def manifest_info() -> dict:
    with open(REPO / MANIFEST, "rb") as f:
        m = tomllib.load(f)
    for key in ("id", "version"):
        if key not in m:
            raise BuildError(f"{MANIFEST}: field '{key}' is missing")
    return m


def zip_python(stage_dir: Path, out_file: Path) -> Path:
    """The pure-Python builder: every staged file at the archive root, sorted, fixed dates."""
    tmp = out_file.with_name(out_file.name + ".partial")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for p in sorted(stage_dir.rglob("*")):
            if p.is_file():
                info = zipfile.ZipInfo(p.relative_to(stage_dir).as_posix(), ZIP_DATE)
                # wheels are zips already: stored, as Blender's builder does
                info.compress_type = zipfile.ZIP_STORED if p.suffix == ".whl" else zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                z.writestr(info, p.read_bytes())
    tmp.replace(out_file)
    return out_file


def zip_blender(blender: str, stage_dir: Path, out_file: Path) -> Path:
    cmd = [blender, "--command", "extension", "build", "--source-dir", str(stage_dir),
           "--output-filepath", str(out_file)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0 or not out_file.is_file():
        raise BuildError(f"{' '.join(cmd)} failed ({r.returncode}): {(r.stdout + r.stderr)[-800:]}")
    return out_file


def find_blender_ext() -> Path | None:
    """Blender's extension tool (blender_ext.py), shipped inside the bpy module."""
    try:
        import importlib.util
        spec = importlib.util.find_spec("bpy")
    except (ImportError, ValueError):
        spec = None
    if spec is None or not spec.submodule_search_locations:
        return None
    for loc in spec.submodule_search_locations:
        hits = sorted(Path(loc).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
        if hits:
            return hits[-1]
    return None


def validate(zip_file: Path, blender: str | None = None) -> str:
    """Blender's own validation of the zip; returns its output, raises BuildError on failure."""
    if blender:
        cmd = [blender, "--command", "extension", "validate", str(zip_file)]
    else:
        tool = find_blender_ext()
        if tool is None:
            return "skipped: no Blender binary or bpy module to validate with"
        cmd = [sys.executable, str(tool), "validate", str(zip_file)]
    r = subprocess.run(cmd, capture_output=True, text=True)
    out = (r.stdout + r.stderr).strip()
    if r.returncode != 0 or "error" in out.lower():
        raise BuildError(f"validation failed: {out[-800:]}")
    return out


def zip_name(info: dict, platform: str | None) -> str:
    suffix = f"-{blender_wheels.wheel_platform(platform)}" if platform else ""
    return f"{info['id']}-{info['version']}{suffix}.zip"


def build(out_dir, blender: str | None = None, check: bool = False, platform: str | None = None,
          wheels=()) -> Path:
    """One zip: code only (platform None) or for one platform with its wheels."""
    info = manifest_info()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    out_file = out_dir / zip_name(info, platform)
    with tempfile.TemporaryDirectory(prefix="platolidar_ext_") as tmp:
        stage_dir = Path(tmp) / info["id"]
        stage_dir.mkdir()
        stage(stage_dir, platform, wheels)
        path = zip_blender(blender, stage_dir, out_file) if blender else zip_python(stage_dir, out_file)
    if check:
        print(validate(path, blender))
    return path


def build_platforms(out_dir, platforms=blender_wheels.PLATFORMS, cache_dir=blender_wheels.DEFAULT_CACHE,
                    offline: bool = False, blender: str | None = None, check: bool = False) -> list[Path]:
    """A zip per platform with that platform's wheels (downloaded into the cache when missing)."""
    check_third_party()
    out = []
    for platform in platforms:
        try:
            wheels = blender_wheels.ensure_wheels(platform, cache_dir, offline=offline)
        except blender_wheels.WheelError as exc:
            raise BuildError(str(exc)) from None
        out.append(build(out_dir, blender, check, platform, wheels))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="dist", help="output folder (default: dist)")
    ap.add_argument("--platform", action="append", choices=blender_wheels.PLATFORMS + ("all",),
                    help="Blender platform to build a zip for (repeatable; default: all)")
    ap.add_argument("--no-wheels", action="store_true", help="one code-only zip without wheels (Simulate then "
                    "needs a Project Folder with its .venv)")
    ap.add_argument("--wheel-cache", default=str(blender_wheels.DEFAULT_CACHE),
                    help="folder of downloaded wheels, one sub-folder per platform (default: .cache/blender_wheels)")
    ap.add_argument("--offline", action="store_true", help="use cached wheels only, never the network")
    ap.add_argument("--blender", help="build with this Blender binary's `--command extension build`")
    ap.add_argument("--validate", action="store_true", help="check the zip with Blender's extension validator")
    ap.add_argument("--list", action="store_true", help="print the archive's files")
    args = ap.parse_args(argv)
    platforms = blender_wheels.PLATFORMS if not args.platform or "all" in args.platform \
        else tuple(dict.fromkeys(args.platform))
    try:
        if args.no_wheels:
            paths = [build(args.out, args.blender, args.validate)]
        else:
            paths = build_platforms(args.out, platforms, Path(args.wheel_cache), args.offline, args.blender,
                                    args.validate)
    except (BuildError, OSError, tomllib.TOMLDecodeError, SyntaxError) as exc:
        print(f"build_zip: error: {exc}", file=sys.stderr)
        return 2
    for path in paths:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
        n_wheels = sum(n.startswith(WHEELS + "/") for n in names)
        print(f"{path}: {len(names)} files ({n_wheels} wheels), {os.path.getsize(path) / 2**20:.1f} MiB")
        if args.list:
            print("\n".join(names))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
