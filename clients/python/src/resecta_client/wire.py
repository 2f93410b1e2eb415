"""Decoder of the resecta mesh wire format (docs/wire/mesh-delta.md), the reference one.

`decode_mesh` reads a snapshot (magic ``RSMS``), `decode_delta` a delta (magic ``RSDL``) and
`apply_delta` applies a delta to a decoded snapshot. Bad input raises `WireError` (a
`ValueError`) naming the problem; nothing is allocated beyond what the message's length and the
limits allow. Needs numpy, and the `zstandard` package only for compressed messages (the `zstd` extra).
`tests/test_mesh_wire.py` checks it against golden messages of the Rust encoder.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
import numpy.typing as npt

try:
    import zstandard
except ImportError:  # only compressed messages need it
    zstandard = None  # type: ignore[assignment]

ZSTD_AVAILABLE = zstandard is not None
"""Whether compressed (ZSTD) messages can be decoded here."""

MESH_MAGIC = b"RSMS"
DELTA_MAGIC = b"RSDL"
VERSION = 2
HEADER_BYTES = 20

# Header flag bits.
POSITIONS = 1 << 0
NORMALS = 1 << 1
MARGINS = 1 << 2
CLASSES = 1 << 3
POSITIONS_U16 = 1 << 4  # only together with POSITIONS
NORMALS_OCT16 = 1 << 5  # only together with NORMALS
ZSTD = 1 << 6  # one zstd frame with a content checksum
INDEX_LIST = 1 << 7
ALL_FLAGS = (1 << 8) - 1

NAN_U16 = 0xFFFF  # quantised coordinate code of a non-finite value
ZERO_OCT = -32768  # octahedral pair (ZERO_OCT, ZERO_OCT): a zero normal

# Margin class codes (resecta_margin::MarginClass).
CLASS_OUTSIDE, CLASS_SAFE, CLASS_WARNING, CLASS_VIOLATION = 0, 1, 2, 3

# The server's default decode limits.
MAX_VERTICES = 8 << 20
MAX_TRIANGLES = 16 << 20

F32 = npt.NDArray[np.float32]
U32 = npt.NDArray[np.uint32]
U8 = npt.NDArray[np.uint8]


class WireError(ValueError):
    """A message that is truncated, inconsistent or not of this format."""


@dataclass(frozen=True)
class Header:
    kind: str  # "mesh" or "delta"
    version: int
    flags: int
    vertex_count: int
    count2: int  # triangles (mesh) or changed vertices (delta)
    payload_bytes: int  # length of the uncompressed payload

    def has(self, flag: int) -> bool:
        return self.flags & flag != 0


class Mesh(TypedDict):
    version: int
    flags: int
    vertex_count: int
    triangle_count: int
    payload_bytes: int
    positions: F32  # (n, 3)
    normals: F32 | None  # (n, 3)
    triangles: U32  # (t, 3)
    margin: F32 | None  # (n,) mm
    classes: U8 | None  # (n,) CLASS_* codes


class Delta(TypedDict):
    version: int
    flags: int
    vertex_count: int
    changed_count: int
    payload_bytes: int
    changed: U32  # (m,) ascending vertex indices; the rows below are theirs, in this order
    positions: F32 | None  # (m, 3)
    normals: F32 | None
    margin: F32 | None
    classes: U8 | None


def read_header(buf: bytes | bytearray | memoryview) -> Header:
    """The fixed header, with magic, version, reserved flag bits and encoding flags (only with
    their section) checked."""
    b = bytes(buf[:HEADER_BYTES])
    if len(b) < HEADER_BYTES:
        raise WireError(f"truncated: header needs {HEADER_BYTES} bytes, {len(b)} available")
    magic, version, flags, n, count2, payload = struct.unpack("<4sHHIII", b)
    kinds = {MESH_MAGIC: "mesh", DELTA_MAGIC: "delta"}
    if magic not in kinds:
        raise WireError(f"bad magic {magic!r}: expected b'RSMS' (mesh) or b'RSDL' (delta)")
    if version != VERSION:
        raise WireError(f"unsupported format version {version} (this decoder reads {VERSION})")
    if flags & ~ALL_FLAGS:
        raise WireError(f"bad flags {flags:#06x}: reserved bits set")
    if flags & POSITIONS_U16 and not flags & POSITIONS:
        raise WireError(f"bad flags {flags:#06x}: POSITIONS_U16 without a positions section")
    if flags & NORMALS_OCT16 and not flags & NORMALS:
        raise WireError(f"bad flags {flags:#06x}: NORMALS_OCT16 without a normals section")
    return Header(kinds[magic], version, flags, n, count2, payload)


def _pad4(n: int) -> int:
    return -(-n // 4) * 4


def _attribute_bytes(flags: int, rows: int) -> int:
    size = 0
    if flags & POSITIONS:
        size += 24 + _pad4(6 * rows) if flags & POSITIONS_U16 else 12 * rows
    if flags & NORMALS:
        size += 4 * rows if flags & NORMALS_OCT16 else 12 * rows
    if flags & MARGINS:
        size += 4 * rows
    if flags & CLASSES:
        size += _pad4(rows)
    return size


def _payload(buf: bytes, h: Header, expected: int) -> bytes:
    """The payload (decompressed when ZSTD), checked to be exactly `expected` bytes."""
    if h.payload_bytes != expected:
        raise WireError(
            f"payload size {h.payload_bytes} bytes in the header, but the counts and flags give {expected}"
        )
    body = buf[HEADER_BYTES:]
    if not h.has(ZSTD):
        if len(body) < expected:
            raise WireError(f"truncated: payload needs {expected} bytes, {len(body)} available")
        if len(body) > expected:
            raise WireError(f"{len(body) - expected} trailing bytes after the payload")
        return body
    if zstandard is None:
        raise RuntimeError("a zstd-compressed message needs the 'zstandard' package")
    try:
        params = zstandard.get_frame_parameters(body)
        if not params.has_checksum:
            raise WireError("the zstd frame has no content checksum (the format requires one)")
        size = params.content_size
        if size not in (zstandard.CONTENTSIZE_UNKNOWN, expected):
            raise WireError(f"zstd frame holds {size} bytes, the payload is {expected}")
        # Verifies the frame's content checksum.
        out: bytes = zstandard.ZstdDecompressor().decompress(
            body, max_output_size=expected, allow_extra_data=False
        )
    except zstandard.ZstdError as e:
        if "checksum" in str(e):
            raise WireError(
                "the zstd frame's content checksum does not match the decompressed payload: "
                "the message is corrupt"
            ) from e
        raise WireError(f"zstd: {e}") from e
    if len(out) != expected:
        raise WireError(f"zstd frame holds {len(out)} bytes, the payload is {expected}")
    return out


class _Reader:
    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def take(self, what: str, dtype: str, count: int) -> np.ndarray:
        size = np.dtype(dtype).itemsize * count
        if self.pos + size > len(self.data):
            raise WireError(f"truncated: {what} needs {size} bytes, {len(self.data) - self.pos} available")
        out = np.frombuffer(self.data, dtype, count, self.pos)
        self.pos += size
        return out.astype(out.dtype.newbyteorder("="))  # a native, writable copy

    def align4(self) -> None:
        self.take("padding", "u1", _pad4(self.pos) - self.pos)


def oct_decode(q: npt.NDArray[np.int16]) -> F32:
    """Unit normals (k, 3) of octahedral snorm16 pairs (k, 2), bit-identical to the Rust
    decoder (f32 arithmetic); the pair (ZERO_OCT, ZERO_OCT) gives a zero vector."""
    q = np.asarray(q, np.int16).reshape(-1, 2)
    x = np.maximum(q[:, 0].astype(np.float32) / np.float32(32767), np.float32(-1))
    y = np.maximum(q[:, 1].astype(np.float32) / np.float32(32767), np.float32(-1))
    z = np.float32(1) - np.abs(x) - np.abs(y)
    fold = z < 0
    sx = np.where(x < 0, np.float32(-1), np.float32(1))
    sy = np.where(y < 0, np.float32(-1), np.float32(1))
    x, y = (
        np.where(fold, (np.float32(1) - np.abs(y)) * sx, x),
        np.where(fold, (np.float32(1) - np.abs(x)) * sy, y),
    )
    length = np.sqrt(x * x + y * y + z * z)
    out = np.stack([x / length, y / length, z / length], axis=1).astype(np.float32)
    out[(q[:, 0] == ZERO_OCT) & (q[:, 1] == ZERO_OCT)] = 0
    return out


@dataclass
class _Rows:
    positions: F32 | None = None
    normals: F32 | None = None
    margin: F32 | None = None
    classes: U8 | None = None


def _read_attributes(r: _Reader, flags: int, rows: int) -> _Rows:
    """`rows` vertices of the attributes in `flags`, in section order."""
    out = _Rows()
    if flags & POSITIONS:
        if flags & POSITIONS_U16:
            box = r.take("quantisation box", "<f4", 6).astype(np.float64)
            codes = r.take("positions", "<u2", 3 * rows).reshape(rows, 3)
            r.align4()
            with np.errstate(all="ignore"):  # a corrupt box gives inf/NaN, as in Rust
                pos = (box[:3] + codes * box[3:]).astype(np.float32)
            pos[codes == NAN_U16] = np.nan
            out.positions = pos
        else:
            out.positions = r.take("positions", "<f4", 3 * rows).reshape(rows, 3)
    if flags & NORMALS:
        if flags & NORMALS_OCT16:
            out.normals = oct_decode(r.take("normals", "<i2", 2 * rows))
        else:
            out.normals = r.take("normals", "<f4", 3 * rows).reshape(rows, 3)
    if flags & MARGINS:
        out.margin = r.take("margins", "<f4", rows)
    if flags & CLASSES:
        out.classes = r.take("classes", "u1", rows)
        r.align4()
    return out


def _check_limit(what: str, count: int, limit: int) -> None:
    if count > limit:
        raise WireError(f"{what} count {count} exceeds the limit {limit}")


def decode_mesh(
    buf: bytes | bytearray | memoryview,
    *,
    max_vertices: int = MAX_VERTICES,
    max_triangles: int = MAX_TRIANGLES,
) -> Mesh:
    """Decodes a snapshot (magic RSMS)."""
    buf = bytes(buf)
    h = read_header(buf)
    if h.kind != "mesh":
        raise WireError("a delta (RSDL) where a mesh (RSMS) was expected")
    if not h.has(POSITIONS) or h.has(INDEX_LIST):
        raise WireError(f"bad flags {h.flags:#06x}: a mesh has positions and no changed-index list")
    _check_limit("vertex", h.vertex_count, max_vertices)
    _check_limit("triangle", h.count2, max_triangles)
    n, t = h.vertex_count, h.count2
    r = _Reader(_payload(buf, h, 12 * t + _attribute_bytes(h.flags, n)))
    triangles = r.take("triangles", "<u4", 3 * t).reshape(t, 3)
    bad = np.flatnonzero((triangles >= n).any(axis=1))
    if bad.size:
        k = int(bad[0])
        index = int(triangles[k][triangles[k] >= n][0])
        raise WireError(f"triangle {k} refers to vertex {index}, but there are {n} vertices")
    a = _read_attributes(r, h.flags, n)
    assert a.positions is not None  # POSITIONS is set
    return Mesh(
        version=h.version,
        flags=h.flags,
        vertex_count=n,
        triangle_count=t,
        payload_bytes=h.payload_bytes,
        positions=a.positions,
        normals=a.normals,
        triangles=triangles,
        margin=a.margin,
        classes=a.classes,
    )


def decode_delta(buf: bytes | bytearray | memoryview, *, max_vertices: int = MAX_VERTICES) -> Delta:
    """Decodes a delta (magic RSDL): the changed vertices and their new attribute rows."""
    buf = bytes(buf)
    h = read_header(buf)
    if h.kind != "delta":
        raise WireError("a mesh (RSMS) where a delta (RSDL) was expected")
    _check_limit("vertex", h.vertex_count, max_vertices)
    n, m = h.vertex_count, h.count2
    if m > n:
        raise WireError(f"changed-vertex set: {m} changed vertices of {n}")
    words = m if h.has(INDEX_LIST) else -(-n // 32)
    r = _Reader(_payload(buf, h, 4 * words + _attribute_bytes(h.flags, m)))
    raw = r.take("changed set", "u1", 4 * words)
    if h.has(INDEX_LIST):
        changed = raw.view("<u4").astype(np.uint32)
        if m and (changed[-1] >= n or np.any(np.diff(changed.astype(np.int64)) <= 0)):
            raise WireError(f"changed-vertex set: indices not ascending or not below the vertex count {n}")
    else:
        bits = np.unpackbits(raw, bitorder="little")  # bit i of the set is vertex i
        if bits[n:].any():
            i = n + int(np.argmax(bits[n:]))
            raise WireError(f"changed-vertex set: bit {i} set beyond the vertex count {n}")
        changed = np.flatnonzero(bits).astype(np.uint32)
        if changed.size != m:
            raise WireError(
                f"changed-vertex set: {changed.size} bits set, {m} changed vertices in the header"
            )
    a = _read_attributes(r, h.flags, m)
    return Delta(
        version=h.version,
        flags=h.flags,
        vertex_count=n,
        changed_count=m,
        payload_bytes=h.payload_bytes,
        changed=changed,
        positions=a.positions,
        normals=a.normals,
        margin=a.margin,
        classes=a.classes,
    )


_ATTRS = ("positions", "normals", "margin", "classes")


def check_delta(mesh: Mesh, d: Delta) -> None:
    """Raises `WireError` unless the decoded delta `d` applies to `mesh` (same vertex count, no
    attribute the mesh lacks)."""
    n = len(mesh["positions"])
    if d["vertex_count"] != n:
        raise WireError(f"vertex count differs: {d['vertex_count']} in the delta, {n} held")
    for what in _ATTRS:
        held, rows = mesh[what], d[what]  # type: ignore[literal-required]
        if held is None and rows is not None:
            raise WireError(f"{what} present in the delta but not in the mesh")
        if held is not None and len(held) != n:
            raise WireError(f"mesh {what} has {len(held)} entries, expected {n}")


def write_delta(mesh: Mesh, d: Delta) -> None:
    """Writes the rows of a checked delta (`check_delta`) into `mesh`'s arrays, in place."""
    c = d["changed"]
    for what in _ATTRS:
        rows = d[what]  # type: ignore[literal-required]
        if rows is not None:
            mesh[what][c] = rows  # type: ignore[literal-required]


def apply_delta(
    mesh: Mesh,
    buf: bytes | bytearray | memoryview,
    *,
    max_vertices: int = MAX_VERTICES,
    in_place: bool = False,
) -> Mesh:
    """The mesh after a delta made against it. Header fields and triangles stay those of the
    snapshot (a delta never changes topology). By default `mesh` is not modified and the result
    holds copies; with `in_place` the changed rows are written into `mesh`'s own arrays (after
    the whole delta is decoded and checked, so a bad delta leaves them unchanged) and `mesh` is
    returned."""
    d = decode_delta(buf, max_vertices=max_vertices)
    check_delta(mesh, d)
    out = mesh
    if not in_place:
        out = mesh.copy()
        for what in (*_ATTRS, "triangles"):
            held = mesh[what]  # type: ignore[literal-required]
            out[what] = None if held is None else held.copy()  # type: ignore[literal-required]
    write_delta(out, d)
    return out
