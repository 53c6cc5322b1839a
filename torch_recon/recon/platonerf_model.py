"""PlatoNeRF's reconstructor: two NeRF MLPs trained the way the authors' published code trains them.

Reference: facebookresearch/PlatoNeRF, src/run_platonerf.py with configs/chair.txt (read, not copied).
Per step, for the fine and for the coarse camera depth d (each rendered hierarchically, 64 + 128):
    path = (d + |l - x| + |l - o|) / 15 with x = c + d u
    warm-up (lit pairs only):  plain MSE(path, measured / 15)
    afterwards (all pairs):    6000 MSE(path, measured / 15 | lit)
                               + MSE(T | shadowed) + MSE(1 - T | lit) for T of the secondary ray x -> l
                                 through both the fine and the coarse network
and the loss is 100 x (fine term + coarse term). When the gradient of the coarse network's weights (theirs;
by default here: of either network's) is exactly zero after a step (a dead ReLU density: the field is
empty and nothing can change that), both networks and the optimiser are re-created, from the networks saved every 5000 steps when there are
such, otherwise from a fresh random initialisation. Deliberate differences: docs/reconstruction.md.
"""

from __future__ import annotations

import copy

import torch

from .config import FitConfig
from .data import RayData
from .fields import GridBox, NeRFField
from .init import scene_bbox
from .losses import distance_loss, in_warmup, shadow_loss
from .model_interface import ReconstructionModel, rendered_depth
from .platonerf_render import render_hierarchical


