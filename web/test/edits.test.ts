// The tools' edits: moves of the surface, a group or one point; rotations; a tumour's target;
// typed numbers checked.

import assert from "node:assert/strict";
import { test } from "node:test";
import type { Resection } from "../src/api";
import { freshName, moveEdit, parseNumber, rotateEdit, tumourTarget } from "../src/edits";
import { vec3 } from "../src/plan";
import type { Mesh } from "../src/wire";

const grid: Resection = {
  name: "r1",
  gridM: 2,
  gridN: 3,
  controlPoints: [0, 1, 2, 3, 4, 5].map((k) => ({ x: k, y: 10 * k, z: -k })),
};

test("the whole surface translates, groups move, one point is set where it goes", () => {
  assert.deepEqual(moveEdit(grid, { kind: "all" }, "y", -5), { translate: { name: "r1", delta: { x: -0, y: -5, z: -0 } } });
  assert.deepEqual(moveEdit(grid, { kind: "inner" }, "z", 2), {
    moveGroup: { name: "r1", group: "CONTROL_GROUP_INNER", delta: { x: 0, y: 0, z: 2 } },
  });
  assert.deepEqual(moveEdit(grid, { kind: "outer" }, "x", 1), {
    moveGroup: { name: "r1", group: "CONTROL_GROUP_OUTER", delta: { x: 1, y: 0, z: 0 } },
  });
  // P(1, 2) is entry 1·3 + 2 = 5: (5, 50, −5), moved 3 mm along +x.
  assert.deepEqual(moveEdit(grid, { kind: "point", i: 1, j: 2 }, "x", 3), {
    setControlPoint: { name: "r1", i: 1, j: 2, point: { x: 8, y: 50, z: -5 } },
  });
});

test("a point outside the grid is refused with the grid's index ranges", () => {
  assert.throws(() => moveEdit(grid, { kind: "point", i: 2, j: 0 }, "x", 1), /no control point \(2, 0\): i is 0\.\.1, j is 0\.\.2/);
  assert.throws(() => moveEdit(grid, { kind: "point", i: 0.5, j: 0 }, "x", 1), RangeError);
  assert.throws(() => moveEdit(grid, { kind: "point", i: -1, j: 0 }, "x", 1), RangeError);
});

test("rotations are about a patient axis through the control points' centroid (the server's default)", () => {
  assert.deepEqual(rotateEdit(grid, "z", -5), { rotate: { name: "r1", axis: { x: 0, y: 0, z: 1 }, angleDeg: -5 } });
});

test("a tumour's target: its label and its vertex nearest the centroid", () => {
  // Four vertices of a square around (1, 1, 0) and one far off that pulls the centroid to (2, 1, 0).
  const positions = Float32Array.from([0, 0, 0, 2, 0, 0, 2, 2, 0, 0, 2, 0, 6, 1, 0]);
  const mesh = { positions, vertexCount: 5 } as unknown as Mesh;
  assert.deepEqual(tumourTarget(7, mesh), { labels: [7], points: [{ x: 2, y: 0, z: 0 }] });
  const empty = { positions: new Float32Array(0), vertexCount: 0 } as unknown as Mesh;
  assert.throws(() => tumourTarget(7, empty), /no vertices/);
});

test("new names skip those taken; typed numbers are checked and named", () => {
  assert.equal(freshName([]), "r1");
  assert.equal(freshName(["r1", "r3", "left"]), "r2");
  assert.equal(parseNumber("Margin", " 12.5 ", 0.1, 100), 12.5);
  assert.throws(() => parseNumber("Margin", "", 0.1, 100), /^RangeError: Margin: type a number$/);
  assert.throws(() => parseNumber("Margin", "1e3", 0.1, 100), /Margin: must be from 0.1 to 100/);
  assert.throws(() => parseNumber("Band", "abc", 0, 100), /Band: type a number/);
});

test("points of the proto JSON get their left-out zero coordinates back", () => {
  assert.deepEqual(vec3({ y: 2 }), { x: 0, y: 2, z: 0 });
  assert.deepEqual(vec3({}), { x: 0, y: 0, z: 0 });
});
