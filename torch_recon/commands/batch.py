"""`batch`: many scenes simulated, fitted and evaluated on Dask distributed (pipeline/batch, docs/batch.md).

The batch runner only starts the other commands as subprocesses; it imports neither bpy nor torch.
"""

from __future__ import annotations


def register(sub) -> None:
    from pipeline.batch.cli import register as register_batch

    register_batch(sub)
