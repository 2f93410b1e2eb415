// The TypeScript decoder against golden messages of the Rust encoder
// (server/crates/engine/resecta-delta/tests/golden.rs): bit-identical to what Rust decodes.
// Write them with
//   RESECTA_DELTA_GOLDEN_DIR=DIR cargo test -p resecta-delta --test golden --locked
// and run with RESECTA_GOLDEN_DIR=DIR; skipped (visibly) without it.

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { test } from "node:test";
import * as w from "../src/wire";

const dir = process.env["RESECTA_GOLDEN_DIR"];
const skip = dir ? false : "RESECTA_GOLDEN_DIR is not set: no golden messages to check against";
if (!dir) console.log(`SKIP: ${skip}`);

interface Frame {
  positions: number[][];
  normals: number[][];
  margins: number[];
  classes: number[];
}
interface Case {
  file: string;
  kind: "mesh" | "delta";
  base?: string;
  header: { version: number; flags: number; vertex_count: number; count2: number; payload_bytes: number };
  triangles?: number[][];
  changed?: number[];
  decoded: Frame;
}

const expected = (): Case[] => JSON.parse(readFileSync(join(dir!, "expected.json"), "utf8")).cases;
const read = (name: string): Uint8Array => new Uint8Array(readFileSync(join(dir!, name)));
const bits = (a: Float32Array | null): number[] | null => (a ? [...new Uint32Array(a.slice().buffer)] : null);

/** Bitwise equal to the Rust decoder's frame (absent attributes: null here, empty there). */
function assertSame(got: w.Rows, want: Frame, name: string): void {
  const flat = (v: number[][] | number[]) => v.flat();
  assert.deepEqual(bits(got.positions), flat(want.positions), `${name}: positions`);
  assert.deepEqual(bits(got.normals), want.normals.length ? flat(want.normals) : null, `${name}: normals`);
  assert.deepEqual(bits(got.margins), want.margins.length ? want.margins : null, `${name}: margins`);
  assert.deepEqual(got.classes ? [...got.classes] : null, want.classes.length ? want.classes : null, `${name}: classes`);
}

function decoderOf(c: Case): (b: Uint8Array) => unknown {
  if (c.kind === "mesh") return (b) => w.decodeMesh(b);
  const base = w.decodeMesh(read(c.base!));
  return (b) => w.applyDelta(base, b);
}

function patched(buf: Uint8Array, at: number, bytes: number, value: number): Uint8Array {
  const b = buf.slice();
  for (let i = 0; i < bytes; i++) b[at + i] = Math.floor(value / 256 ** i) & 0xff;
  return b;
}

test("meshes decode like Rust", { skip }, () => {
  const meshes = expected().filter((c) => c.kind === "mesh");
  assert.ok(meshes.length >= 7);
  for (const c of meshes) {
    const m = w.decodeMesh(read(c.file));
    const h = c.header;
    assert.deepEqual(
      [m.header.version, m.header.flags, m.vertexCount, m.header.count2, m.header.payloadBytes],
      [h.version, h.flags, h.vertex_count, h.count2, h.payload_bytes],
      c.file,
    );
    assert.deepEqual([...m.triangles], c.triangles!.flat(), `${c.file}: triangles`);
    assertSame(m, c.decoded, c.file);
    assert.equal((h.flags & w.ZSTD) !== 0, c.file.includes("zstd"));
  }
});

test("deltas apply like Rust, and leave the held mesh alone on request", { skip }, () => {
  const deltas = expected().filter((c) => c.kind === "delta");
  assert.ok(deltas.length >= 5);
  for (const c of deltas) {
    const buf = read(c.file);
    const d = w.decodeDelta(buf);
    assert.deepEqual([...d.changed], c.changed, `${c.file}: changed`);
    assert.deepEqual([d.header.flags, d.vertexCount, d.changed.length], [c.header.flags, c.header.vertex_count, c.header.count2]);
    const base = w.decodeMesh(read(c.base!));
    const before = bits(base.positions);
    const { mesh: after } = w.applyDelta(base, buf);
    assert.deepEqual(bits(base.positions), before, "applyDelta modified its input");
    assert.deepEqual([...after.triangles], [...base.triangles]);
    assertSame(after, c.decoded, c.file);
    const positions = base.positions;
    const inPlace = w.applyDelta(base, buf, { inPlace: true }).mesh;
    assert.ok(inPlace === base && base.positions === positions);
    assertSame(base, c.decoded, c.file);
  }
});

