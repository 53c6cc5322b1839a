"""The dependency rule (docs/architecture.md): the contract layer imports only itself, the standard
library and a few numeric/geometry libraries; never bpy, torch, pipeline/, addon/ or the rest of torch_recon."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
CONTRACT = REPO / "torch_recon" / "contract"
ALLOWED_THIRD_PARTY = {"numpy", "OpenEXR", "Imath", "trimesh", "scipy", "embreex", "tqdm"}
BLOCKED = ("bpy", "mathutils", "torch", "pipeline", "addon")


def _contract_files():
    return sorted(p for p in CONTRACT.rglob("*.py") if "__pycache__" not in p.parts)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imported(path: Path):
    """(absolute module name, line) of every import in `path`, relative ones resolved."""
    here = _module_name(path).split(".")
    pkg = here if path.name == "__init__.py" else here[:-1]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - (node.level - 1)] + ([node.module] if node.module else [])
                yield ".".join(base), node.lineno
            else:
                yield node.module, node.lineno


@pytest.mark.parametrize("path", _contract_files(), ids=lambda p: str(p.relative_to(CONTRACT)))
def test_contract_imports_only_allowed_modules(path):
    bad = []
    for name, line in _imported(path):
        top = name.split(".")[0]
        if name == "torch_recon.contract" or name.startswith("torch_recon.contract."):
            continue
        if top in sys.stdlib_module_names or top in ALLOWED_THIRD_PARTY or top == "__future__":
            continue
        bad.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    assert not bad, "\n".join(bad)


def test_package_root_imports_nothing():
    tree = ast.parse((REPO / "torch_recon" / "__init__.py").read_text(encoding="utf-8"))
    assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]


def test_contract_modules_import_with_bpy_and_torch_blocked():
    """Import every contract module in a fresh interpreter where bpy, torch, pipeline and addon cannot load."""
    modules = sorted({_module_name(p) for p in _contract_files()})
    script = f"""
import importlib, importlib.abc, sys
BLOCKED = {BLOCKED!r}
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in BLOCKED:
            raise ImportError('blocked by the layer test: ' + name)
        return None
sys.meta_path.insert(0, Block())
for m in {modules!r}:
    importlib.import_module(m)
leaked = sorted(k for k in sys.modules if k.split('.')[0] in BLOCKED)
assert not leaked, leaked
print('ok', len({modules!r}))
"""
    r = subprocess.run([sys.executable, "-c", script], cwd=REPO, capture_output=True, text=True, timeout=120,
                       env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.startswith("ok")
