"""Tables of f on direction grids: the RAW table Tabulate writes and MERL's .binary, read with numpy."""
import struct

import numpy as np

# docs/tabulation.md "Formats": 'LLTB', version, header bytes, grid kind, dimension count, 4 dimensions, channels.
_RAW_HEADER = struct.Struct("<4sIIII4II")
GRID_KINDS = {1: "in_plane", 2: "anisotropic", 3: "merl"}
# MERL's channel scales: a .binary stores f / scale, and readers multiply by it.
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
MERL_DIMS = (90, 90, 180)


def read_raw(data):
    """A RAW table's bytes as (grid kind, float32 array of shape dims + (3,))."""
    if len(data) < _RAW_HEADER.size:
        raise ValueError(f"a RAW table has a {_RAW_HEADER.size}-byte header; got {len(data)} bytes")
    magic, version, header_bytes, kind, ndims, d0, d1, d2, d3, channels = _RAW_HEADER.unpack_from(data)
    if magic != b"LLTB" or version != 1 or not 1 <= ndims <= 4:
        raise ValueError("not a Loomlight RAW table (magic LLTB, version 1)")
    dims = (d0, d1, d2, d3)[:ndims]
    cells = int(np.prod(dims))
    expected = header_bytes + cells * channels * 4
    if len(data) != expected:
        raise ValueError(f"RAW table of {len(data)} bytes, {expected} expected for dims {dims}")
    values = np.frombuffer(data, dtype="<f4", offset=header_bytes).reshape(*dims, channels)
    return GRID_KINDS.get(kind, str(kind)), values.astype(np.float32)


def read_merl(path_or_bytes):
    """A MERL .binary as f (1/sr), float64, shape (90 theta_h, 90 theta_d, 180 phi_d, 3): the int32 dimensions,
    then the R, G and B blocks of float64, each multiplied by MERL's channel scale, as MERL's own reader does."""
    if isinstance(path_or_bytes, (bytes, bytearray, memoryview)):
        data = bytes(path_or_bytes)
    else:
        with open(path_or_bytes, "rb") as f:
            data = f.read()
    dims = tuple(int(d) for d in np.frombuffer(data, dtype="<i4", count=3))
    if dims != MERL_DIMS:
        raise ValueError(f"a MERL .binary is 90 x 90 x 180; this one says {dims}")
    cells = 90 * 90 * 180
    blocks = np.frombuffer(data, dtype="<f8", offset=12)
    if blocks.size != 3 * cells:
        raise ValueError(f"a MERL .binary holds {3 * cells} values; this one {blocks.size}")
    return (blocks.reshape(3, *MERL_DIMS) * MERL_SCALE[:, None, None, None]).transpose(1, 2, 3, 0)
