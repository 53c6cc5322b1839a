"""One-voxel sheets in the mesh field: a wall thinner than a voxel, placed inside its voxel (`fast.mesh_sheet_inset_voxels`).

A 1 cm lamp-shade wall that the shadows put back (restored blockers, `voxel_evidence.explain_shadows`) or that no lit ray
crossed is a sheet of whole 3.2 cm voxels, free on both sides across it. Marching cubes puts its two faces half a
voxel either side of the voxel centre, and the wall lies anywhere inside: one face is up to 2.7 cm from it (session
14: 2-3 cm samples are 13.5 % of the lamp's, more than its lumps beyond 5 cm). Lowering the sheet's voxels so that
both crossings lie `inset` voxel inside the face puts them (0.5 - inset) voxel from the centre: at inset 0.25 (0.8 cm)
each face lies within 1.9 cm of a 1 cm wall anywhere in the voxel (the whole voxel: up to 2.7 cm). A leg or a pole (a column:
occupied in-plane neighbours only along it) keeps its faces: the part there may lie off the voxel's centre
(the lamp pole's top, session 12). Training lowers the raw density of the hull and of restored voxels without
emptying them (opacity still 1): a voxel counts as occupied here when above the lowered value, saturated or not.
"""

from __future__ import annotations

import torch

from .fields import beside_ramp, shifted


def one_voxel_sheets(occupied: torch.Tensor, free: torch.Tensor, min_in_plane: int, max_run: int = 1) -> torch.Tensor:
    """Occupied voxels (nx, ny, nz bool) on a run across some axis from free space to free space again at most
    `max_run` voxels long, with at least `min_in_plane` of their 8 neighbours in the plane across that axis
    occupied: a sheet one (or up to `max_run`) voxels thick."""
    sheet = torch.zeros_like(occupied)
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        in_plane = torch.zeros(occupied.shape, dtype=torch.int32, device=occupied.device)
        for i in (-1, 0, 1):
            for j in (-1, 0, 1):
                if i == 0 and j == 0:
                    continue
                off = [0, 0, 0]
                off[others[0]], off[others[1]] = i, j
                in_plane += shifted(occupied, off, False, max_run).int()
        for sign in (-1, 1):
            along = lambda m, t, fill: shifted(m, [sign * t if a == axis else 0 for a in range(3)], fill, max_run)  # noqa: E731
            run, thin = along(free, -1, True), torch.zeros_like(occupied)
            for t in range(1, max_run + 1):
                thin |= run & along(free, t, True)
                run = run & along(occupied, t, False)
            sheet |= occupied & thin & (in_plane >= min_in_plane)
    return sheet


def sheet_inset(clipped: torch.Tensor, level: float, half: float, inset_voxels: float, min_in_plane: int = 4,
                keep=None, max_run: int = 1, seen=None) -> torch.Tensor:
    """`clipped` (raw density clipped to [level - half, level + half], nx, ny, nz) with the voxels of sheets up to
    `max_run` voxels thick (`one_voxel_sheets` of the voxels above the lowered value) lowered so that their crossings
    with saturated free neighbours lie `inset_voxels` inside the midpoint (as `models.binary_boundary_inset` lowers
    saturated two-voxel slabs). keep: voxels never lowered (thin parts); a voxel next to a measured surface's outer
    ramp is never lowered either. seen: voxels (nx, ny, nz bool) the sensor saw through: free space there does not
    end a sheet (the slab behind a measured face is that part's thickness, a chair's seat, not a wall inside it)."""
    target = level - half + half / (0.5 + inset_voxels)
    occ = clipped > target      # training lowers the hull's raw (opacity still 1): saturated or not, above the target
    free = clipped <= level - half + 1e-4
    if seen is not None:
        free = free & ~seen.to(free.device)
    lower = one_voxel_sheets(occ, free, min_in_plane, max_run) & ~beside_ramp(clipped, level, half)
    if keep is not None:
        lower &= ~keep.to(lower.device)
    out = clipped.clone()
    out[lower] = target
    return out
