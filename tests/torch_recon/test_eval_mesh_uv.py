"""UV atlas packing size: the charts (and so vertices and faces) do not depend on it, only the UVs."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("xatlas")
trimesh = pytest.importorskip("trimesh")

from torch_recon.mesh_export import write_mesh  # noqa: E402
from torch_recon.mesh_uv import uv_unwrap  # noqa: E402


def test_packing_size_changes_only_where_charts_lie(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=4)          # 5120 faces: 3 blocks of <= 2000
    small = uv_unwrap(mesh, tile_texels=64)
    own = uv_unwrap(mesh, tile_texels=0)                        # xatlas' own atlas size
    assert np.array_equal(small.vertices, own.vertices) and np.array_equal(small.faces, own.faces)
    for m in (small, own):
        uv = np.asarray(m.visual.uv)
        assert uv.shape == (len(m.vertices), 2) and uv.min() >= 0.0 and uv.max() <= 1.0
    assert not np.array_equal(small.visual.uv, own.visual.uv)
    # every face's UVs stay inside its block's tile of the 2 x 2 grid
    tile = np.floor(np.asarray(small.visual.uv)[small.faces] * 2).astype(int)
    assert np.all(tile == tile[:, :1])
    path = write_mesh(small, tmp_path / "m.obj")               # OBJ without material lines, UVs kept
    text = path.read_text()
    assert "mtllib" not in text and "usemtl" not in text and text.count("\nvt ") >= len(small.vertices) - 1
