// Decoder of the resecta mesh wire format, version 2 (docs/wire/mesh-delta.md): snapshots
// (`RSMS`) and deltas (`RSDL`), raw or zstd with its content checksum, exact or quantised.
// Bad input throws `WireError` naming the problem; nothing is allocated beyond what the
// message's length and the limits allow. A port of the Python reference decoder
// (clients/python/src/resecta_client/wire.py), bit-identical to the Rust one.

import { Decompress } from "fzstd";
import { xxh64Low32 } from "./xxh64";

export const VERSION = 2;
export const HEADER_BYTES = 20;

export const POSITIONS = 0x01;
export const NORMALS = 0x02;
export const MARGINS = 0x04;
export const CLASSES = 0x08;
export const POSITIONS_U16 = 0x10; // only with POSITIONS
export const NORMALS_OCT16 = 0x20; // only with NORMALS
export const ZSTD = 0x40; // one zstd frame with a content checksum
export const INDEX_LIST = 0x80; // delta only
const ALL_FLAGS = 0xff;

const NAN_U16 = 0xffff;
const ZERO_OCT = -32768;

/** Margin class codes (resecta_margin::MarginClass). */
export const CLASS_OUTSIDE = 0, CLASS_SAFE = 1, CLASS_WARNING = 2, CLASS_VIOLATION = 3;

export interface Limits {
  maxVertices: number;
  maxTriangles: number;
}
/** The server's default decode limits. */
export const DEFAULT_LIMITS: Limits = { maxVertices: 8 << 20, maxTriangles: 16 << 20 };

/** A message that is truncated, inconsistent or not of this format. */
export class WireError extends Error {
  override name = "WireError";
}

export interface Header {
  kind: "mesh" | "delta";
  version: number;
  flags: number;
  vertexCount: number;
  count2: number; // triangles (mesh) or changed vertices (delta)
  payloadBytes: number; // length of the uncompressed payload
}

/** Per-vertex attributes of `rows` rows; absent sections are null. */
export interface Rows {
  positions: Float32Array | null; // 3 per row: x, y, z (RAS, mm)
  normals: Float32Array | null; // 3 per row
  margins: Float32Array | null; // mm to the nearest target tumour
  classes: Uint8Array | null; // CLASS_* codes
}

/** A decoded snapshot: the surface whole. */
export interface Mesh extends Rows {
  header: Header;
  vertexCount: number;
  triangles: Uint32Array; // 3 vertex indices per triangle
  positions: Float32Array;
}

/** A decoded delta: the changed vertices (ascending) and their new rows. */
export interface Delta extends Rows {
  header: Header;
  vertexCount: number;
  changed: Uint32Array;
}

const LITTLE_ENDIAN = new Uint8Array(new Uint16Array([1]).buffer)[0] === 1;

const hex = (flags: number): string => "0x" + flags.toString(16).padStart(4, "0");
const pad4 = (n: number): number => Math.ceil(n / 4) * 4;
const u16At = (b: Uint8Array, at: number): number => b[at]! | (b[at + 1]! << 8);
const u32At = (b: Uint8Array, at: number): number =>
  (b[at]! | (b[at + 1]! << 8) | (b[at + 2]! << 16) | (b[at + 3]! << 24)) >>> 0;

/** The fixed header, with magic, version, reserved flag bits and encoding flags checked. */
export function readHeader(buf: Uint8Array): Header {
  if (buf.length < HEADER_BYTES) {
    throw new WireError(`truncated: header needs ${HEADER_BYTES} bytes, ${buf.length} available`);
  }
  const magic = String.fromCharCode(buf[0]!, buf[1]!, buf[2]!, buf[3]!);
  const kind = magic === "RSMS" ? "mesh" : magic === "RSDL" ? "delta" : null;
  if (!kind) {
    throw new WireError(`bad magic ${JSON.stringify(magic)}: expected "RSMS" (mesh) or "RSDL" (delta)`);
  }
  const version = u16At(buf, 4);
  if (version !== VERSION) {
    throw new WireError(`unsupported format version ${version} (this decoder reads ${VERSION})`);
  }
  const flags = u16At(buf, 6);
  if (flags & ~ALL_FLAGS) throw new WireError(`bad flags ${hex(flags)}: reserved bits set`);
  if (flags & POSITIONS_U16 && !(flags & POSITIONS)) {
    throw new WireError(`bad flags ${hex(flags)}: POSITIONS_U16 without a positions section`);
  }
  if (flags & NORMALS_OCT16 && !(flags & NORMALS)) {
    throw new WireError(`bad flags ${hex(flags)}: NORMALS_OCT16 without a normals section`);
  }
  return {
    kind,
    version,
    flags,
    vertexCount: u32At(buf, 8),
    count2: u32At(buf, 12),
    payloadBytes: u32At(buf, 16),
  };
}

