"""Adam for the fast mode's density grid without `torch.optim`'s Optimizer base class.

`torch.optim.Adam` imports `torch._dynamo` the first time any of its methods runs (`add_param_group`,
`zero_grad`, `step` and `state_dict` are wrapped by `torch._disable_dynamo`): about 2-3 CPU-s of imports per fit
process, more than a tenth of the fast fit's fixed cost (session 17, issue 11). `GridAdam` runs the same arithmetic
as torch's single-tensor Adam on the CPU (`torch.optim.adam._single_tensor_adam` with amsgrad, weight decay,
maximize, capturable and differentiable off: the path `torch.optim.Adam` takes for CPU tensors), operation for
operation, so the trained grid is the same bit for bit; its `state_dict` has torch's layout, so checkpoints
written with either optimizer load into the other.
"""

from __future__ import annotations

import torch

#: the param-group entries of torch.optim.Adam's state_dict (betas and eps set per instance)
_GROUP_DEFAULTS = {"weight_decay": 0, "amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
                   "differentiable": False, "fused": None, "decoupled_weight_decay": False}


def _step_dtype():
    """torch.optim's dtype of the step count (`optimizer._get_scalar_dtype`)."""
    return torch.float64 if torch.get_default_dtype() == torch.float64 else torch.float32


class GridAdam:
    """`torch.optim.Adam(params, lr, betas, eps)` for CPU or GPU float tensors, as the trainer uses it:
    `param_groups` (with "lr", halved after a non-finite step), `zero_grad`, `step`, `state_dict`,
    `load_state_dict`."""

    def __init__(self, params, lr: float, eps: float = 1e-8, betas=(0.9, 0.999)):
        if not lr >= 0.0 or not eps >= 0.0 or not all(0.0 <= b < 1.0 for b in betas):
            raise ValueError(f"Adam: lr {lr}, eps {eps} and betas {betas} must be >= 0 (betas < 1)")
        params = list(params)
        if not params:
            raise ValueError("optimizer got an empty parameter list")
        self.param_groups = [{"params": params, "lr": lr, "betas": tuple(betas), "eps": eps, **_GROUP_DEFAULTS}]
        self.state: dict = {}       # param -> {"step", "exp_avg", "exp_avg_sq"}, created on its first step

    def _params(self):
        return [p for g in self.param_groups for p in g["params"]]

    def zero_grad(self, set_to_none: bool = True) -> None:
        for p in self._params():
            if p.grad is None:
                continue
            if set_to_none:
                p.grad = None
            else:
                p.grad.detach_().zero_()

    @torch.no_grad()
    def step(self) -> None:
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            lr, eps = group["lr"], group["eps"]
            for param in group["params"]:
                if param.grad is None:
                    continue
                grad = param.grad
                state = self.state.get(param)
                if not state:       # torch keeps the step count on the CPU (capturable and fused off)
                    state = self.state[param] = {
                        "step": torch.tensor(0.0, dtype=_step_dtype()),
                        "exp_avg": torch.zeros_like(param, memory_format=torch.preserve_format),
                        "exp_avg_sq": torch.zeros_like(param, memory_format=torch.preserve_format)}
                step_t, exp_avg, exp_avg_sq = state["step"], state["exp_avg"], state["exp_avg_sq"]
                step_t += 1
                exp_avg.lerp_(grad, 1 - beta1)
                exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
                step = step_t.item()
                bias_correction1 = 1 - beta1 ** step
                bias_correction2 = 1 - beta2 ** step
                step_size = lr / bias_correction1
                denom = (exp_avg_sq.sqrt() / bias_correction2 ** 0.5).add_(eps)
                param.addcdiv_(exp_avg, denom, value=-step_size)

    def state_dict(self) -> dict:
        """torch.optim.Optimizer's layout: parameters by their index over the groups; the state dicts themselves
        (not copies, as torch's; the trainer's snapshots deep-copy them)."""
        index = {id(p): i for i, p in enumerate(self._params())}
        groups, start = [], 0
        for g in self.param_groups:
            groups.append({**{k: v for k, v in g.items() if k != "params"},
                           "params": list(range(start, start + len(g["params"])))})
            start += len(g["params"])
        return {"state": {index[id(p)]: s for p, s in self.state.items()}, "param_groups": groups}

    def load_state_dict(self, state_dict: dict) -> None:
        """A state dict of this class or of torch.optim.Adam: the saved group settings (lr included) replace the
        current ones, as torch's does; moments move to their parameter's device and dtype, the step count stays."""
        saved = state_dict["param_groups"]
        if len(saved) != len(self.param_groups) or any(len(s["params"]) != len(g["params"])
                                                       for s, g in zip(saved, self.param_groups)):
            raise ValueError("loaded state dict has a different number of parameter groups or parameters")
        params = self._params()
        self.state = {}
        for i, s in state_dict["state"].items():
            p = params[int(i)]
            self.state[p] = {k: (v if not torch.is_tensor(v) else v if k == "step"
                                 else v.to(dtype=p.dtype, device=p.device)) for k, v in s.items()}
            if "step" in self.state[p] and not torch.is_tensor(self.state[p]["step"]):    # an old torch's number
                self.state[p]["step"] = torch.tensor(float(self.state[p]["step"]), dtype=_step_dtype())
        self.param_groups = [{**{k: v for k, v in s.items() if k != "params"}, "params": g["params"]}
                             for s, g in zip(saved, self.param_groups)]
