// The resectogram's pure parts: decoding the answer and painting its pixels.

import assert from "node:assert/strict";
import { test } from "node:test";
import type { ResectogramResponse } from "../src/api";
import {
  BOUNDARY_RGBA, CLASS_RGBA, CUT_VESSEL_RGBA, TERRITORY_EDGE_RGBA, WORST_RGBA,
  crossArm, decodeResectogram, discRadius, pixelOf, resectogramRgba,
} from "../src/resectogram";

const W = 10, H = 10;

/** A 10 × 10 resectogram: the outer frame outside the liver; inside, columns 1–3 safe, 4–6
 * warning, 7–8 violation; rows 1–4 territory 1, rows 5–8 territory 2. A portal vessel cut at
 * pixel (6, 2), a hepatic one at (8, 5), the worst point at (3, 4). */
function response(): ResectogramResponse {
  const classes = new Uint8Array(W * H), territories: number[] = [];
  for (let r = 0; r < H; r++) {
    for (let c = 0; c < W; c++) {
      const inside = r > 0 && r < H - 1 && c > 0 && c < W - 1;
      classes[r * W + c] = inside ? (c <= 3 ? 1 : c <= 6 ? 2 : 3) : 0;
      territories.push(inside ? (r <= 4 ? 1 : 2) : 0);
    }
  }
  return {
    planVersion: "7", resection: "r1", width: W, height: H,
    classes: Buffer.from(classes).toString("base64"), territories,
    cutVessels: [
      { system: "VESSEL_SYSTEM_PORTAL", resection: "r1", generation: 1, radiusMm: 5, u: 0.25, v: 0.65 },
      { system: "VESSEL_SYSTEM_HEPATIC", resection: "r1", radiusMm: 1, u: 0.55, v: 0.85 },
    ],
    worstU: 0.45, worstV: 0.35, minMarginMm: 4.5, marginMm: 10, bandMm: 5,
  };
}

function pixel(rgba: Uint8ClampedArray, row: number, col: number): number[] {
  return [...rgba.slice(4 * (row * W + col), 4 * (row * W + col) + 4)];
}

test("a resectogram decodes to its classes, territories, vessels and worst point", () => {
  const r = decodeResectogram(response());
  assert.equal(r.planVersion, 7);
  assert.deepEqual([r.width, r.height, r.resection, r.minMarginMm], [10, 10, "r1", 4.5]);
  assert.deepEqual([r.classes[0], r.classes[11], r.classes[15], r.classes[18]], [0, 1, 2, 3]);
  assert.deepEqual([r.territories[11], r.territories[51]], [1, 2]);
  assert.deepEqual(r.worst, { u: 0.45, v: 0.35 });
  assert.equal(r.cutVessels.length, 2);
});

test("left-out fields decode to their defaults; a wrong size is refused", () => {
  const m = response();
  delete m.territories;
  delete m.worstU;
  delete m.worstV;
  delete m.minMarginMm;
  delete m.cutVessels;
  const r = decodeResectogram(m);
  assert.ok(r.territories.every((t) => t === 0));
  assert.deepEqual([r.worst, r.minMarginMm, r.cutVessels], [null, null, []]);
  assert.throws(() => decodeResectogram({ ...response(), width: 9 }), /100 classes, expected 9×10/);
  assert.throws(() => decodeResectogram({ ...response(), territories: [1, 2] }), /2 territories/);
});

test("classes in the margin colours, outside light grey, opaque", () => {
  assert.deepEqual(CLASS_RGBA, [[219, 219, 219, 255], [158, 158, 158, 255], [255, 217, 0, 255], [230, 13, 13, 255]]);
  const rgba = resectogramRgba(decodeResectogram(response()));
  assert.equal(rgba.length, 4 * W * H);
  assert.deepEqual(pixel(rgba, 0, 0), CLASS_RGBA[0]);
  assert.deepEqual(pixel(rgba, 2, 2), CLASS_RGBA[1]);
  assert.deepEqual(pixel(rgba, 2, 5), CLASS_RGBA[2]);
  assert.deepEqual(pixel(rgba, 2, 7), CLASS_RGBA[3]);
});

