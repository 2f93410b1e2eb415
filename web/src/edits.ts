// The plan edits the panel's tools send, built from what the person chose (no DOM: testable in
// Node): moves of the whole surface, a group or one control point along a patient axis,
// rotations about a patient axis through the control points' centroid, a new resection's
// target from a tumour model, and the checks of typed numbers.

import type { Edit, Resection, Vec3 } from "./api";
import type { Mesh } from "./wire";

/** Which control points a move takes. */
export type Selection = { kind: "all" } | { kind: "inner" } | { kind: "outer" } | { kind: "point"; i: number; j: number };

/** The patient axes (RAS), as the buttons name their directions. */
export const AXES = {
  x: { x: 1, y: 0, z: 0 },
  y: { x: 0, y: 1, z: 0 },
  z: { x: 0, y: 0, z: 1 },
} as const satisfies Record<string, Vec3>;
export type Axis = keyof typeof AXES;

const scale = (v: Vec3, s: number): Vec3 => ({ x: v.x * s, y: v.y * s, z: v.z * s });
const add = (a: Vec3, b: Vec3): Vec3 => ({ x: a.x + b.x, y: a.y + b.y, z: a.z + b.z });

/** Moves `selection` of `r` by `mm` along `axis` (negative: the other way). */
export function moveEdit(r: Resection, selection: Selection, axis: Axis, mm: number): Edit {
  const delta = scale(AXES[axis], mm);
  switch (selection.kind) {
    case "all":
      return { translate: { name: r.name, delta } };
    case "inner":
      return { moveGroup: { name: r.name, group: "CONTROL_GROUP_INNER", delta } };
    case "outer":
      return { moveGroup: { name: r.name, group: "CONTROL_GROUP_OUTER", delta } };
    case "point": {
      const { i, j } = selection;
      const m = r.gridM ?? 0, n = r.gridN ?? 0;
      const p = r.controlPoints?.[i * n + j];
      if (!Number.isInteger(i) || !Number.isInteger(j) || i < 0 || j < 0 || i >= m || j >= n || !p) {
        throw new RangeError(`resection ${r.name} has no control point (${i}, ${j}): i is 0..${m - 1}, j is 0..${n - 1}`);
      }
      return { setControlPoint: { name: r.name, i, j, point: add(p, delta) } };
    }
  }
}

/** Rotates `r` by `deg` degrees about `axis` through the centroid of its control points. */
export function rotateEdit(r: Resection, axis: Axis, deg: number): Edit {
  return { rotate: { name: r.name, axis: AXES[axis], angleDeg: deg } };
}

/** The target of a resection removing the tumour drawn by `mesh` (label `label`): its label
 * and the mesh vertex nearest the mesh's centroid, which lies on that tumour's boundary, so
 * the server picks this component of the label and no other. */
export function tumourTarget(label: number, mesh: Mesh): { labels: number[]; points: Vec3[] } {
  const p = mesh.positions;
  const count = p.length / 3;
  if (count === 0) throw new RangeError("the tumour model has no vertices");
  let cx = 0, cy = 0, cz = 0;
  for (let v = 0; v < count; v++) {
    cx += p[3 * v]!;
    cy += p[3 * v + 1]!;
    cz += p[3 * v + 2]!;
  }
  cx /= count;
  cy /= count;
  cz /= count;
  let best = 0, bestD = Infinity;
  for (let v = 0; v < count; v++) {
    const d = (p[3 * v]! - cx) ** 2 + (p[3 * v + 1]! - cy) ** 2 + (p[3 * v + 2]! - cz) ** 2;
    if (d < bestD) (best = v), (bestD = d);
  }
  return { labels: [label], points: [{ x: p[3 * best]!, y: p[3 * best + 1]!, z: p[3 * best + 2]! }] };
}

/** The first of r1, r2, … not in `taken`. */
export function freshName(taken: Iterable<string>): string {
  const names = new Set(taken);
  for (let k = 1; ; k++) if (!names.has(`r${k}`)) return `r${k}`;
}

/** A number typed into `field`, checked against [lo, hi]; throws a message naming the field. */
export function parseNumber(field: string, text: string, lo: number, hi: number): number {
  const t = text.trim();
  const v = t === "" ? NaN : Number(t);
  if (!Number.isFinite(v)) throw new RangeError(`${field}: type a number`);
  if (v < lo || v > hi) throw new RangeError(`${field}: must be from ${lo} to ${hi}`);
  return v;
}
