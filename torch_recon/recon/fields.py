"""Density fields: an explicit voxel grid (fast mode) and PlatoNeRF's MLP with positional encoding.

Both map world points (N, 3) in the Blender frame to a density sigma >= 0 in 1 / m.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from ..contract.errors import MeasurementsError


class GridBox:
    """An axis-aligned box cut into cubic voxels; values live at voxel centres."""

    def __init__(self, bbox_min, bbox_max, resolution: int):
        lo = torch.as_tensor(bbox_min, dtype=torch.float32)
        hi = torch.as_tensor(bbox_max, dtype=torch.float32)
        ext = hi - lo
        if not torch.all(ext > 0):
            raise MeasurementsError(f"reconstruction box: empty bounding box {lo.tolist()} .. {hi.tolist()} "
                                    f"(expected a positive extent on every axis: the measured points are degenerate)")
        self.voxel = float(ext.max()) / int(resolution)
        self.shape = tuple(max(1, int(math.ceil(float(e) / self.voxel - 1e-6))) for e in ext)  # (nx, ny, nz)
        self.bbox_min = lo
        self.bbox_max = lo + torch.tensor(self.shape, dtype=torch.float32, device=lo.device) * self.voxel

    @classmethod
    def exact(cls, bbox_min, voxel: float, shape) -> "GridBox":
        """A box given by its corner, voxel size and voxel counts (as stored in a checkpoint)."""
        b = cls.__new__(cls)
        b.voxel = float(voxel)
        b.shape = tuple(int(n) for n in shape)
        b.bbox_min = torch.as_tensor(bbox_min, dtype=torch.float32)
        b.bbox_max = b.bbox_min + torch.tensor(b.shape, dtype=torch.float32, device=b.bbox_min.device) * b.voxel
        return b

    def to(self, device):
        self.bbox_min, self.bbox_max = self.bbox_min.to(device), self.bbox_max.to(device)
        return self

    def normalised(self, pts: torch.Tensor) -> torch.Tensor:
        """World -> grid_sample coordinates in [-1, 1] (align_corners=False: -1 is the box face)."""
        return 2.0 * (pts - self.bbox_min) / (self.bbox_max - self.bbox_min) - 1.0

    def cell_index(self, pts: torch.Tensor):
        """Integer voxel (ix, iy, iz) of each point and whether it lies inside the box."""
        idx = torch.floor((pts - self.bbox_min) / self.voxel).long()
        size = torch.tensor(self.shape, device=pts.device)
        inside = ((idx >= 0) & (idx < size)).all(-1)
        return idx.clamp(min=0).minimum(size - 1), inside

    def centres(self) -> torch.Tensor:
        """(nx, ny, nz, 3) world coordinates of the voxel centres."""
        axes = [self.bbox_min[i] + (torch.arange(n, device=self.bbox_min.device) + 0.5) * self.voxel
                for i, n in enumerate(self.shape)]
        return torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)

    def near_points(self, points: torch.Tensor, radius_m: float) -> torch.Tensor:
        """bool (nx, ny, nz): voxels whose centre lies within radius_m of one of points (N, 3)."""
        out = torch.zeros(self.shape, dtype=torch.bool, device=self.bbox_min.device)
        r = int(math.ceil(radius_m / self.voxel)) + 1
        size = torch.tensor(self.shape)
        for p in points.to(self.bbox_min):
            c = torch.floor((p - self.bbox_min) / self.voxel).long().cpu()
            lo, hi = (c - r).clamp(min=0).minimum(size), (c + r + 1).clamp(min=0).minimum(size)
            axes = [self.bbox_min[i] + (torch.arange(int(lo[i]), int(hi[i]), device=out.device) + 0.5) * self.voxel
                    for i in range(3)]
            centres = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1)
            out[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] |= torch.linalg.vector_norm(centres - p, dim=-1) <= radius_m
        return out


def shifted(mask: torch.Tensor, offset, fill: bool = False, pad: int = 1) -> torch.Tensor:
    """mask[v + offset] for every voxel v of a bool (nx, ny, nz) `mask` (offset: 3 ints, each within `pad`); `fill`
    outside the box."""
    p = F.pad(mask.float()[None, None], (pad,) * 6, value=float(fill))[0, 0]
    sl = tuple(slice(pad + o, pad + o + n) for o, n in zip(offset, mask.shape))
    return p[sl] > 0.5


def beside_ramp(clipped: torch.Tensor, level: float, half: float) -> torch.Tensor:
    """Voxels with a 6-neighbour on a measured surface's outer ramp (raw between the saturated free value and the
    level) of the mesh field `clipped` (raw clipped to [level - half, level + half]): lowering such a voxel to move a
    hull's or a sheet's face would move that measured surface too."""
    return next_to((clipped > level - half + 1e-4) & (clipped < level))


def next_to(mask: torch.Tensor) -> torch.Tensor:
    """Voxels with a 6-neighbour in `mask` (nx, ny, nz) bool."""
    p = F.pad(mask.float()[None, None], (1,) * 6)[0, 0]
    n = torch.zeros_like(mask)
    for axis in range(3):
        for t in (0, 2):
            sl = [slice(1, 1 + s) for s in mask.shape]
            sl[axis] = slice(t, t + mask.shape[axis])
            n |= p[tuple(sl)] > 0
    return n


class DensityGrid(nn.Module):
    """sigma(x) = scale * softplus(trilinear(raw)), raw stored as (1, 1, nz, ny, nx) for grid_sample."""

    def __init__(self, box: GridBox, density_scale: float = 50.0, raw: torch.Tensor | None = None):
        super().__init__()
        self.box = box
        self.density_scale = float(density_scale)
        nx, ny, nz = box.shape
        init = torch.zeros(1, 1, nz, ny, nx) if raw is None else raw.reshape(1, 1, nz, ny, nx).float()
        self.raw = nn.Parameter(init.clone())

    @classmethod
    def from_xyz(cls, box: GridBox, raw_xyz: torch.Tensor, density_scale: float):
        """From a (nx, ny, nz) raw-density array indexed like GridBox.cell_index."""
        return cls(box, density_scale, raw_xyz.permute(2, 1, 0).contiguous())

    def raw_xyz(self) -> torch.Tensor:
        return self.raw[0, 0].permute(2, 1, 0)

    def forward(self, pts: torch.Tensor) -> torch.Tensor:
        if pts.numel() == 0:
            return pts.new_zeros(pts.shape[:-1])
        g = self.box.normalised(pts.reshape(1, 1, 1, -1, 3))
        raw = F.grid_sample(self.raw, g, mode="bilinear", padding_mode="border", align_corners=False)
        return self.density_scale * F.softplus(raw.reshape(pts.shape[:-1]))

    def sigma_xyz(self) -> torch.Tensor:
        """Density at the voxel centres (nx, ny, nz), no grad."""
        with torch.no_grad():
            return self.density_scale * F.softplus(self.raw_xyz())

    def upsampled(self, resolution: int) -> "DensityGrid":
        """The same field on a finer grid over (at least) the same box: coarse-to-fine step."""
        box = GridBox(self.box.bbox_min.cpu(), self.box.bbox_max.cpu(), resolution).to(self.raw.device)
        with torch.no_grad():
            g = self.box.normalised(box.centres()).permute(2, 1, 0, 3)[None]  # (1, nz, ny, nx, 3)
            raw = F.grid_sample(self.raw, g, mode="bilinear", padding_mode="border", align_corners=False)
        return DensityGrid(box, self.density_scale, raw)


class PositionalEncoding(nn.Module):
    """NeRF's encoding: x, sin(2^k x), cos(2^k x) for k < L."""

    def __init__(self, frequencies: int = 10):
        super().__init__()
        self.register_buffer("freq", 2.0 ** torch.arange(frequencies, dtype=torch.float32), persistent=False)
        self.out_dim = 3 + 6 * frequencies

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        xf = (x[..., None, :] * self.freq[:, None]).flatten(-2)
        return torch.cat([x, torch.sin(xf), torch.cos(xf)], -1)


