// DS and CP traces: slices, thinning, self-crossing, the checks before sending, the edits, the
// CP normal's sign.

import assert from "node:assert/strict";
import { test } from "node:test";
import type { Vec3 } from "../src/api";
import { resectionOf } from "../src/plan";
import {
  addTracedResection, cpNormal, crossesItself, deformationEdit, dsTraceProblem, methodOf, nearestVertex, normalOffset, sliceOf,
  sortedSlices, thin, traceEdit, traceOnSlice,
} from "../src/traces";
import type { Mesh } from "../src/wire";

const axial = (z: number, y = 0): Vec3[] => [-50, 0, 50].map((x, k) => ({ x, y: y + 5 * (k % 2), z }));
const coronal = (y: number): Vec3[] => [-50, 0, 50].map((x, k) => ({ x, y, z: 5 * (k % 2) }));

test("a trace's slice is the axis-aligned plane all its points lie on (0.01 mm)", () => {
  assert.deepEqual(sliceOf(axial(12.5)), { axis: "axial", positionMm: 12.5 });
  assert.deepEqual(sliceOf(coronal(-3)), { axis: "coronal", positionMm: -3 });
  assert.deepEqual(sliceOf([{ x: 7, y: 0, z: 0 }, { x: 7.005, y: 1, z: 3 }, { x: 7, y: 2, z: 1 }]), { axis: "sagittal", positionMm: 7 });
  assert.equal(sliceOf([{ x: 0, y: 0, z: 0 }, { x: 1, y: 1, z: 1 }]), null);
  assert.equal(sliceOf([]), null);
});

test("a stroke is thinned to points a step apart, its end kept", () => {
  const stroke = Array.from({ length: 101 }, (_, k) => ({ x: k * 0.1, y: 0, z: 0 }));
  const t = thin(stroke, 1);
  assert.equal(t.length, 11);
  assert.deepEqual(t[10], { x: 10, y: 0, z: 0 });
  assert.ok(thin(Array.from({ length: 9000 }, (_, k) => ({ x: k, y: 0, z: 0 })), 0).length <= 4096);
});

test("self-crossing strokes are found; touching ends are not crossings", () => {
  const z = 0;
  const bowtie = [{ x: 0, y: 0, z }, { x: 10, y: 10, z }, { x: 10, y: 0, z }, { x: 0, y: 10, z }];
  assert.equal(crossesItself(bowtie, "axial"), true);
  assert.equal(crossesItself(axial(0), "axial"), false);
  const u = [{ x: 0, y: 10, z }, { x: 0, y: 0, z }, { x: 10, y: 0, z }, { x: 10, y: 10, z }];
  assert.equal(crossesItself(u, "axial"), false);
});

test("DS traces: 3 points, one orientation, one trace per slice, redrawing the slice's own", () => {
  const held = [axial(0), axial(10)];
  assert.equal(dsTraceProblem(axial(20), held), null);
  assert.match(dsTraceProblem(axial(20).slice(0, 2), held)!, /at least 3 points/);
  assert.match(dsTraceProblem(coronal(5), held)!, /axial slices/);
  assert.match(dsTraceProblem(axial(10, 3), held)!, /Trace 2 is on this slice already/);
  assert.equal(dsTraceProblem(axial(10, 3), held, 1), null);
  assert.match(dsTraceProblem([{ x: 0, y: 0, z: 0 }, { x: 1, y: 1, z: 1 }, { x: 2, y: 0, z: 5 }], held)!, /one axial, coronal or sagittal slice/);
  assert.equal(traceOnSlice(held, { axis: "axial", positionMm: 10.004 }), 1);
  assert.equal(traceOnSlice(held, { axis: "coronal", positionMm: 10 }), null);
  assert.deepEqual(sortedSlices([axial(10), axial(-5), axial(3)]).map((s) => s.index), [1, 2, 0]);
});

test("the edits: a DS or CP resection of its traces, a trace added or redrawn, a deformation", () => {
  const e = addTracedResection("ds1", "ds", [axial(0), axial(5), axial(10)], { labels: [2] }) as { addResection: { resection: Record<string, unknown> } };
  assert.deepEqual(Object.keys(e.addResection.resection).sort(), ["bandMm", "kind", "marginMm", "name", "ru", "rv", "target", "traces"]);
  assert.equal(e.addResection.resection["kind"], "RESECTION_KIND_DS");
  assert.equal((e.addResection.resection["traces"] as unknown[]).length, 3);
  const cp = addTracedResection("cp1", "cp", [axial(0)], undefined) as { addResection: { resection: Record<string, unknown> } };
  assert.equal(cp.addResection.resection["kind"], "RESECTION_KIND_CP");
  assert.equal("target" in cp.addResection.resection, false);
  assert.deepEqual(traceEdit("ds1", axial(1), null), { addTrace: { name: "ds1", trace: { points: axial(1) } } });
  assert.deepEqual(traceEdit("ds1", axial(1), 2), { setTrace: { name: "ds1", index: 2, trace: { points: axial(1) } } });
  const o = { x: 1, y: 2, z: 3 };
  assert.equal(normalOffset(o, { x: 4, y: 2, z: 10.26 }, { x: 0, y: 0, z: 1 }), 7.3);
  assert.equal(normalOffset(o, { x: 1, y: 2, z: -500 }, { x: 0, y: 0, z: 1 }), -100);
  assert.deepEqual(deformationEdit("cp1", o, -4, 20), { addDeformation: { name: "cp1", deformation: { point: o, offsetMm: -4, radiusMm: 20 } } });
});

test("the CP normal is minus the surface normal (∂u × ∂v = E₂ × E₁ = −N), from the mesh's normals or its winding", () => {
  // A unit square in z = 0 wound counter-clockwise seen from +z: surface normal +z.
  const positions = Float32Array.from([0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]);
  const triangles = Uint32Array.from([0, 1, 2, 0, 2, 3]);
  const mesh = { positions, triangles, vertexCount: 4, normals: null } as unknown as Mesh;
  assert.deepEqual(cpNormal(mesh, 2), { x: -0, y: -0, z: -1 });
  const withNormals = { ...mesh, normals: Float32Array.from([0, 0, 2, 0, 0, 2, 0, 0, 2, 0, 0, 2]) } as unknown as Mesh;
  assert.deepEqual(cpNormal(withNormals, 0), { x: -0, y: -0, z: -1 });
  assert.equal(nearestVertex(mesh, { x: 0.9, y: 1.2, z: 0 }), 2);
});

test("traces and deformations of the proto JSON get their zero coordinates back; kinds by name", () => {
  const r = resectionOf({ name: "x", kind: "RESECTION_KIND_CP", traces: [{ points: [{ x: 1 } as Vec3] }], deformations: [{ point: { y: 2 } as Vec3, offsetMm: 3 }] });
  assert.deepEqual(r.traces, [{ points: [{ x: 1, y: 0, z: 0 }] }]);
  assert.deepEqual(r.deformations, [{ point: { x: 0, y: 2, z: 0 }, offsetMm: 3 }]);
  assert.equal(methodOf(r), "cp");
  assert.equal(methodOf({ name: "b" }), "bezier");
  assert.equal(methodOf({ name: "d", kind: "RESECTION_KIND_DS" }), "ds");
});