function attributeBytes(flags: number, rows: number): number {
  let size = 0;
  if (flags & POSITIONS) size += flags & POSITIONS_U16 ? 24 + pad4(6 * rows) : 12 * rows;
  if (flags & NORMALS) size += flags & NORMALS_OCT16 ? 4 * rows : 12 * rows;
  if (flags & MARGINS) size += 4 * rows;
  if (flags & CLASSES) size += pad4(rows);
  return size;
}

function checkLimit(what: string, count: number, limit: number): void {
  if (count > limit) throw new WireError(`${what} count ${count} exceeds the limit ${limit}`);
}

/** The payload (decompressed when ZSTD), checked to be exactly `expected` bytes. */
function payload(buf: Uint8Array, h: Header, expected: number): Uint8Array {
  if (h.payloadBytes !== expected) {
    throw new WireError(
      `payload size ${h.payloadBytes} bytes in the header, but the counts and flags give ${expected}`,
    );
  }
  const body = buf.subarray(HEADER_BYTES);
  if (!(h.flags & ZSTD)) {
    if (body.length < expected) {
      throw new WireError(`truncated: payload needs ${expected} bytes, ${body.length} available`);
    }
    if (body.length > expected) {
      throw new WireError(`${body.length - expected} trailing bytes after the payload`);
    }
    return body;
  }
  return unzstd(body, expected);
}

const BLOCK_MAX = 128 << 10;

/** `body` as exactly one zstd frame with a content checksum, decompressed to exactly `expected`
 * bytes (never more in memory), its checksum verified. */
