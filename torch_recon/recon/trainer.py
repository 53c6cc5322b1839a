"""The optimisation loop shared by both modes.

Seeded (one torch.Generator draws every batch and stratified sample); checkpoints to
OUT/checkpoint.pt (atomic) every `checkpoint_every_s` and at the end; resumes from it; a tqdm bar
with loss and ETA; Ctrl-C finishes the current step, writes the checkpoint and returns (a second
Ctrl-C aborts at once); a non-finite loss, gradient or parameter is reported and the last good
snapshot restored with half the learning rate; early stop when the loss plateaus.
"""

from __future__ import annotations

import copy
import signal
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..contract.errors import CheckpointError
from .config import FitConfig
from .losses import all_finite, in_warmup

CHECKPOINT_NAME = "checkpoint.pt"
SNAPSHOT_EVERY = 10


@dataclass
class TrainResult:
    steps_done: int = 0
    stopped: str = "done"            # done | plateau | time | interrupted | nan | paused
    train_seconds: float = 0.0
    resumed_from: int | None = None
    nan_restores: int = 0
    history: list = field(default_factory=list)   # {step, seconds, loss, dist, shadow}
    evals: list = field(default_factory=list)     # whatever on_eval returned, with step and seconds


def _config_key(cfg: FitConfig) -> dict:
    d = cfg.to_dict()
    for k in ("max_seconds", "resume", "progress", "eval_every_s", "checkpoint_every_s", "device", "threads"):
        d.pop(k, None)
    return d


def save_checkpoint(path: Path, model, gen: torch.Generator, step: int, cfg: FitConfig, result: TrainResult,
                    data_key: str | None = None):
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"step": step, "model": model.state_dict(), "generator": gen.get_state(),
                "config": _config_key(cfg), "history": result.history, "train_seconds": result.train_seconds,
                "data": data_key}, tmp)
    tmp.replace(path)


def load_checkpoint(path: Path, model, gen: torch.Generator, cfg: FitConfig, data_key: str | None = None):
    try:
        ck = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # noqa: BLE001 - torch/pickle raise many kinds for a damaged file
        raise CheckpointError(f"{path}: unreadable checkpoint ({type(exc).__name__}); remove it or pass "
                              f"--no-resume") from None
    if data_key is not None and ck.get("data") != data_key:
        raise CheckpointError(f"{path}: checkpoint was made from other data than this source; use another --out "
                         f"or pass --no-resume to start afresh")
    if ck.get("config") != _config_key(cfg):
        raise CheckpointError(f"{path}: checkpoint was written with other settings; remove it or pass --no-resume")
    model.load_state_dict(ck["model"])
    gen.set_state(ck["generator"])
    return int(ck["step"]), ck.get("history", []), float(ck.get("train_seconds", 0.0))


class _StopFlag:
    """First SIGINT sets the flag (stop after this step); the second one raises KeyboardInterrupt."""

    def __init__(self):
        self.set = False
        self._old = None

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handler)
        return self

    def _handler(self, signum, frame):
        if self.set:
            raise KeyboardInterrupt
        self.set = True

    def __exit__(self, *exc):
        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


def _snapshot(model):
    return copy.deepcopy(model.state_dict())


