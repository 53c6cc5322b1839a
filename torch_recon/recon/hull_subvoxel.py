"""The shadow hull's faces that no camera ray places, below voxel granularity (session 13, issue 11).

The hull is binary: an uncarved voxel next to a carved one meets marching cubes at their shared voxel face,
wherever inside the 3.2 cm voxels the object ends. The lit segments cannot place those faces finer: whole-voxel
carving (any marching sample carves) already takes every voxel a lit segment passes through, so no hull voxel
holds a lit segment within half a voxel of its centre, and the faces lie inside the lit segments' envelope
(organic-occluded, dark-room; docs/reconstruction.md). A visual hull over-estimates its object where no light
came near, so the mesh's hull vertices are smoothed inward by a bounded amount (mesh_export `inward_smoothing`,
`fast.mesh_hull_shrink_voxels`): a staircase's convex steps are cut. Not at a shadow's edge: a shadowed segment
that grazes the hull there needs its blocker in that voxel (the object reaches it).
`binary_boundary_inset` (`fast.mesh_hull_inset_voxels`) places a kept hull voxel's faces inside their voxel face.
Which voxels lit segments cross is read back from the start field's evidence (`voxel_evidence.VoxelEvidence`, the
same march: session 14, issue 11), not marched again at export.
"""

from __future__ import annotations

import torch

from .data import lit_path_tolerance, unexplained_lit
from .fields import beside_ramp, next_to, shifted
from .hull_trim import sole_blockers
from .sampler import ray_box
from .segment_crossings import accumulate_crossings, pair_segments
from .voxel_evidence import VoxelEvidence, carving_pixel_mask

#: Laplacian steps of the inward smoothing (each moves a vertex half-way to its neighbours' mean at most)
SHRINK_ITERATIONS = 10


def hull_voxels(start_raw: torch.Tensor, raw_free: float, raw_occupied: float, lit_crossed: torch.Tensor, keep=None):
    """Occupied voxels of the start field `start_raw` (nx, ny, nz; training barely moves them, session 5) that no
    lit segment crossed (`lit_crossed`, bool; the shadow hull proper: not a restored blocker, which the light
    crossed, nor a thin part in `keep`), next to a free voxel and not next to a measured surface's ramp (that
    surface would move)."""
    occ = start_raw >= raw_occupied - 1e-3
    free = start_raw <= raw_free + 1e-3
    ramp = ~occ & ~free
    hull = occ & ~lit_crossed & next_to(free) & ~next_to(ramp)
    return hull if keep is None else hull & ~keep.to(hull.device)


def camera_free(model, box) -> torch.Tensor:
    """Voxels (nx, ny, nz) bool a camera ray crossed before its visible surface (as `evidence_grid`'s label 2,
    every pixel): the sensor saw through them. Not the evidence's label 2, which stops at a pixel's nearest return
    (`fast.nearest_free`), marches the carving pixels only and adds the footprints' `seen_free`."""
    data, fc = model.data, model.fc
    d = data.visible_depth
    ok = torch.isfinite(d)
    dirs = data.pixel_dirs[ok]
    org = data.sensor_origin.expand_as(dirs).contiguous()
    near, _ = ray_box(org, dirs, box.bbox_min, box.bbox_max)
    count = torch.zeros(int(torch.tensor(box.shape).prod()), dtype=torch.long, device=dirs.device)
    accumulate_crossings(box, org, dirs, near, torch.maximum(d[ok] - fc.surface_margin_voxels * box.voxel, near),
                fc.step_voxels * box.voxel, count)
    return (count > 0).reshape(box.shape)


def carving_segments(model, lit: bool):
    """`pair_segments` of the carving pixels' lit (`lit`) or shadowed pairs, as the start field's labelling marched
    them (`evidence_grid`: its offset; a lit pair whose path disagrees with its pixel from its own range)."""
    data, fc, box = model.data, model.fc, model.grid.box
    off = max(model.offset_for(box.voxel), fc.surface_margin_voxels * box.voxel)     # as evidence_grid's
    on_sub = carving_pixel_mask(data, box, fc.carve_spacing_voxels)[data.pair_pixel]
    if not lit:
        return pair_segments(data, data.shadowed & on_sub, off)
    tol = lit_path_tolerance(data, box.voxel, fc.lit_path_tolerance_voxels)
    return pair_segments(data, data.lit & on_sub, off, unexplained_lit(data, tol) if tol > 0 else None)


