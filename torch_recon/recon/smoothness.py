"""A smoothness prior on the fast mode's surface that acts under Adam's large epsilon.

Why not total variation on the raw density: the start field is a signed-distance ramp (raw rises by
`surface_slope` per voxel across every visible surface), so penalising raw differences flattens the ramp
everywhere instead of the lumps; and as a mean over the 2 M voxels its gradient per voxel (~1e-8) is far
below Adam's epsilon (`fast.adam_eps`, 1e-3), so it never moved a voxel (session 7: 10x its weight gave
the same mesh).

What this prior penalises instead: disagreement between the surface normals of neighbouring surface
cells, n = grad(raw) / |grad(raw)|. A plane costs (nearly) nothing whatever the ramp's profile and
offset; a lump or a spike tilts the normals around it. Pairs whose normals already differ
by more than `max_angle_deg` (a real edge or corner, the two sides of a thin slab, around a thin leg)
are left alone, so edges and thin parts are not rounded away. The term is a sum over pairs, not a mean:
its gradient at a voxel depends on the local shape only, not on the grid's size, and its weight is chosen
against Adam's epsilon (docs/reconstruction.md, "A smoothness prior that acts").

The surface cells are found again with the occupancy (every `fast.occupancy_update_every` steps), so a
step only gathers their corners (cave-chair 128: 88 k of the 2.1 M cells).
"""

from __future__ import annotations

import math

import torch

#: keeps a normal finite where the raw density is flat (raw units per voxel)
MIN_GRADIENT_PER_VOXEL = 0.5


def surface_cells(raw: torch.Tensor, level: float) -> torch.Tensor:
    """Flat indices (lowest corner) of the cells of `raw` (1, 1, nz, ny, nx) whose 8 corners straddle `level`."""
    with torch.no_grad():
        r = raw[0, 0]
        nz, ny, nx = r.shape
        corners = torch.stack([r[k:nz - 1 + k, j:ny - 1 + j, i:nx - 1 + i]
                               for k in (0, 1) for j in (0, 1) for i in (0, 1)])
        surface = torch.zeros_like(r, dtype=torch.bool)
        surface[:-1, :-1, :-1] = (corners.amin(0) < level) & (corners.amax(0) >= level)
        return torch.nonzero(surface.reshape(-1)).reshape(-1)


class NormalConsistencyPrior:
    """sum over neighbouring surface cells (a, b) with angle(n_a, n_b) < max_angle of |n_a - n_b|^2.

    A cell is the cube between 8 voxel centres (what marching cubes meshes); the surface cells are those
    whose corners straddle the surface level; n is the gradient of the trilinear field at the cell's
    centre (forward differences averaged over the cell's 4 parallel edges), normalised. On a plane that
    is exact up to a few degrees whatever the plane's offset, also where the start's ramp is clamped one
    voxel inside the solid; central differences at voxels there lost the tilt (measured on a tilted ramp:
    up to the full tilt) and the prior rippled flat walls."""

    def __init__(self, raw: torch.Tensor, level: float | None, max_angle_deg: float = 30.0,
                 cells: torch.Tensor | None = None):
        """`raw`: the grid's raw density (1, 1, nz, ny, nx); `level`: its surface value; or `cells` (the
        `cells` of an earlier prior on this grid, e.g. from a checkpoint) instead of finding them in `raw`."""
        _, _, _, ny, nx = raw.shape
        self.strides = (1, nx, nx * ny)          # flat-index step along x, y, z
        self.cos_min = math.cos(math.radians(max_angle_deg))
        dev = raw.device
        with torch.no_grad():
            self.cells = surface_cells(raw, level) if cells is None else cells.to(dev)
            n_vox = raw.numel()
            lookup = torch.full((n_vox,), -1, dtype=torch.long, device=dev)
            lookup[self.cells] = torch.arange(self.cells.numel(), device=dev)
            pairs_a, pairs_b = [], []
            for st in self.strides:         # each pair once: a cell and its +x, +y, +z neighbour
                j = lookup[(self.cells + st).clamp(max=n_vox - 1)]
                keep = j >= 0
                pairs_a.append(torch.nonzero(keep).reshape(-1))
                pairs_b.append(j[keep])
            self.pair_a, self.pair_b = torch.cat(pairs_a), torch.cat(pairs_b)
            # the cells' 8 corners (flat voxel indices, z y x bit order) and the trilinear gradient as a matrix
            sx, sy, sz = self.strides
            bits = [(k, j, i) for k in (0, 1) for j in (0, 1) for i in (0, 1)]
            offs = torch.tensor([k * sz + j * sy + i * sx for k, j, i in bits], device=dev)
            self.corners = (offs[:, None] + self.cells[None, :]).reshape(-1).contiguous()    # (8, C) flat
            self.diff = torch.tensor([[(2 * i - 1) / 4, (2 * j - 1) / 4, (2 * k - 1) / 4] for k, j, i in bits],
                                     dtype=raw.dtype, device=dev).T.contiguous()    # (3, 8): mean of 4 edges per axis

    @property
    def band_size(self) -> int:
        return int(self.cells.numel())

    def normals(self, raw: torch.Tensor) -> torch.Tensor:
        """Unit normals (3: x, y, z; C) of the surface cells (towards higher density), differentiable.
        Laid out (3, C) so that the sums over x, y, z are adds of contiguous rows (faster on a CPU)."""
        g = self.diff @ raw.reshape(-1).index_select(0, self.corners).view(8, -1)
        return g / (g.square().sum(0) + MIN_GRADIENT_PER_VOXEL ** 2).sqrt()

    def __call__(self, raw: torch.Tensor) -> torch.Tensor:
        if self.pair_a.numel() == 0:
            return raw.new_zeros(())
        n = self.normals(raw)
        nn = n.square().sum(0)
        na_nb = (n.index_select(1, self.pair_a) * n.index_select(1, self.pair_b)).sum(0)
        sq_a, sq_b = nn.index_select(0, self.pair_a), nn.index_select(0, self.pair_b)
        with torch.no_grad():      # edges, corners, thin slabs and legs: normals far apart, not smoothed
            similar = na_nb > self.cos_min * (sq_a * sq_b).sqrt()
        return ((sq_a + sq_b - 2.0 * na_nb) * similar).sum()       # |n_a - n_b|^2