def train(model, data, cfg: FitConfig, gen: torch.Generator, out_dir=None, on_eval=None,
          fault_hook=None, stop_after: int | None = None, data_key: str | None = None) -> TrainResult:
    """Run the optimisation. `on_eval(model, step, seconds)` is called every `cfg.eval_every_s` seconds
    of training (its time is not counted); `fault_hook(step, loss)` lets tests inject a fault;
    `stop_after` ends this call after that many steps (the schedule still spans cfg.total_steps)."""
    from tqdm.auto import tqdm

    data = model.training_data(data)
    total = cfg.total_steps
    batch = cfg.method_settings.rays_per_batch
    res = TrainResult()
    ck_path = Path(out_dir) / CHECKPOINT_NAME if out_dir is not None else None
    start = 0
    if ck_path is not None and cfg.resume and ck_path.is_file():
        start, res.history, res.train_seconds = load_checkpoint(ck_path, model, gen, cfg, data_key)
        res.resumed_from = start
    good = (_snapshot(model), start)
    best, since, ema = float("inf"), 0, None
    last_ck = last_eval = res.train_seconds
    warm_prev = None
    step = start
    pbar = tqdm(total=total, initial=start, disable=not cfg.progress, desc=f"fit {cfg.mode}", unit="step",
                dynamic_ncols=True, leave=False)
    with _StopFlag() as stop:
        t_mark = time.perf_counter()
        while step < total:
            if stop_after is not None and step - start >= stop_after:
                res.stopped = "paused"
                break
            if stop.set:
                res.stopped = "interrupted"
                break
            if cfg.max_seconds is not None and res.train_seconds >= cfg.max_seconds:
                res.stopped = "time"
                break
            rebuilt = model.before_step(step, total)
            warm = in_warmup(step, total, cfg.loss)
            if rebuilt or warm != warm_prev:     # the loss changes meaning: restart the plateau watch
                best, since, ema = float("inf"), 0, None
            warm_prev = warm
            idx = data.sample(batch, gen, lit_only=warm)
            loss, stats = model.loss(idx, step, total, gen)
            if fault_hook is not None:
                loss = fault_hook(step, loss)
            ok = bool(torch.isfinite(loss))
            if ok:
                model.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                ok = all(p.grad is None or all_finite(p.grad)
                         for g in model.optimizer.param_groups for p in g["params"])
                if ok:
                    model.optimizer.step()
                    ok = model.params_finite()
                    # a model may replace its networks after a step (PlatoNeRF's re-initialisation)
                    if ok and model.after_step(step + 1):
                        best, since, ema = float("inf"), 0, None
            if not ok:
                res.nan_restores += 1
                msg = (f"non-finite loss/gradient at step {step}: restoring step {good[1]} "
                       f"({res.nan_restores}/{cfg.max_nan_restores}), halving the learning rate")
                pbar.write(msg) if cfg.progress else None
                warnings.warn(msg, RuntimeWarning, stacklevel=2)
                model.load_state_dict(copy.deepcopy(good[0]))
                for g in model.optimizer.param_groups:
                    g["lr"] *= 0.5 ** res.nan_restores
                step = good[1]
                if res.nan_restores > cfg.max_nan_restores:
                    res.stopped = "nan"
                    break
                continue
            step += 1
            now = time.perf_counter()
            res.train_seconds += now - t_mark
            t_mark = now
            lv = float(loss.detach())
            res.history.append({"step": step, "seconds": round(res.train_seconds, 3), "loss": lv, **stats})
            pbar.update(1)
            pbar.set_postfix(loss=f"{lv:.4g}", refresh=False)
            if step % SNAPSHOT_EVERY == 0:
                good = (_snapshot(model), step)
            ema = lv if ema is None else 0.9 * ema + 0.1 * lv
            if ema < best * (1.0 - cfg.plateau_rel_tol):
                best, since = ema, 0
            else:
                since += 1
            if (not warm and cfg.plateau_patience > 0 and since >= cfg.plateau_patience
                    and model.plateau_stop):
                res.stopped = "plateau"
                break
            if ck_path is not None and res.train_seconds - last_ck >= cfg.checkpoint_every_s:
                save_checkpoint(ck_path, model, gen, step, cfg, res, data_key)
                last_ck = res.train_seconds
            if on_eval is not None and cfg.eval_every_s is not None and res.train_seconds - last_eval >= cfg.eval_every_s:
                res.evals.append({"step": step, "seconds": res.train_seconds, **on_eval(model, step, res.train_seconds)})
                last_eval = res.train_seconds
                t_mark = time.perf_counter()
    pbar.close()
    res.steps_done = step
    if ck_path is not None:
        save_checkpoint(ck_path, model, gen, step, cfg, res, data_key)
    return res