class PlatoNeRFModel(ReconstructionModel):
    """Coarse + fine NeRF density MLPs, hierarchical sampling and the authors' loss and schedule."""

    plateau_stop = False    # the authors' schedule runs all its steps (no early stop)

    def __init__(self, data: RayData, cfg: FitConfig, meas_meta: dict, generator: torch.Generator):
        self.data, self.cfg, self.pc = data, cfg, cfg.platonerf
        self.device = data.pixel_dirs.device
        lo, hi = scene_bbox(data, 0.05)     # only for the mesh volume and far_m None
        self.bbox = (torch.as_tensor(lo, device=self.device), torch.as_tensor(hi, device=self.device))
        self.gen = generator
        self.reinit_steps: list[int] = []
        self.saved = None                   # (coarse, fine) state dicts, every reinit_snapshot_every steps
        self._create()

    def _create(self):
        kw = dict(depth=self.pc.depth, width=self.pc.width, skip=self.pc.skip, pe_frequencies=self.pc.pe_frequencies)
        self.coarse = NeRFField(**kw).to(self.device)
        self.fine = NeRFField(**kw).to(self.device)
        self.make_optimizer()

    def make_optimizer(self):
        self.optimizer = torch.optim.Adam(list(self.coarse.parameters()) + list(self.fine.parameters()),
                                          lr=self.pc.lr, betas=(0.9, 0.999))

    def before_step(self, step: int, total: int) -> bool:
        lr = self.pc.lr * 0.1 ** (step / self.pc.lr_decay_steps)
        for g in self.optimizer.param_groups:
            g["lr"] = lr
        return False

    @staticmethod
    def weight_grad_norm(field) -> torch.Tensor:
        """L2 norm of the gradient of a network's layer weights (biases excluded, as theirs), on the device."""
        sq = [p.grad.pow(2).sum() for n, p in field.named_parameters() if n.endswith("weight") and p.grad is not None]
        return torch.stack(sq).sum().sqrt() if sq else torch.zeros((), device=field.centre.device)

    def dead(self) -> bool:
        """A network whose weights got an exactly zero gradient: theirs watches the coarse one only;
        'both' also catches a dead fine network (6 of 20 seeds on the test scene), which would
        otherwise leave the output field empty for good. One device sync per step."""
        if self.pc.reinit_dead == "off":
            return False
        nets = (self.coarse,) if self.pc.reinit_dead == "coarse" else (self.coarse, self.fine)
        return bool((torch.stack([self.weight_grad_norm(n) for n in nets]) == 0).any())

    def after_step(self, step: int) -> bool:
        """The authors' re-initialisation; True when it fired. `step` counts the steps done."""
        if self.dead():
            self._create()
            if self.saved is not None:
                self.coarse.load_state_dict(self.saved[0])
                self.fine.load_state_dict(self.saved[1])
            self.reinit_steps.append(step)
            return True
        if self.pc.reinit_snapshot_every > 0 and step % self.pc.reinit_snapshot_every == 0:
            self.saved = (copy.deepcopy(self.coarse.state_dict()), copy.deepcopy(self.fine.state_dict()))
        return False

    def _camera_bounds(self, o, d, near_m):
        near = torch.full_like(o[:, 0], near_m)
        if self.pc.far_m is None:
            from .sampler import ray_box

            far = torch.maximum(ray_box(o, d, *self.bbox)[1], near + 1e-3)
        else:
            far = torch.full_like(near, self.pc.far_m)
        return near, far

    def _render(self, o, d, near, far, train: bool):
        return render_hierarchical(self.coarse, self.fine, o, d, near, far, self.pc.coarse_samples,
                                   self.pc.fine_samples, perturb=train, generator=self.gen)

    def loss(self, idx, step, total, gen):
        data, lc = self.data, self.cfg.loss
        px, sp = data.pair_pixel[idx], data.pair_spot[idx]
        u = data.pixel_dirs[px]
        c = data.sensor_origin.expand_as(u)
        l = data.spot_points[sp]
        lit, shadowed = data.lit[idx], data.shadowed[idx]
        warm = in_warmup(step, total, lc)
        near, far = self._camera_bounds(c, u, self.pc.near_m)
        fine, coarse = self._render(c, u, near, far, train=True)
        terms, dists, shadows = [], [], []
        for depth in (fine.depth, coarse.depth):
            x = c + u * depth[:, None]
            v = l - x
            length = torch.linalg.vector_norm(v, dim=-1)
            dist = distance_loss(depth + length + data.laser_to_spot[sp], data.path[idx], lit, lc)
            dists.append(dist.detach())
            if warm:
                terms.append(dist)          # the warm-up loss is the plain MSE (no distance weight)
                continue
            s_near = torch.full_like(length, self.pc.near_m)
            s_far = torch.maximum(length, s_near)   # theirs would sample backwards on shorter segments
            f2, c2 = self._render(x, v / length.clamp(min=1e-6)[:, None], s_near, s_far, train=True)
            shadow = shadow_loss(f2.transmittance, lit, shadowed, lc) + shadow_loss(c2.transmittance, lit, shadowed, lc)
            shadows.append(shadow.detach())
            terms.append(lc.distance_weight * dist + shadow)
        d, sh = torch.stack(dists).sum(), (torch.stack(shadows).sum() if shadows else torch.zeros_like(dists[0]))
        stats = dict(zip(("dist", "shadow"), torch.stack([d, sh]).tolist()))    # one device sync, not four
        return lc.loss_scale * (terms[0] + terms[1]), stats

    @torch.no_grad()
    def render_depth(self, origins, dirs, chunk=4096, min_opacity=None):
        """Their test rendering (fine network, 64 + 128 deterministic samples from test_near_m to far);
        min_opacity None: their depth (the last sample takes what is left); else evaluate's convention."""
        out = []
        for i in range(0, origins.shape[0], chunk):
            o, d = origins[i:i + chunk], dirs[i:i + chunk]
            near, far = self._camera_bounds(o, d, self.pc.test_near_m)
            fine, _ = self._render(o, d, near, far, train=False)
            out.append(fine.depth if min_opacity is None else rendered_depth(fine, far, min_opacity))
        return torch.cat(out) if out else origins.new_zeros(0)

    def density(self, pts):
        if not pts.shape[0]:
            return pts.new_zeros(0)
        with torch.no_grad():
            return torch.cat([self.fine(pts[i:i + 65536]) for i in range(0, pts.shape[0], 65536)])

    @torch.no_grad()
    def density_volume(self):
        box = GridBox(self.bbox[0].cpu(), self.bbox[1].cpu(), self.pc.volume_resolution).to(self.device)
        sigma = self.density(box.centres().reshape(-1, 3))
        op = 1.0 - torch.exp(-sigma * box.voxel)
        return op.reshape(box.shape).cpu().numpy(), box.bbox_min.cpu().numpy(), box.bbox_max.cpu().numpy()

    def params_finite(self) -> bool:
        ps = list(self.coarse.parameters()) + list(self.fine.parameters())
        return bool(torch.stack([torch.isfinite(p).all() for p in ps]).all())      # one device sync

    def state_dict(self):
        clone = lambda sd: {k: v.detach().clone() for k, v in sd.items()}  # noqa: E731
        return {"coarse": clone(self.coarse.state_dict()), "fine": clone(self.fine.state_dict()),
                "optimizer": self.optimizer.state_dict(), "saved": self.saved,
                "reinit_steps": list(self.reinit_steps)}

    def load_state_dict(self, st):
        self.coarse.load_state_dict(st["coarse"])
        self.fine.load_state_dict(st["fine"])
        self.make_optimizer()
        self.optimizer.load_state_dict(st["optimizer"])
        self.saved = st.get("saved")
        self.reinit_steps = list(st.get("reinit_steps", []))