function unzstd(body: Uint8Array, expected: number): Uint8Array {
  const fail = (what: string): never => {
    throw new WireError(`zstd: ${what}`);
  };
  if (body.length < 6) fail(`the frame is truncated (${body.length} bytes)`);
  const magic = u32At(body, 0);
  if ((magic & 0xfffffff0) === 0x184d2a50) fail("a skippable frame where the payload's frame belongs");
  if (magic !== 0xfd2fb528) fail(`bad frame magic 0x${magic.toString(16)}`);
  const fhd = body[4]!;
  const singleSegment = (fhd >> 5) & 1, dictBytes = [0, 1, 2, 4][fhd & 3]!, fcsCode = fhd >> 6;
  if (fhd & 0x08) fail("reserved bit set in the frame header");
  if (!(fhd & 0x04)) {
    throw new WireError("the zstd frame has no content checksum (the format requires one)");
  }
  let at = 5;
  let window = 0;
  if (!singleSegment) {
    const wd = body[at++]!;
    const base = 2 ** (10 + (wd >> 3));
    window = base + (base / 8) * (wd & 7);
  }
  for (let i = 0; i < dictBytes; i++) if (body[at + i]) fail("dictionaries are not supported");
  at += dictBytes;
  const fcsBytes = fcsCode ? 1 << fcsCode : singleSegment;
  if (at + fcsBytes > body.length) fail("the frame header is truncated");
  let size: number | null = null;
  if (fcsBytes) {
    size = 0;
    for (let i = fcsBytes - 1; i >= 0; i--) size = size * 256 + body[at + i]!;
    if (fcsBytes === 2) size += 256;
    if (size !== expected) {
      throw new WireError(`zstd frame holds ${size} bytes, the payload is ${expected}`);
    }
  }
  // The decompressor allocates the window the header asks for (up to 2 GiB). No match can reach
  // back beyond the payload's start, so a window of the payload's size decodes every valid frame
  // the same: a larger one is lowered to that (on a copy), and memory stays bounded by it.
  const needed = Math.max(expected, BLOCK_MAX);
  let frame = body;
  if (!singleSegment && window > needed) {
    frame = body.slice();
    frame[5] = (Math.max(10, Math.ceil(Math.log2(needed))) - 10) << 3;
  }
  at += fcsBytes;
  // Walk the blocks to find the frame's end: exactly one frame, then its 4-byte checksum.
  for (let last = 0; !last; ) {
    if (at + 3 > body.length) fail("the frame is truncated");
    const bh = body[at]! | (body[at + 1]! << 8) | (body[at + 2]! << 16);
    last = bh & 1;
    const type = (bh >> 1) & 3, blockSize = bh >>> 3;
    if (type === 3) fail("reserved block type");
    if (blockSize > BLOCK_MAX) fail(`block of ${blockSize} bytes (at most ${BLOCK_MAX})`);
    at += 3 + (type === 1 ? 1 : blockSize);
  }
  if (at + 4 > body.length) fail("the frame is truncated");
  if (at + 4 < body.length) fail(`${body.length - at - 4} bytes after the frame`);
  const out = new Uint8Array(expected);
  let filled = 0;
  try {
    const d = new Decompress((chunk: Uint8Array) => {
      if (filled + chunk.length > expected) {
        throw new WireError(`zstd frame holds more than ${expected} bytes, the payload is ${expected}`);
      }
      out.set(chunk, filled);
      filled += chunk.length;
    });
    d.push(frame, true);
  } catch (e) {
    if (e instanceof WireError) throw e;
    fail(`corrupt frame (${e instanceof Error ? e.message : String(e)})`);
  }
  if (filled !== expected) throw new WireError(`zstd frame holds ${filled} bytes, the payload is ${expected}`);
  if (xxh64Low32(out) !== u32At(body, body.length - 4)) {
    throw new WireError(
      "the zstd frame's content checksum does not match the decompressed payload: the message is corrupt",
    );
  }
  return out;
}

/** Sequential reads of little-endian sections, each copied into its own aligned buffer. */
class Reader {
  pos = 0;
  constructor(private readonly data: Uint8Array) {}

  private bytes(what: string, size: number): Uint8Array {
    if (this.pos + size > this.data.length) {
      throw new WireError(`truncated: ${what} needs ${size} bytes, ${this.data.length - this.pos} available`);
    }
    const out = this.data.slice(this.pos, this.pos + size);
    this.pos += size;
    return out;
  }
  u8(what: string, count: number): Uint8Array {
    return this.bytes(what, count);
  }
  u16(what: string, count: number): Uint16Array {
    return new Uint16Array(this.native(this.bytes(what, 2 * count), 2).buffer);
  }
  i16(what: string, count: number): Int16Array {
    return new Int16Array(this.native(this.bytes(what, 2 * count), 2).buffer);
  }
  u32(what: string, count: number): Uint32Array {
    return new Uint32Array(this.native(this.bytes(what, 4 * count), 4).buffer);
  }
  f32(what: string, count: number): Float32Array {
    return new Float32Array(this.native(this.bytes(what, 4 * count), 4).buffer);
  }
  align4(): void {
    this.bytes("padding", pad4(this.pos) - this.pos);
  }
  private native(b: Uint8Array, width: number): Uint8Array {
    if (!LITTLE_ENDIAN) for (let i = 0; i < b.length; i += width) b.subarray(i, i + width).reverse();
    return b;
  }
}

/** Unit normals of octahedral snorm16 pairs, bit-identical to the Rust decoder (f32
 * arithmetic, each step rounded); the pair (-32768, -32768) gives a zero vector. */
