"""The third-party wheels the extension bundles for Blender's Python (cp311), per platform.

Blender ships numpy (and bpy, mathutils, ...) but not what the simulator imports besides:
OpenEXR (transients), scipy (filters, erf), trimesh (ground-truth meshes), embreex (shadow
rays) and tqdm (progress). build_zip.py lists the downloaded files in the manifest's
``wheels`` field; Blender installs the ones matching the running platform into
``<extensions>/.local/lib/python3.11/site-packages`` and puts that folder on ``sys.path``,
also in the background Blender that runs pipeline/simulate.py.

Downloads go to a cache folder (default ``.cache/blender_wheels/<platform>/``, git-ignored):
``pip download --only-binary=:all: --no-deps --python-version 3.11 --platform TAG``. A cache
that already satisfies every requirement is used without the network. Not shipped in the zip.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / ".cache" / "blender_wheels"
PYTHON_VERSION = "3.11"  # Blender 4.2 - 5.0

#: top-level module the vendored code imports -> the requirement that provides it (no numpy:
#: Blender's own numpy must stay, a bundled one would shadow it)
REQUIREMENTS = {
    "OpenEXR": "openexr>=3.3",
    "scipy": "scipy>=1.11",
    "trimesh": "trimesh>=4.0",
    "embreex": "embreex>=2.17.7",
    "tqdm": "tqdm>=4.60",
}
#: modules Blender's own Python has (bundled or built in)
BLENDER_PROVIDES = {"bpy", "bpy_extras", "mathutils", "gpu", "gpu_extras", "bmesh", "bl_math", "addon_utils",
                    "numpy", "requests", "zstandard", "idna", "certifi", "urllib3", "charset_normalizer"}

#: Blender platform -> the wheel platform tags pip may use for it (newest first). Blender 5.0 needs
#: glibc 2.28 on Linux; scipy's arm64 wheels need macOS 12+ and embreex's macOS 13+.
PLATFORM_TAGS = {
    "linux-x64": ("manylinux_2_28_x86_64", "manylinux_2_27_x86_64", "manylinux_2_17_x86_64",
                  "manylinux2014_x86_64"),
    "macos-arm64": ("macosx_14_0_arm64",),
    "macos-x64": ("macosx_11_0_x86_64",),
    "windows-x64": ("win_amd64",),
}
PLATFORMS = tuple(PLATFORM_TAGS)


class WheelError(RuntimeError):
    pass


def _dist_name(name: str) -> str:
    return re.sub(r"[-_.]+", "_", name).lower()


def _requirement_name(req: str) -> str:
    return _dist_name(re.split(r"[<>=!~ ;\[]", req, maxsplit=1)[0])


def _version_key(version: str) -> tuple:
    return tuple(int(p) if p.isdigit() else -1 for p in re.split(r"[.+-]", version.replace("post", "")))


def wheel_platform(platform: str) -> str:
    """Folder name of a Blender platform in the cache (and the zip suffix): linux-x64 -> linux_x64."""
    return platform.replace("-", "_")


def pip_download_command(platform: str, dest: Path, offline: bool = False, python: str = sys.executable) -> list:
    cmd = [python, "-m", "pip", "download", "--disable-pip-version-check", "--no-deps", "--only-binary=:all:",
           "--python-version", PYTHON_VERSION, "--implementation", "cp", "--abi", "cp311", "--abi", "abi3",
           "--abi", "none", "--dest", str(dest)]
    for tag in PLATFORM_TAGS[platform]:
        cmd += ["--platform", tag]
    if offline:
        cmd += ["--no-index", "--find-links", str(dest)]
    return cmd + list(REQUIREMENTS.values())


def cached_wheels(platform: str, cache_dir: Path = DEFAULT_CACHE) -> list[Path] | None:
    """One wheel per requirement (the newest cached version) for `platform`, or None if one is missing."""
    folder = Path(cache_dir) / wheel_platform(platform)
    picked = []
    for req in REQUIREMENTS.values():
        name = _requirement_name(req)
        found = []
        for p in folder.glob("*.whl"):
            parts = p.name[:-4].split("-")
            if len(parts) >= 5 and _dist_name(parts[0]) == name:
                found.append((_version_key(parts[1]), p))
        if not found:
            return None
        picked.append(max(found)[1])
    return sorted(picked, key=lambda p: p.name)


def ensure_wheels(platform: str, cache_dir: Path = DEFAULT_CACHE, offline: bool = False, quiet: bool = False,
                  ) -> list[Path]:
    """The platform's wheels from the cache, downloading the missing ones unless `offline`."""
    if platform not in PLATFORM_TAGS:
        raise WheelError(f"unknown platform '{platform}' (expected one of {', '.join(PLATFORMS)})")
    dest = Path(cache_dir) / wheel_platform(platform)
    dest.mkdir(parents=True, exist_ok=True)
    have = cached_wheels(platform, cache_dir)
    if have is not None:
        return have
    if offline:
        raise WheelError(f"wheels for {platform} are not all in {dest} and downloads are off (--offline)")
    r = subprocess.run(pip_download_command(platform, dest), text=True,
                       capture_output=quiet, stdin=subprocess.DEVNULL)
    have = cached_wheels(platform, cache_dir)
    if r.returncode != 0 or have is None:
        tail = ((r.stdout or "") + (r.stderr or ""))[-600:] if quiet else "see pip's output above"
        raise WheelError(f"pip download of the {platform} wheels into {dest} failed ({r.returncode}): {tail}")
    return have
