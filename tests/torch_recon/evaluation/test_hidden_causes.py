"""The hidden-recall diagnostic: where a lit two-bounce segment can carve, and the face directions."""

from __future__ import annotations

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")

from torch_recon.contract.synthetic import default_sensor  # noqa: E402
from torch_recon.evaluation.hidden_causes import face_direction, lit_segment_passes  # noqa: E402


def _quad(corners):
    return trimesh.Trimesh(np.asarray(corners, float), [[0, 1, 2], [0, 2, 3]], process=False)


def test_lit_segment_passes_only_where_light_lands_on_a_seen_surface():
    back = _quad([[-3, 3, -3], [3, 3, -3], [3, 3, 3], [-3, 3, 3]])         # the wall the sensor looks at
    side = _quad([[-2, -1, -3], [-2, 5, -3], [-2, 5, 3], [-2, -1, 3]])     # a side wall, seen at grazing angles
    gt = trimesh.util.concatenate([back, side])
    sensor = default_sensor()                                               # at the origin, looking along +y
    spot = np.array([-2.0, 2.0, 0.0])                                       # the laser spot on the side wall
    q = np.array([[-1.0, 2.5, 0.0],     # light passes here and lands on the back wall in view: carvable
                  [-1.0, 3.5, 0.0],     # behind the back wall: blocked before it
                  [-1.0, 1.0, 0.0],     # the light going on towards -y hits nothing
                  [-1.5, 2.0, 0.0]])    # lands on the back wall? no: towards +x along y = 2, nothing there
    assert lit_segment_passes(q, gt, [spot], sensor).tolist() == [True, False, False, False]


def test_face_direction_names_the_dominant_axis():
    n = np.array([[0.9, 0.1, 0.0], [-0.2, -0.9, 0.1], [0.1, 0.2, -0.95]])
    assert face_direction(n).tolist() == ["+x", "-y", "-z"]


def test_cli_reads_a_glb_in_the_world_frame(synthetic_dataset, tmp_path, capsys):
    """A fit's mesh.glb is written Y-up: read as it is, the box beside the truth's missed every point."""
    import json

    from torch_recon.evaluation.hidden_causes import main
    from torch_recon.mesh_export import export_mesh

    root, _, _ = synthetic_dataset
    room = trimesh.creation.box((3.0, 4.0, 0.02))       # a floor under the dataset's GT box: the box is an object
    room.apply_translation([0.25, 3.0, -1.26])
    box = trimesh.load(root / "ground_truth/mesh.ply", force="mesh", process=False)
    trimesh.util.concatenate([room, box]).export(root / "ground_truth/mesh.ply")
    lo, hi = np.array([-0.5, 1.8, -1.5]), np.array([1.0, 4.2, -0.5])     # the dataset's GT box, a margin round it
    axes = [np.linspace(lo[i], hi[i], 31) for i in range(3)]
    x, y, z = np.meshgrid(*axes, indexing="ij")
    occ = ((np.abs(x - 0.25) < 0.5) & (np.abs(y - 3.0) < 1.0) & (np.abs(z + 1.0) < 0.25)).astype(np.float32)
    export_mesh(occ, lo, hi, 0.5, tmp_path / "rec.glb", {}, extra_formats=(".ply",), uv=False)
    rows = []
    for name in ("rec.glb", "rec.ply"):
        assert main([str(root), str(tmp_path / name)]) == 0
        rows.append(json.loads(capsys.readouterr().out))
    assert rows[0] and rows[0] == rows[1]
    assert all(r["missed"] < r["hidden"] for r in rows[0].values()), rows[0]
