"""The contract every stage shares: units, frames, the dataset format, scene descriptions and the paper's
reference data, the analytic renderer, the ground-truth writer, spot geometry, errors and settings.

Dependency rule (docs/architecture.md, enforced by tests/torch_recon/contract/test_contract_layers.py):
modules here import only each other, the standard library, numpy, OpenEXR, trimesh, scipy and embreex;
never bpy, torch, pipeline/, addon/ or the rest of torch_recon. Importing this package imports nothing.
"""
