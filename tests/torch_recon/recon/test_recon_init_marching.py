"""The carving's sample marching (recon/segment_crossings.py) counts exactly what one globally padded march counts.

The fast start's voxel counts drive the labels and the shadow-explanation score, so the faster marching
(segments longest first, per-chunk padding, one axis at a time) must give the same integers.
"""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from torch_recon.recon.fields import GridBox  # noqa: E402
from torch_recon.recon.segment_crossings import accumulate_crossings, marching_cells  # noqa: E402
from torch_recon.recon.fields import dilate_cube  # noqa: E402
from torch_recon.recon.sampler import marching_intervals  # noqa: E402


def _reference_counts(box, origins, dirs, near, far, step, core=0.5):
    """One padded (R, n, 3) march over every segment at once, as the fast start counted before."""
    nx, ny, nz = box.shape
    t0, t1 = marching_intervals(near, far, step)
    pts = origins[:, None] + dirs[:, None] * (0.5 * (t0 + t1))[..., None]
    idx, inside = box.cell_index(pts)
    keep = inside & (t1 > t0)
    if core < 0.5:
        frac = (pts - box.bbox_min) / box.voxel - idx
        keep &= ((frac - 0.5).abs() <= core).all(-1)
    flat = (idx[..., 0] * ny + idx[..., 1]) * nz + idx[..., 2]
    return torch.bincount(flat[keep], minlength=nx * ny * nz)


def pair_segments(n, seed=0):
    """Segments of very different lengths, some leaving the box, some of zero length."""
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(n, 3, generator=g) * 1.4 - 0.2
    b = torch.rand(n, 3, generator=g) * 1.4 - 0.2
    b[:5] = a[:5]                                           # zero length
    v = b - a
    length = torch.linalg.vector_norm(v, dim=-1).clamp_min(1e-6)
    near = torch.rand(n, generator=g) * 0.05
    return a, v / length[:, None], near, length


@pytest.mark.parametrize("core", [0.5, 0.3])
def test_marching_counts_equal_one_padded_march(core):
    box = GridBox([0.0, 0.0, 0.0], [1.0, 0.7, 0.9], 23)
    seg = pair_segments(400)
    step = 0.5 * box.voxel
    ref = _reference_counts(box, *seg, step, core)
    got = torch.zeros(int(np.prod(box.shape)), dtype=torch.long)
    accumulate_crossings(box, *seg, step, got, chunk_samples=997, core=core)     # many small chunks
    assert int(ref.sum()) > 1000
    assert torch.equal(got, ref)


def test_marching_cells_yield_each_segment_once():
    box = GridBox([0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 16)
    seg = pair_segments(300, seed=1)
    rays = torch.cat([r for r, _, _ in marching_cells(box, *seg, 0.03, chunk_samples=500)])
    assert torch.equal(torch.sort(rays).values, torch.arange(300))


@pytest.mark.parametrize("r", [1, 3])
def test_cube_dilation_equals_a_3d_max_pool(r):
    x = (torch.rand(9, 14, 11, generator=torch.Generator().manual_seed(r)) > 0.97).float()
    ref = torch.nn.functional.max_pool3d(x[None, None], 2 * r + 1, 1, r)[0, 0]
    assert torch.equal(dilate_cube(x, r), ref)
