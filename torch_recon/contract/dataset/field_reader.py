"""Typed reading of a manifest's JSON fields: every failure names the file and the dotted field path.

Split from schema.py so the dataclasses there read as the format itself; platonerf_layout.py reads the
authors' layout with the same reader.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import PlatolidarError


class DatasetError(PlatolidarError, ValueError):
    """A dataset that cannot be used: names the file, the field and what was expected."""

    def __init__(self, file: str, field_path: str, message: str):
        self.file, self.field, self.detail = str(file), field_path, message
        where = f"{self.file}: field '{field_path}'" if field_path else self.file
        super().__init__(f"{where}: {message}")


class FieldReader:
    """Reads typed values out of a JSON dict, raising DatasetError with the field path."""

    def __init__(self, file: str):
        self.file = file

    def fail(self, path: str, msg: str):
        raise DatasetError(self.file, path, msg)

    def get(self, d: dict, key: str, path: str, default=..., ):
        if not isinstance(d, dict):
            self.fail(path.rsplit(".", 1)[0], f"expected an object, got {type(d).__name__}")
        if key not in d:
            if default is ...:
                self.fail(path, "missing")
            return default
        return d[key]

    def number(self, d, key, path, default=..., positive=False, nonneg=False):
        v = self.get(d, key, path, default)
        if v is None and default is None:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(path, f"expected a finite number, got {v!r}")
        if positive and v <= 0:
            self.fail(path, f"expected a positive number, got {v!r}")
        if nonneg and v < 0:
            self.fail(path, f"expected a number >= 0, got {v!r}")
        return float(v)

    def integer(self, d, key, path, default=..., minimum=None):
        v = self.get(d, key, path, default)
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(path, f"expected an integer, got {v!r}")
        if minimum is not None and v < minimum:
            self.fail(path, f"expected an integer >= {minimum}, got {v!r}")
        return int(v)

    def boolean(self, d, key, path, default=...):
        v = self.get(d, key, path, default)
        if not isinstance(v, bool):
            self.fail(path, f"expected true or false, got {v!r}")
        return v

    def string(self, d, key, path, default=..., choices=None):
        v = self.get(d, key, path, default)
        if v is None and default is None:
            return None
        if not isinstance(v, str):
            self.fail(path, f"expected a string, got {v!r}")
        if choices is not None and v not in choices:
            self.fail(path, f"expected one of {list(choices)}, got {v!r}")
        return v

    def vector(self, d, key, path, n=3, default=...):
        v = self.get(d, key, path, default)
        if v is None and default is None:
            return None
        a = np.asarray(v, dtype=object)
        if a.shape != (n,) or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in a):
            self.fail(path, f"expected a list of {n} numbers, got {v!r}")
        a = np.asarray(v, dtype=np.float64)
        if not np.all(np.isfinite(a)):
            self.fail(path, f"expected finite numbers, got {v!r}")
        return [float(x) for x in a]

    def matrix4(self, d, key, path, default=...):
        v = self.get(d, key, path, default)
        if v is None and default is None:
            return None
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            self.fail(path, "expected a 4x4 matrix of numbers")
        if a.shape != (4, 4) or not np.all(np.isfinite(a)):
            self.fail(path, f"expected a finite 4x4 matrix, got shape {a.shape}")
        rot = a[:3, :3]
        if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-4) or not np.allclose(a[3], [0, 0, 0, 1], atol=1e-6):
            self.fail(path, "expected a rigid camera-to-world transform (orthonormal rotation, last row 0 0 0 1)")
        return a.tolist()