export function octDecode(q: Int16Array): Float32Array {
  const f = Math.fround;
  const rows = q.length / 2;
  const out = new Float32Array(3 * rows);
  for (let k = 0; k < rows; k++) {
    const qu = q[2 * k]!, qv = q[2 * k + 1]!;
    if (qu === ZERO_OCT && qv === ZERO_OCT) continue; // stays (0, 0, 0)
    let x = Math.max(f(qu / 32767), -1);
    let y = Math.max(f(qv / 32767), -1);
    const z = f(f(1 - Math.abs(x)) - Math.abs(y));
    if (z < 0) {
      const fx = f(f(1 - Math.abs(y)) * (x < 0 ? -1 : 1));
      const fy = f(f(1 - Math.abs(x)) * (y < 0 ? -1 : 1));
      x = fx;
      y = fy;
    }
    const len = f(Math.sqrt(f(f(f(x * x) + f(y * y)) + f(z * z))));
    out[3 * k] = f(x / len);
    out[3 * k + 1] = f(y / len);
    out[3 * k + 2] = f(z / len);
  }
  return out;
}

/** `rows` vertices of the attributes in `flags`, in section order. */
function readAttributes(r: Reader, flags: number, rows: number): Rows {
  const out: Rows = { positions: null, normals: null, margins: null, classes: null };
  if (flags & POSITIONS) {
    if (flags & POSITIONS_U16) {
      const box = r.f32("quantisation box", 6);
      const codes = r.u16("positions", 3 * rows);
      r.align4();
      const pos = new Float32Array(3 * rows);
      for (let i = 0; i < codes.length; i++) {
        const k = i % 3, code = codes[i]!;
        // f32(f64(min) + f64(code) * f64(step)), rounded once; a corrupt box gives inf/NaN
        pos[i] = code === NAN_U16 ? NaN : box[k]! + code * box[k + 3]!;
      }
      out.positions = pos;
    } else {
      out.positions = r.f32("positions", 3 * rows);
    }
  }
  if (flags & NORMALS) {
    out.normals = flags & NORMALS_OCT16 ? octDecode(r.i16("normals", 2 * rows)) : r.f32("normals", 3 * rows);
  }
  if (flags & MARGINS) out.margins = r.f32("margins", rows);
  if (flags & CLASSES) {
    out.classes = r.u8("classes", rows);
    r.align4();
  }
  return out;
}

/** Decodes a snapshot (magic RSMS). */
export function decodeMesh(buf: Uint8Array, limits: Limits = DEFAULT_LIMITS): Mesh {
  const h = readHeader(buf);
  if (h.kind !== "mesh") throw new WireError("a delta (RSDL) where a mesh (RSMS) was expected");
  if (!(h.flags & POSITIONS) || h.flags & INDEX_LIST) {
    throw new WireError(`bad flags ${hex(h.flags)}: a mesh has positions and no changed-index list`);
  }
  checkLimit("vertex", h.vertexCount, limits.maxVertices);
  checkLimit("triangle", h.count2, limits.maxTriangles);
  const n = h.vertexCount, t = h.count2;
  const r = new Reader(payload(buf, h, 12 * t + attributeBytes(h.flags, n)));
  const triangles = r.u32("triangles", 3 * t);
  for (let i = 0; i < triangles.length; i++) {
    if (triangles[i]! >= n) {
      throw new WireError(`triangle ${Math.floor(i / 3)} refers to vertex ${triangles[i]}, but there are ${n} vertices`);
    }
  }
  const a = readAttributes(r, h.flags, n);
  return { header: h, vertexCount: n, triangles, ...a, positions: a.positions! };
}

/** Decodes a delta (magic RSDL). With `held`, also checks that it applies to that mesh (same
 * vertex count, no attribute the mesh lacks) before reading the payload, in the spec's order. */