class NeRFField(nn.Module):
    """PlatoNeRF's density MLP: depth x width ReLU layers, input re-injected after layer `skip`.

    The paper's network also has an intensity head that no loss supervises; only density is kept.
    """

    def __init__(self, depth: int = 8, width: int = 256, skip: int = 4, pe_frequencies: int = 10,
                 centre=(0.0, 0.0, 0.0)):
        super().__init__()
        self.pe = PositionalEncoding(pe_frequencies)
        self.skip = skip
        self.register_buffer("centre", torch.as_tensor(centre, dtype=torch.float32))
        layers = []
        for i in range(depth):
            fan_in = self.pe.out_dim if i == 0 else width + (self.pe.out_dim if i == skip + 1 else 0)
            layers.append(nn.Linear(fan_in, width))
        self.layers = nn.ModuleList(layers)
        self.density = nn.Linear(width, 1)

    def forward(self, pts: torch.Tensor) -> torch.Tensor:
        e = self.pe(pts.reshape(-1, 3) - self.centre)
        h = e
        for i, layer in enumerate(self.layers):
            if i == self.skip + 1:
                h = torch.cat([h, e], -1)
            h = F.relu(layer(h))
        return F.relu(self.density(h)).reshape(pts.shape[:-1])


def dilate_cube(x: torch.Tensor, r: int) -> torch.Tensor:
    """Maximum over the (2 r + 1)^3 cube around each voxel (cut off at the grid's faces) of x (..., nx, ny, nz), a
    new tensor: the same values as `max_pool3d(x, 2 r + 1, 1, r)`, NaN included. One axis at a time, each a
    maximum with the neighbours on either side r times over: 12 ms for r = 1 on 128^3 voxels where max_pool3d took
    160 ms (and its 1-D kernels one axis at a time 138; session 17, issue 11)."""
    if r <= 0:
        return x.clone()
    for dim in range(x.dim() - 3, x.dim()):
        n = x.shape[dim]
        for _ in range(r):
            y = x.clone()
            lo, hi = y.narrow(dim, 0, n - 1), y.narrow(dim, 1, n - 1)
            torch.maximum(hi, x.narrow(dim, 0, n - 1), out=hi)
            torch.maximum(lo, x.narrow(dim, 1, n - 1), out=lo)
            x = y
    return x
