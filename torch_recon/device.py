"""The one torch device resolver for every stage (preprocess, baseline, fit)."""

from __future__ import annotations

from .contract.errors import SettingsError
from .contract.settings import check_device_name


def resolve_device(name: str = "auto", threads: int | None = None):
    """torch.device for 'auto' (CUDA when present), 'cpu', 'cuda' or 'cuda:N'; sets the CPU thread count.

    An unknown name, or CUDA where torch sees none, is a SettingsError naming 'device'.
    """
    import torch

    check_device_name(name)
    if threads is not None:
        if isinstance(threads, bool) or int(threads) < 1:
            raise SettingsError("threads", f"expected an integer >= 1, got {threads}")
        torch.set_num_threads(int(threads))
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise SettingsError("device", f"{name}: CUDA is not available in this torch build/machine; use cpu")
        index = int(name[5:]) if ":" in name else 0
        if index >= torch.cuda.device_count():
            raise SettingsError("device", f"{name}: only {torch.cuda.device_count()} CUDA device(s) present")
    return torch.device(name)