def unmeasured_hull(model, start_raw: torch.Tensor, evidence: VoxelEvidence, occupied=None) -> torch.Tensor:
    """`hull_voxels` of the start field with its own carving (`evidence`), less the model's thin parts, still
    `occupied` in the mesh field: the hull no measured surface, lit segment or thin part places (nx, ny, nz) bool."""
    keep = None if model.thin_parts is None else model.thin_parts[0, 0].permute(2, 1, 0)
    lit = evidence.lit_crossed
    hull = hull_voxels(start_raw.to(lit.device), model.fc.raw_free, model.fc.raw_occupied, lit, keep)
    return hull if occupied is None else hull & occupied.to(hull.device)


def shrinkable_hull(model, start_raw: torch.Tensor, evidence: VoxelEvidence, graze_samples: int, occupied=None,
                    silhouettes: bool = True) -> torch.Tensor:
    """The hull voxels (nx, ny, nz) bool whose mesh vertices may move inward: `hull_voxels` of the start field with
    the start's own carving (its `evidence`), still `occupied` in the mesh field (not lowered by training or the hull
    inset), less the voxels a shadowed segment grazes (crossing at most `graze_samples` marching samples of the hull:
    `hull_trim.sole_blockers`, the shadow's edge) and, with `silhouettes`, the voxels next to camera-free ones."""
    fc, box = model.fc, model.grid.box
    step = fc.step_voxels * box.voxel
    start_raw = start_raw.to(evidence.lit_crossed.device)
    hull = unmeasured_hull(model, start_raw, evidence, occupied)
    if silhouettes:     # a face the sensor saw past is its silhouette, placed to a pixel
        hull &= ~next_to(camera_free(model, box).to(hull.device))
    if graze_samples > 0:
        solid = (start_raw > fc.raw_free + 1e-3).reshape(-1)
        edge = sole_blockers(box, solid, carving_segments(model, lit=False), step, max_samples=graze_samples)
        hull &= ~edge.reshape(box.shape)
    return hull


def binary_boundary_inset(clipped, level: float, half: float, inset_voxels: float, max_thickness_voxels: int = 0,
                          keep=None, min_thickness_voxels: int = 1) -> torch.Tensor:
    """Marching cubes crosses from a saturated free voxel (level - half) to a saturated occupied one
    (level + half) at their midpoint, a voxel face. Where a kept hull voxel holds the part somewhere inside
    (flat and thin parts, restored blockers) the true surface lies inside that face: lower the occupied voxels
    next to a saturated free one (6-neighbours) so that this crossing lies `inset_voxels` inside the midpoint.
    A one-voxel part then keeps a thickness of 1 - 2 inset voxels. (Where whole-voxel carving already put the
    hull inside the part, the organic blob, it moves the wrong way.)
    max_thickness_voxels > 0: only where the occupied run across that face, from the free neighbour on, is
    min_thickness_voxels .. max_thickness_voxels long before free space again (a slab the part lies somewhere
    inside: a 1 cm lamp-shade wall straddling two 3.2 cm voxels); a thick hull keeps its faces, and a run of one
    voxel (a leg or a restored blocker, the part at its centre) too with min 2. keep: bool (nx, ny, nz), voxels
    never lowered (thin parts placed at their voxel's centre by measurement). A voxel next to a measured
    surface's outer ramp is never lowered (that surface would move).
    clipped: (nx, ny, nz) raw density clipped to [level - half, level + half]."""
    occ = clipped >= level + half - 1e-4
    m = 1 + max(int(max_thickness_voxels), 0)
    free = clipped <= level - half + 1e-4

    def at(mask, axis, t):      # mask[v + t e_axis] for every voxel v (False outside the box)
        return shifted(mask, [t if a == axis else 0 for a in range(3)], False, m)

    lower = torch.zeros_like(occ)
    for axis in range(3):
        for sign in (-1, 1):
            face = at(free, axis, sign)
            if max_thickness_voxels > 0:     # free again after a run of min..max voxels on the other side
                run, thin = torch.ones_like(occ), torch.zeros_like(occ)
                for t in range(1, int(max_thickness_voxels) + 1):
                    after = at(free, axis, -sign * t)
                    if t >= min_thickness_voxels:
                        thin = thin | (run & after)
                    run = run & ~after
                face = face & thin      # (not in place: `at` gives views of the masks)
            lower |= face
    lower &= ~beside_ramp(clipped, level, half)      # (that measured surface would move too)
    lower &= occ if keep is None else occ & ~keep.to(occ.device)
    out = clipped.clone()
    out[lower] = level - half + half / (0.5 + inset_voxels)
    return out
