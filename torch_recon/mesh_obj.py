"""Wavefront OBJ text of an exported mesh, byte for byte what `trimesh.exchange.obj.export_obj` writes for it.

trimesh formats the numbers with one `str.format` call over numpy scalars; `%` formatting of Python floats
and ints (the same float-to-text conversion: `'%.8f' % x == '{:.8f}'.format(x)`) takes about a third of
the time: the 128 px cave-chair mesh (173k faces) 1.5 -> 0.38 CPU-s with UVs, 0.74 -> 0.19 without (session 17,
issue 11). Only the meshes
this pipeline writes take the short path (no vertex or face colours, no cached vertex normals, no name; UVs
or none); anything else returns None and the caller lets trimesh write it.
"""

from __future__ import annotations

import numpy as np

#: trimesh's header line and digits (export_obj's defaults)
HEADER = "# https://github.com/mikedh/trimesh"
DIGITS = 8


def _rows(values: np.ndarray, row_format: str, row_delim: str) -> str:
    """The rows of `values` (n, k) in `row_format` (k %-fields), joined by `row_delim` (trimesh.util.array_to_string)."""
    return row_delim.join([row_format] * len(values)) % tuple(values.reshape(-1).tolist())


def obj_text(mesh) -> str | None:
    """The OBJ text of `mesh` (trimesh.Trimesh) as `export_obj(mesh, include_texture=True)` writes it, less its
    `mtllib` / `usemtl` lines (no material files are written beside it); None where trimesh must write it."""
    from trimesh.visual import ColorVisuals, TextureVisuals

    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.faces)
    visual = mesh.visual
    if (len(v) == 0 or len(f) == 0 or v.dtype.kind != "f" or f.dtype.kind not in "iu"
            or "vertex_normals" in mesh._cache.cache or "name" in mesh.metadata):
        return None
    uv = None
    if isinstance(visual, TextureVisuals):
        uv = None if visual.uv is None else np.asarray(visual.uv)
        if uv is None or uv.ndim != 2 or uv.shape[1] != 2 or uv.dtype.kind != "f":
            return None
    elif not (isinstance(visual, ColorVisuals) and visual.kind is None):
        return None
    num = f"%.{DIGITS}f"
    parts = [HEADER, "v " + _rows(v, " ".join([num] * v.shape[1]), "\nv ")]
    if uv is not None:
        parts.append("vt " + _rows(uv, f"{num} {num}", "\nvt "))
        faces = np.repeat(f.astype(np.int64) + 1, 2, axis=1)      # "v/vt" with the same index
        parts.append("f " + _rows(faces, " ".join(["%d/%d"] * f.shape[1]), "\nf "))
    else:
        parts.append("f " + _rows(f.astype(np.int64) + 1, " ".join(["%d"] * f.shape[1]), "\nf "))
    return "\n".join(parts) + "\n\n"
