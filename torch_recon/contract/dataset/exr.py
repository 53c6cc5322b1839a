"""EXR reading and writing (OpenEXR's official Python bindings, ZIP- or RLE-compressed scanlines).

Why OpenEXR: lossless float32/float16 with per-channel compression, readable by
Blender, nuke, OpenCV and every renderer; the official bindings read channels
straight into numpy arrays.
"""

from __future__ import annotations

import os

import numpy as np

from .schema import DatasetError

_ALLOWED = (np.float32, np.float16, np.uint32)
#: lossless scanline compressions a writer may choose; every reader reads either
COMPRESSIONS = ("zip", "rle")


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], attributes: dict | None = None,
              compression: str = "zip") -> None:
    """Write single-part EXR with 2-D channels of equal shape (float32, float16 or uint32).

    compression: 'zip' (smallest) or 'rle' (about half the CPU time to write; transients, whose
    windows are mostly zeros, come out about 25 % larger).
    """
    import OpenEXR

    if compression not in COMPRESSIONS:
        raise ValueError(f"EXR compression: expected one of {COMPRESSIONS}, got {compression!r}")

    shape = None
    out = {}
    for name, arr in channels.items():
        arr = np.ascontiguousarray(arr)
        if arr.ndim != 2:
            raise ValueError(f"EXR channel {name!r} must be 2-D, got shape {arr.shape}")
        if arr.dtype.type not in _ALLOWED:
            raise ValueError(f"EXR channel {name!r}: dtype {arr.dtype} not storable (float32, float16, uint32)")
        if shape is not None and arr.shape != shape:
            raise ValueError(f"EXR channel {name!r} has shape {arr.shape}, others {shape}")
        shape = arr.shape
        out[name] = arr
    header = {"compression": OpenEXR.ZIP_COMPRESSION if compression == "zip" else OpenEXR.RLE_COMPRESSION,
              "type": OpenEXR.scanlineimage}
    for k, v in (attributes or {}).items():
        header[k] = v
    OpenEXR.File(header, out).write(str(path))


def read_exr(path: str | os.PathLike, field: str = "") -> tuple[dict[str, np.ndarray], dict]:
    """Read a single-part EXR: (channels by name, header). Errors name the file."""
    import OpenEXR

    path = str(path)
    if not os.path.isfile(path):
        raise DatasetError(path, field, "file is missing")
    try:
        f = OpenEXR.File(path)
        part = f.parts[0]
        chans = {name: np.asarray(ch.pixels) for name, ch in part.channels.items()}
        header = dict(part.header)
    except Exception as exc:  # OpenEXR raises RuntimeError/ValueError on corrupt or truncated files
        raise DatasetError(path, field, f"not a readable EXR file ({exc})") from None
    return chans, header


def read_exr_channel(path, channel: str, field: str = "") -> np.ndarray:
    chans, _ = read_exr(path, field)
    if channel not in chans:
        raise DatasetError(str(path), field, f"EXR channel {channel!r} missing (has {sorted(chans)})")
    return chans[channel]
