"""OBJ text (issue 11's speed, session 17): byte for byte what trimesh's export_obj writes, less the material lines."""

from __future__ import annotations

import re

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from torch_recon.mesh_export import write_mesh  # noqa: E402
from torch_recon.mesh_obj import obj_text  # noqa: E402


def trimesh_text(mesh) -> str:
    """write_mesh's OBJ text before session 17: trimesh's, its mtllib / usemtl lines dropped."""
    from trimesh.exchange.obj import export_obj

    text, _ = export_obj(mesh, include_texture=True, return_texture=True, mtl_name="m.mtl")
    return re.sub(r"^(?:mtllib|usemtl)\b[^\n]*\n?", "", text, flags=re.MULTILINE)


def _meshes():
    rng = np.random.default_rng(7)
    sphere = trimesh.creation.icosphere(subdivisions=2)
    # awkward numbers: -0.0, values that round to -0.00000000, large and tiny magnitudes, float32 UVs
    v = np.asarray(sphere.vertices) * rng.uniform(1e-9, 1e3, (len(sphere.vertices), 1))
    v[:5] = [[-0.0, 0.0, -4e-9], [1e-12, -5e-9, 5e-9], [123456.789012345, -0.5, 0.125], [2.5e-9, 7.5e-9, -1.5e-9],
             [1.0, -1.0, 0.0]]
    plain = trimesh.Trimesh(v, sphere.faces, process=False)
    uv64 = rng.uniform(0.0, 1.0, (len(v), 2))
    uv64[:3] = [[0.0, 1.0], [-0.0, 0.999999995], [0.123456785, 0.5]]
    textured = trimesh.Trimesh(v, sphere.faces, process=False, visual=trimesh.visual.TextureVisuals(uv=uv64))
    uv32 = trimesh.Trimesh(v, sphere.faces, process=False,
                           visual=trimesh.visual.TextureVisuals(uv=uv64.astype(np.float32)))
    return {"plain": plain, "uv64": textured, "uv32": uv32}


@pytest.mark.parametrize("name", ["plain", "uv64", "uv32"])
def test_obj_text_is_trimeshs_byte_for_byte(name):
    mesh = _meshes()[name]
    assert obj_text(mesh) == trimesh_text(mesh)


def test_other_meshes_fall_back_to_trimesh(tmp_path):
    """Cached vertex normals (trimesh then writes 'vn'), vertex colours or a name: trimesh writes the file."""
    base = _meshes()["plain"]
    normals = base.copy()
    normals.vertex_normals          # noqa: B018 - cached now: export_obj writes 'vn' lines
    coloured = base.copy()
    coloured.visual.vertex_colors = np.tile([200, 10, 10, 255], (len(base.vertices), 1))
    named = base.copy()
    named.metadata["name"] = "part"
    for mesh in (normals, coloured, named):
        assert obj_text(mesh) is None
        assert write_mesh(mesh, tmp_path / "m.obj").read_text().startswith("# https://github.com/mikedh/trimesh")


def test_write_mesh_obj_is_the_same_file(tmp_path):
    """write_mesh through obj_text writes the bytes the trimesh path wrote (the y-up file frame included)."""
    from torch_recon.mesh_export import _to_file_frame

    for name, mesh in _meshes().items():
        path = write_mesh(mesh, tmp_path / f"{name}.obj")
        expected = trimesh_text(_to_file_frame(mesh, ".obj"))
        assert path.read_bytes() == expected.encode()