test("the liver boundary is black on the inside of where class 0 meets the rest", () => {
  const rgba = resectogramRgba(decodeResectogram(response()));
  for (const [row, col] of [[1, 1], [1, 5], [5, 8], [8, 2], [4, 1]] as const) assert.deepEqual(pixel(rgba, row, col), BOUNDARY_RGBA, `${row},${col}`);
  assert.deepEqual(pixel(rgba, 0, 5), CLASS_RGBA[0]); // outside stays outside
});

test("even territories are shaded; a territory's edge is outlined one pixel wide", () => {
  const rgba = resectogramRgba(decodeResectogram(response()));
  // Row 4 (territory 1) meets row 5 (territory 2): the edge on row 4.
  assert.deepEqual(pixel(rgba, 4, 3), TERRITORY_EDGE_RGBA);
  assert.deepEqual(pixel(rgba, 4, 7), TERRITORY_EDGE_RGBA);
  assert.deepEqual(pixel(rgba, 5, 7), [Math.round(230 * 0.8), Math.round(13 * 0.8), Math.round(13 * 0.8), 255]);
  assert.deepEqual(pixel(rgba, 6, 5), [204, 174, 0, 255]); // warning, territory 2
  assert.deepEqual(pixel(rgba, 3, 7), CLASS_RGBA[3]); // territory 1: as is
});

test("cut vessels are discs at their (u, v): portal blue, hepatic purple", () => {
  assert.equal(discRadius(W, H), 1.5);
  assert.equal(discRadius(200, 300), 4);
  const rgba = resectogramRgba(decodeResectogram(response()));
  // u = 0.25, v = 0.65: centred on pixel (6, 2), its 8 neighbours within 1.5 px.
  for (let row = 5; row <= 7; row++) for (let col = 1; col <= 3; col++) assert.deepEqual(pixel(rgba, row, col), CUT_VESSEL_RGBA.VESSEL_SYSTEM_PORTAL);
  assert.deepEqual(pixel(rgba, 4, 2), TERRITORY_EDGE_RGBA); // 2 px away
  assert.deepEqual(pixel(rgba, 6, 4), [204, 174, 0, 255]);
  assert.deepEqual(CUT_VESSEL_RGBA.VESSEL_SYSTEM_PORTAL, [26, 89, 255, 255]);
  // u = 0.55, v = 0.85: pixel (8, 5); drawn over the outside too.
  assert.deepEqual(pixel(rgba, 8, 5), CUT_VESSEL_RGBA.VESSEL_SYSTEM_HEPATIC);
  assert.deepEqual(pixel(rgba, 9, 6), CUT_VESSEL_RGBA.VESSEL_SYSTEM_HEPATIC);
  assert.deepEqual(CUT_VESSEL_RGBA.VESSEL_SYSTEM_HEPATIC, [153, 38, 204, 255]);
});

test("the worst point is a magenta cross, v down", () => {
  assert.equal(crossArm(W, H), 2);
  assert.equal(crossArm(200, 200), 5);
  assert.deepEqual([pixelOf(0.45, 10), pixelOf(1, 10), pixelOf(-0.1, 10)], [4, 9, 0]);
  const rgba = resectogramRgba(decodeResectogram(response()));
  for (const [row, col] of [[3, 4], [3, 2], [3, 6], [1, 4], [5, 4]] as const) assert.deepEqual(pixel(rgba, row, col), WORST_RGBA, `${row},${col}`);
  assert.deepEqual(pixel(rgba, 3, 7), CLASS_RGBA[3]); // beyond the arm
  assert.deepEqual(pixel(rgba, 2, 3), CLASS_RGBA[1]); // off the cross
  assert.deepEqual(pixel(rgba, 6, 4), [204, 174, 0, 255]);
});