test("truncated and corrupted messages throw WireError", { skip }, () => {
  for (const c of expected()) {
    const buf = read(c.file);
    const decode = decoderOf(c);
    const h = c.header;
    for (const cut of new Set([0, 3, 19, 20, 21, buf.length >> 1, buf.length - 1])) {
      if (cut < buf.length) assert.throws(() => decode(buf.subarray(0, cut)), w.WireError, `${c.file} cut ${cut}`);
    }
    const longer = new Uint8Array(buf.length + 1);
    longer.set(buf);
    const bad = [
      longer,
      patched(buf, 0, 4, 0x58585352), // "RSXX"
      patched(buf, 4, 2, w.VERSION - 1),
      patched(buf, 4, 2, w.VERSION + 1),
      patched(buf, 6, 2, h.flags | 0x100),
      patched(buf, 16, 4, h.payload_bytes + 4),
      patched(buf, 8, 4, h.vertex_count + 1),
      patched(buf, 12, 4, h.count2 + 1),
      patched(buf, 12, 4, 0xffffffff),
      patched(buf, 8, 4, 0xffffffff),
    ];
    bad.forEach((b, i) => assert.throws(() => decode(b), w.WireError, `${c.file} bad ${i}`));
    assert.throws(() => (c.kind === "mesh" ? w.decodeDelta : w.decodeMesh)(buf), /expected/);
  }
  const mesh = read("mesh_exact.rsms");
  assert.throws(() => w.decodeMesh(patched(mesh, 20 + 2 * 12 + 8, 4, 144)), /triangle 2 refers to vertex 144/);
  assert.throws(() => w.decodeMesh(patched(mesh, 6, 2, 0x0f | w.INDEX_LIST)), /a mesh has positions/);
  const z = read("mesh_exact_zstd.rsms");
  z[20]! ^= 0xff; // the frame's magic number
  assert.throws(() => w.decodeMesh(z), /zstd/);
  const bare = read("mesh_bare_quant.rsms");
  assert.throws(
    () => w.decodeMesh(patched(bare, 6, 2, bare[6]! | w.NORMALS_OCT16)),
    /NORMALS_OCT16 without a normals section/,
  );
  const few = read("delta_few_exact.rsdl"); // index list [0, 17, 143]
  assert.throws(
    () => w.decodeDelta(patched(few, 6, 2, w.POSITIONS_U16 | w.MARGINS | w.CLASSES | w.INDEX_LIST)),
    /POSITIONS_U16 without a positions section/,
  );
  assert.throws(() => w.decodeDelta(patched(few, 24, 4, 0)), /ascending/);
  assert.throws(() => w.decodeDelta(patched(few, 28, 4, 144)), /ascending/);
  const quant = w.decodeMesh(read("mesh_quant.rsms"));
  assert.throws(() => w.applyDelta(w.decodeMesh(read("mesh_empty.rsms")), few), /vertex count differs/);
  assert.throws(
    () => w.applyDelta(w.decodeMesh(bare), read("delta_all_quant_zstd.rsdl")),
    /normals present in the delta/,
  );
  assert.throws(() => w.applyDelta(quant, mesh), w.WireError);
});

test("zstd frames carry a checksum that is verified", { skip }, () => {
  const compressed = expected().filter((c) => c.header.flags & w.ZSTD);
  assert.ok(compressed.length >= 3);
  for (const c of compressed) {
    const buf = read(c.file);
    const decode = decoderOf(c);
    assert.ok(buf[24]! & 0x04, `${c.file}: checksum flag`);
    const badSum = buf.slice();
    badSum[badSum.length - 1]! ^= 0x5a;
    assert.throws(() => decode(badSum), /checksum does not match/);
    assert.throws(() => decode(patched(buf, 24, 1, buf[24]! & ~0x04)), /no content checksum/);
    const twice = new Uint8Array(2 * buf.length - 20);
    twice.set(buf);
    twice.set(buf.subarray(20), buf.length);
    assert.throws(() => decode(twice), w.WireError, "two frames");
    // Any single flipped bit: a WireError, or exactly what the intact message decodes to.
    const want = JSON.stringify(rowsOf(decode(buf)));
    for (let at = 20; at < buf.length; at++) {
      for (const bit of [0x01, 0x80]) {
        const b = buf.slice();
        b[at]! ^= bit;
        let got: unknown;
        try {
          got = decode(b);
        } catch (e) {
          assert.ok(e instanceof w.WireError, `${c.file} byte ${at}: ${String(e)}`);
          continue;
        }
        assert.equal(JSON.stringify(rowsOf(got)), want, `${c.file} byte ${at} bit ${bit}`);
      }
    }
  }
});

test("random corruption throws nothing but WireError", { skip }, () => {
  let seed = 7;
  const rand = (n: number): number => {
    seed = (Math.imul(seed, 1103515245) + 12345) >>> 0;
    return seed % n;
  };
  for (const c of expected()) {
    const buf = read(c.file);
    const decode = c.kind === "mesh" ? w.decodeMesh : w.decodeDelta;
    for (let i = 0; i < 300; i++) {
      const b = buf.slice();
      for (let k = 1 + rand(3); k > 0; k--) b[rand(b.length)]! ^= 1 + rand(255);
      try {
        decode(b);
      } catch (e) {
        assert.ok(e instanceof w.WireError, `${c.file}: ${String(e)}`);
      }
    }
  }
});

function rowsOf(x: unknown): unknown {
  const m = (x as { mesh?: w.Mesh }).mesh ?? (x as w.Mesh);
  return [bits(m.positions), bits(m.normals), bits(m.margins), m.classes && [...m.classes]];
}
