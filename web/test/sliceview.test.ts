// The slice view's pure parts: decoding, colours, the 180° display rotation, pixel ↔ RAS, and
// the request coalescer.

import assert from "node:assert/strict";
import { test } from "node:test";
import { EDGE_LETTERS, Latest, centre, decodeRaster, fit, labelColours, rasterRgba, segmentDistance, toCanvas, toRas } from "../src/sliceview";
import type { Raster, Rgb } from "../src/sliceview";

const PALETTE: Record<string, [Rgb, number]> = { parenchyma: [[1, 0.5, 0], 0.35], tumor: [[0, 1, 0], 1] };

/** A 3×2 axial raster: labels row-major [[0, 1, 2], [1, 1, 9]], 2 mm pixels, pixel (0, 0) at
 * (10, 20, 5). */
function raster(): Raster {
  const bytes = Buffer.from(new Uint16Array([0, 1, 2, 1, 1, 9]).buffer).toString("base64");
  return decodeRaster("axial", 5, {
    width: 3, height: 2, pixelMm: 2, labels: bytes,
    origin: { x: 10, y: 20, z: 5 }, columnAxis: { x: 1 }, rowAxis: { y: 1 },
    minPositionMm: -40, maxPositionMm: 60,
  });
}

test("a label slice decodes to its row-major labels and geometry", () => {
  const r = raster();
  assert.deepEqual([...r.labels], [0, 1, 2, 1, 1, 9]);
  assert.deepEqual(r.columnAxis, { x: 1, y: 0, z: 0 });
  assert.deepEqual(r.rowAxis, { x: 0, y: 1, z: 0 });
  assert.deepEqual([r.minMm, r.maxMm, r.positionMm], [-40, 60, 5]);
  assert.throws(() => decodeRaster("axial", 0, { width: 2, height: 2, labels: "AAAA" }), /2×2/);
});

test("labels take their role's colour, opaque; the rest grey; 0 transparent; rotated by 180°", () => {
  const colours = labelColours({ parenchyma: [1], tumor: [2, 3] }, PALETTE);
  assert.deepEqual([...colours], [[1, [255, 128, 0, 255]], [2, [0, 255, 0, 255]], [3, [0, 255, 0, 255]]]);
  const rgba = rasterRgba(raster(), colours);
  // Display order: the last raster pixel (label 9) first, the first (label 0) last.
  const px = (k: number) => [...rgba.slice(4 * k, 4 * k + 4)];
  assert.deepEqual(px(0), [128, 128, 128, 255]); // label 9: no role
  assert.deepEqual(px(1), [255, 128, 0, 255]);
  assert.deepEqual(px(2), [255, 128, 0, 255]);
  assert.deepEqual(px(3), [0, 255, 0, 255]); // raster (0, 2)
  assert.deepEqual(px(4), [255, 128, 0, 255]);
  assert.deepEqual(px(5), [0, 0, 0, 0]); // raster (0, 0): background
});

test("the raster fits the canvas with its aspect, centred", () => {
  assert.deepEqual(fit(3, 2, 300, 100), { scale: 50, x: 75, y: 0 });
  assert.deepEqual(fit(3, 2, 60, 100), { scale: 20, x: 0, y: 30 });
});

test("pixel centres map to canvas points rotated by 180° and back", () => {
  const r = raster();
  const f = fit(3, 2, 300, 200); // scale 100, no offset
  // Pixel (0, 0) at (10, 20, 5): the bottom-right display pixel, centred at (250, 150).
  assert.deepEqual(toCanvas(r, f, { x: 10, y: 20, z: 5 }), [250, 150]);
  // Right (+x) is to the screen's left, anterior (+y) up: pixel (1, 2) at (14, 22).
  assert.deepEqual(toCanvas(r, f, { x: 14, y: 22, z: 5 }), [50, 50]);
  // Off-plane coordinates project onto it.
  assert.deepEqual(toCanvas(r, f, { x: 12, y: 20, z: 99 }), [150, 150]);
  assert.deepEqual(toRas(r, f, 50, 50), { x: 14, y: 22, z: 5 });
  assert.deepEqual(toRas(r, f, 300, 0), { x: 9, y: 23, z: 5 }); // the raster's corner
});

test("edges are lettered as 3D Slicer's slice views", () => {
  assert.deepEqual(EDGE_LETTERS.axial, ["R", "L", "A", "P"]);
  assert.deepEqual(EDGE_LETTERS.coronal, ["R", "L", "S", "I"]);
  assert.deepEqual(EDGE_LETTERS.sagittal, ["A", "P", "S", "I"]);
});

test("the label map's centre follows its direction and spacing", () => {
  assert.deepEqual(centre([3, 5, 1], [2, 1, 4], [1, 2, 3], [0, 1, 0, -1, 0, 0, 0, 0, 1]), { x: 3, y: 0, z: 3 });
});

test("one call in flight; asks made meanwhile become one call with the newest", async () => {
  const calls: number[] = [];
  const done: number[] = [];
  const pending: (() => void)[] = [];
  const l = new Latest<number, number>(
    (a) => {
      calls.push(a);
      return new Promise((resolve) => pending.push(() => resolve(a * 10)));
    },
    (r) => done.push(r),
    (e) => assert.fail(String(e)),
  );
  l.ask(1);
  l.ask(2);
  l.ask(3);
  assert.deepEqual(calls, [1]);
  pending.shift()!();
  await new Promise((r) => setTimeout(r, 0));
  assert.deepEqual(calls, [1, 3]);
  assert.deepEqual(done, [10]);
  pending.shift()!();
  await new Promise((r) => setTimeout(r, 0));
  assert.deepEqual(done, [10, 30]);
  l.ask(4);
  assert.deepEqual(calls, [1, 3, 4]);
});

test("a click's distance to a trace's segment: to the segment, not its line", () => {
  assert.equal(segmentDistance([5, 3], [0, 0], [10, 0]), 3);
  assert.equal(segmentDistance([13, 4], [0, 0], [10, 0]), 5);
  assert.equal(segmentDistance([1, 1], [2, 2], [2, 2]), Math.SQRT2);
});
