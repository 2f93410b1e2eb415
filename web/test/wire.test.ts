// Unit tests of the decoder that need no golden messages (those: golden.test.ts).

import assert from "node:assert/strict";
import { test } from "node:test";
import * as w from "../src/wire";
import { xxh64Low32 } from "../src/xxh64";

const enc = (s: string) => new TextEncoder().encode(s);

test("xxh64 low 32 bits match the reference vectors", () => {
  assert.equal(xxh64Low32(enc("")), 0x51d8e999); // XXH64("") = ef46db3751d8e999
  assert.equal(xxh64Low32(enc("a")), 0xa98c6e5b); // d24ec4f1a98c6e5b
  assert.equal(xxh64Low32(enc("abc")), 0xad770999); // 44bc2cf5ad770999
  // 39 bytes: a 32-byte stripe, then 4- and 1-byte tails (python-xxhash's README: fbcea83c8a378bf1).
  assert.equal(xxh64Low32(enc("Nobody inspects the spammish repetition")), 0x8a378bf1);
});

/** The spec's example: 144 vertices, 0, 17 and 143 moved and changed margin and class. */
function exampleDelta(): Uint8Array {
  const b = new Uint8Array(84);
  const v = new DataView(b.buffer);
  b.set(enc("RSDL"));
  v.setUint16(4, 2, true);
  v.setUint16(6, w.POSITIONS | w.MARGINS | w.CLASSES | w.INDEX_LIST, true);
  v.setUint32(8, 144, true);
  v.setUint32(12, 3, true);
  v.setUint32(16, 64, true);
  [0, 17, 143].forEach((i, k) => v.setUint32(20 + 4 * k, i, true));
  for (let k = 0; k < 9; k++) v.setFloat32(32 + 4 * k, k + 0.5, true);
  for (let k = 0; k < 3; k++) v.setFloat32(68 + 4 * k, -k, true);
  b.set([2, 2, 2, 0], 80);
  return b;
}

test("the spec's example delta decodes and applies", () => {
  const d = w.decodeDelta(exampleDelta());
  assert.deepEqual([...d.changed], [0, 17, 143]);
  assert.deepEqual([...d.positions!], [0.5, 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5]);
  assert.deepEqual([...d.margins!].map((x) => x + 0), [0, -1, -2]);
  assert.deepEqual([...d.classes!], [2, 2, 2]);
  assert.equal(d.normals, null);
  const mesh: w.Mesh = {
    header: { kind: "mesh", version: 2, flags: 0x0d, vertexCount: 144, count2: 0, payloadBytes: 0 },
    vertexCount: 144,
    triangles: new Uint32Array(0),
    positions: new Float32Array(432),
    normals: null,
    margins: new Float32Array(144).fill(9),
    classes: new Uint8Array(144).fill(1),
  };
  const { mesh: out } = w.applyDelta(mesh, exampleDelta());
  assert.deepEqual([...out.positions.subarray(51, 54)], [3.5, 4.5, 5.5]);
  assert.equal(out.margins![143], -2);
  assert.equal(out.classes![1], 1);
  assert.equal(mesh.classes![0], 1, "the held mesh is left alone");
  assert.throws(() => w.applyDelta({ ...mesh, margins: null }, exampleDelta()), /margins present in the delta/);
});

test("octahedral decoding: the zero pair and the poles", () => {
  const n = w.octDecode(new Int16Array([-32768, -32768, 0, 0, 32767, 0]));
  assert.deepEqual([...n], [0, 0, 0, 0, 0, 1, 1, 0, 0]);
});

test("bad headers are named", () => {
  assert.throws(() => w.decodeMesh(new Uint8Array(5)), /truncated: header needs 20 bytes, 5 available/);
  const b = exampleDelta();
  b[6] = 0;
  b[7] = 1;
  assert.throws(() => w.decodeDelta(b), /reserved bits set/);
  assert.throws(() => w.decodeMesh(exampleDelta()), /a delta \(RSDL\) where a mesh \(RSMS\) was expected/);
});

test("a zstd frame without content size and with a 2 MiB window decodes like the raw payload", () => {
  // `zstd --check --no-content-size` of the example's payload (window descriptor 0x58: 2 MiB).
  const frame = Buffer.from(
    "28b52ffd045801020000000000110000008f0000000000003f0000c03f0000204000006040000090400000b0400000d0400000f0400000084100000080000080bf000000c00202020048cafba3",
    "hex",
  );
  const raw = exampleDelta();
  const msg = new Uint8Array(20 + frame.length);
  msg.set(raw.subarray(0, 20));
  msg[6] = raw[6]! | w.ZSTD;
  msg.set(frame, 20);
  const want = w.decodeDelta(raw);
  const got = w.decodeDelta(msg);
  assert.deepEqual([got.changed, got.positions, got.margins, got.classes], [want.changed, want.positions, want.margins, want.classes]);
  assert.equal(msg[25], 0x58, "the message itself is left alone");
  msg[msg.length - 2]! ^= 1;
  assert.throws(() => w.decodeDelta(msg), /checksum does not match/);
});
