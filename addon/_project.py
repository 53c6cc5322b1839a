"""Where the add-on finds the project's bpy-free modules (pipeline, torch_recon).

Two layouts, one rule (documented in docs/addon.md):
- installed extension zip: ``addon/build_zip.py`` copies the modules the add-on and
  ``pipeline/simulate.py`` import into ``_vendor/`` inside the zip, so the extension is
  self-contained for everything that runs inside Blender;
- repository checkout (development, tests): the repository root, the parent of ``addon/``.
That folder is put on ``sys.path`` so ``pipeline.config`` and ``torch_recon.contract.units`` import
by their own names, exactly as ``blender -b -P pipeline/simulate.py`` imports them.
No bpy here: tests and the zip builder use it too.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ADDON_DIR = Path(__file__).resolve().parent
VENDOR_DIR = ADDON_DIR / "_vendor"
#: installed zip: the whole torch_recon package (torch parts included) for the external reconstruction
#: Python, and requirements.txt, its dependencies (build_zip.py writes both); never imported by Blender
RECONSTRUCTOR_DIR = ADDON_DIR / "_reconstructor"
SETUP_SCRIPT = ADDON_DIR / "recon_setup.py"
SIMULATE_SCRIPT = "pipeline/simulate.py"


def repository_root() -> Path | None:
    """The checkout the add-on runs from, or None when installed from the zip."""
    root = ADDON_DIR.parent
    if (root / "pyproject.toml").is_file() and (root / "torch_recon" / "__init__.py").is_file():
        return root
    return None


def modules_root() -> Path | None:
    """Folder holding the ``pipeline`` and ``torch_recon`` packages the add-on uses."""
    if (VENDOR_DIR / "pipeline" / "config.py").is_file():
        return VENDOR_DIR
    root = repository_root()
    if root is not None and (root / "pipeline" / "config.py").is_file():
        return root
    return None


def ensure_importable() -> Path:
    """Put the modules root on sys.path (idempotent); raise ImportError with a fix when absent."""
    root = modules_root()
    if root is None:
        raise ImportError(f"platolidar: neither {VENDOR_DIR} nor a repository checkout around {ADDON_DIR} "
                          "holds pipeline/config.py; rebuild the extension with addon/build_zip.py")
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    return root


def script_path(rel: str = SIMULATE_SCRIPT, project_dir: str = "") -> Path | None:
    """A project script (e.g. pipeline/simulate.py): the preference's project folder wins, then ours."""
    candidates = []
    if project_dir:
        candidates.append(Path(os.path.expanduser(project_dir)) / rel)
    root = modules_root()
    if root is not None:
        candidates.append(root / rel)
    for c in candidates:
        if c.is_file():
            return c
    return None


def reconstruction_pythonpath(project_dir: str = "") -> list[str]:
    """Folders to prepend to PYTHONPATH for the external reconstruction Python.

    Full checkouts, else the reconstructor shipped in the zip: never the vendored subset, which
    has no reconstructor and would shadow an installed torch_recon.
    """
    out = []
    if project_dir:
        p = Path(os.path.expanduser(project_dir))
        if (p / "torch_recon" / "__init__.py").is_file():
            out.append(str(p))
    root = repository_root()
    if root is not None and str(root) not in out:
        out.append(str(root))
    if not out and (RECONSTRUCTOR_DIR / "torch_recon" / "__init__.py").is_file():
        out.append(str(RECONSTRUCTOR_DIR))
    return out


def reconstructor_source(project_dir: str = "") -> tuple[str, str]:
    """What the environment set-up installs: ('project', checkout) or ('requirements', file)."""
    for p in ([Path(os.path.expanduser(project_dir))] if project_dir else []) + \
            ([repository_root()] if repository_root() else []):
        if (p / "pyproject.toml").is_file() and (p / "torch_recon" / "__init__.py").is_file():
            return "project", str(p)
    req = RECONSTRUCTOR_DIR / "requirements.txt"
    if req.is_file():
        return "requirements", str(req)
    raise FileNotFoundError("neither a project checkout (set Project Folder) nor the extension's "
                            f"{req} says what to install")
