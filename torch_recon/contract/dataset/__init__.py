"""The dataset format: the versioned contract between simulator and reconstructor.

numpy + OpenEXR only (no torch, no bpy): the Blender-side pipeline writes with it,
the reconstructor reads with it. Format: docs/dataset_format.md.
"""

from .schema import (MANIFEST_NAME, SCHEMA_VERSION, DatasetError, GroundTruth, GroundTruthObject, GroundTruthViews,
                     Manifest,
                     NoiseSpec, Provenance, PulseSpec, SensorSpec, Spot, TimeGate, TransientLayout)
from .store import Dataset, DatasetWriter, load_dataset, read_transient_file, transient_relpath
from .transient import Transient

__all__ = [
    "MANIFEST_NAME", "SCHEMA_VERSION", "DatasetError", "GroundTruth", "GroundTruthObject", "GroundTruthViews", "Manifest", "NoiseSpec",
    "Provenance", "PulseSpec", "SensorSpec", "Spot", "TimeGate", "TransientLayout", "Dataset", "DatasetWriter",
    "load_dataset", "read_transient_file", "transient_relpath", "Transient",
]
