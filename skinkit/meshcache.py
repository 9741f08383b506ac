"""PC2 point caches (the format Blender's Mesh Cache modifier and most DCC tools read).

Layout, little-endian: char[12] "POINTCACHE2\\0", int32 version (1), int32 point count, float32 start
frame, float32 sample rate (frames per sample), int32 sample count, then float32 x, y, z for every point of
every sample.
"""
from __future__ import annotations

import struct

import numpy as np

from ._checks import PATH, as_real_array, checked, real
from .model import SkinkitError

#: The public API (what tests/fuzz/api_fuzz.py calls with hostile arguments); the rest are helpers.
__all__ = ["read_pc2", "write_pc2"]

MAGIC = b"POINTCACHE2\0"
HEADER = struct.Struct("<12siiffi")


@checked(path=PATH, start_frame=real(-1e30, 1e30), sample_rate=real(above=0, maximum=1e30))
def write_pc2(path: str, positions, start_frame: float = 1.0, sample_rate: float = 1.0) -> None:
    """positions: (samples, points, 3)."""
    positions = as_real_array(positions, "positions", shape=(None, None, 3))
    if positions.shape[0] == 0:
        raise SkinkitError(f"positions: expected shape (samples >= 1, points, 3), got {positions.shape}")
    if np.abs(positions).max(initial=0.0) > np.finfo(np.float32).max:
        raise SkinkitError("positions: values beyond float32's range (a PC2 cache stores float32)")
    try:
        with open(path, "wb") as stream:
            stream.write(HEADER.pack(MAGIC, 1, positions.shape[1], float(start_frame), float(sample_rate),
                                     positions.shape[0]))
            stream.write(positions.astype("<f4").tobytes())
    except OSError as error:
        raise SkinkitError(f"{path}: {error.strerror}") from None


@checked(path=PATH)
def read_pc2(path: str) -> tuple[np.ndarray, float, float]:
    """(positions (samples, points, 3) float32, start frame, sample rate)."""
    try:
        with open(path, "rb") as stream:
            header = stream.read(HEADER.size)
            if len(header) != HEADER.size or header[:12] != MAGIC:
                raise SkinkitError(f"{path}: not a PC2 point cache")
            _, _, points, start, rate, samples = HEADER.unpack(header)
            body = stream.read()
    except OSError as error:
        raise SkinkitError(f"{path}: {error.strerror}") from None
    if points < 0 or samples < 0:
        raise SkinkitError(f"{path}: its header gives {points} points and {samples} samples")
    if len(body) != samples * points * 12:
        raise SkinkitError(f"{path}: truncated ({len(body)} bytes of data for {samples} samples of {points} points)")
    data = np.frombuffer(body, dtype="<f4")
    return data.reshape(samples, points, 3).astype(np.float32), start, rate