export function decodeDelta(buf: Uint8Array, limits: Limits = DEFAULT_LIMITS, held?: Mesh): Delta {
  const h = readHeader(buf);
  if (h.kind !== "delta") throw new WireError("a mesh (RSMS) where a delta (RSDL) was expected");
  checkLimit("vertex", h.vertexCount, limits.maxVertices);
  const n = h.vertexCount, m = h.count2;
  if (held && n !== held.vertexCount) {
    throw new WireError(`vertex count differs: ${n} in the delta, ${held.vertexCount} held`);
  }
  if (m > n) throw new WireError(`changed-vertex set: ${m} changed vertices of ${n}`);
  if (held) checkSections(held, h.flags);
  const list = (h.flags & INDEX_LIST) !== 0;
  const words = list ? m : Math.ceil(n / 32);
  const r = new Reader(payload(buf, h, 4 * words + attributeBytes(h.flags, m)));
  const set = r.u32("changed set", words);
  let changed: Uint32Array;
  if (list) {
    for (let k = 0; k < m; k++) {
      if (set[k]! >= n || (k > 0 && set[k]! <= set[k - 1]!)) {
        throw new WireError(`changed-vertex set: indices not ascending or not below the vertex count ${n}`);
      }
    }
    changed = set;
  } else {
    let count = 0;
    for (let w = 0; w < words; w++) {
      let v = set[w]!;
      const beyond = w === words - 1 && n % 32 ? v >>> n % 32 : 0;
      if (beyond) {
        const bit = w * 32 + (n % 32) + ctz(beyond);
        throw new WireError(`changed-vertex set: bit ${bit} set beyond the vertex count ${n}`);
      }
      for (; v; v &= v - 1) count++;
    }
    if (count !== m) {
      throw new WireError(`changed-vertex set: ${count} bits set, ${m} changed vertices in the header`);
    }
    changed = new Uint32Array(m);
    let k = 0;
    for (let w = 0; w < words; w++) {
      for (let v = set[w]!; v; v &= v - 1) changed[k++] = w * 32 + ctz(v);
    }
  }
  return { header: h, vertexCount: n, changed, ...readAttributes(r, h.flags, m) };
}

const ctz = (v: number): number => 31 - Math.clz32(v & -v);

const SECTIONS = [
  ["positions", POSITIONS],
  ["normals", NORMALS],
  ["margins", MARGINS],
  ["classes", CLASSES],
] as const;

function checkSections(mesh: Mesh, flags: number): void {
  for (const [what, flag] of SECTIONS) {
    if (flags & flag && !mesh[what]) throw new WireError(`${what} present in the delta but not in the mesh`);
  }
}

/** The mesh after a delta made against it (topology and header stay the snapshot's). By
 * default `mesh` is left alone and the result holds copies; with `inPlace` the rows are written
 * into `mesh`'s arrays, after the whole delta is decoded and checked (a bad delta changes
 * nothing). Values are copied as bit patterns (NaN payloads included). */
export function applyDelta(
  mesh: Mesh,
  buf: Uint8Array,
  opts: { inPlace?: boolean; limits?: Limits } = {},
): { mesh: Mesh; delta: Delta } {
  const d = decodeDelta(buf, opts.limits ?? DEFAULT_LIMITS, mesh);
  const out: Mesh = opts.inPlace
    ? mesh
    : {
        ...mesh,
        triangles: mesh.triangles.slice(),
        positions: mesh.positions.slice(),
        normals: mesh.normals?.slice() ?? null,
        margins: mesh.margins?.slice() ?? null,
        classes: mesh.classes?.slice() ?? null,
      };
  writeRows(out.positions, d.positions, d.changed, 3);
  writeRows(out.normals, d.normals, d.changed, 3);
  writeRows(out.margins, d.margins, d.changed, 1);
  writeRows(out.classes, d.classes, d.changed, 1);
  return { mesh: out, delta: d };
}

function writeRows(
  held: Float32Array | Uint8Array | null,
  rows: Float32Array | Uint8Array | null,
  changed: Uint32Array,
  width: number,
): void {
  if (!held || !rows) return;
  const bits = (a: Float32Array | Uint8Array) =>
    a instanceof Float32Array ? new Uint32Array(a.buffer, a.byteOffset, a.length) : a;
  const dst = bits(held), src = bits(rows);
  for (let k = 0; k < changed.length; k++) {
    const i = changed[k]! * width;
    for (let c = 0; c < width; c++) dst[i + c] = src[k * width + c]!;
  }
}
