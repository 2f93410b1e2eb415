// The traces of DS (drawing on slices) and CP (deformable cutting plane) resections (thesis
// Paper II, Sec. 2.5) and the edits that make and change them, checked as the server checks
// them before anything is sent (no DOM: testable in Node).

import type { Deformation, Edit, Resection, ResectionKind, Trace, Vec3 } from "./api";
import type { Mesh } from "./wire";

export type Method = "bezier" | "ds" | "cp";
export const KIND: Record<Method, ResectionKind> = { bezier: "RESECTION_KIND_BEZIER", ds: "RESECTION_KIND_DS", cp: "RESECTION_KIND_CP" };
export const METHOD_NAME: Record<ResectionKind, string> = {
  RESECTION_KIND_UNSPECIFIED: "Bézier",
  RESECTION_KIND_BEZIER: "Bézier",
  RESECTION_KIND_DS: "DS (drawn on slices)",
  RESECTION_KIND_CP: "CP (deformable plane)",
};

export const methodOf = (r: Resection | undefined): Method =>
  r?.kind === "RESECTION_KIND_DS" ? "ds" : r?.kind === "RESECTION_KIND_CP" ? "cp" : "bezier";

export type SliceAxis = "axial" | "coronal" | "sagittal";
/** The RAS coordinate each slice orientation keeps constant. */
export const SLICE_NORMAL: Record<SliceAxis, keyof Vec3> = { axial: "z", coronal: "y", sagittal: "x" };
/** How far (mm) a DS trace's points may stray from their slice (the server's tolerance). */
export const SLICE_TOLERANCE_MM = 0.01;
/** Traces a DS resection needs before the server makes it. */
export const DS_MIN_TRACES = 3;
/** Most points of one trace. */
export const MAX_TRACE_POINTS = 4096;
/** Default safety margin of a new DS or CP resection (mm) and its sampling. */
export const NEW_MARGIN_MM = 10;
const NEW_SAMPLES = 40;

/** A DS trace's slice: its orientation and position. */
export interface Slice { axis: SliceAxis; positionMm: number }

/** The axis-aligned slice every point of `points` lies on, or null. */
export function sliceOf(points: readonly Vec3[]): Slice | null {
  if (!points.length) return null;
  for (const axis of ["axial", "coronal", "sagittal"] as const) {
    const k = SLICE_NORMAL[axis];
    const at = points[0]![k];
    if (points.every((p) => Math.abs(p[k] - at) <= SLICE_TOLERANCE_MM)) return { axis, positionMm: at };
  }
  return null;
}

export const sameSlice = (a: Slice, b: Slice) => a.axis === b.axis && Math.abs(a.positionMm - b.positionMm) <= SLICE_TOLERANCE_MM;

/** A drawn stroke thinned to points at least `stepMm` apart (the last point kept), at most
 * MAX_TRACE_POINTS. */
export function thin(points: readonly Vec3[], stepMm: number): Vec3[] {
  const out: Vec3[] = [];
  for (const p of points) {
    const q = out[out.length - 1];
    if (!q || dist(p, q) >= stepMm) out.push(p);
  }
  const last = points[points.length - 1];
  if (last && out.length > 1 && out[out.length - 1] !== last) out[out.length - 1] = last;
  if (out.length <= MAX_TRACE_POINTS) return out;
  const every = Math.ceil(out.length / MAX_TRACE_POINTS);
  return out.filter((_, i) => i % every === 0);
}

/** Whether the polyline crosses itself (segments that do not share a point). */
export function crossesItself(points: readonly Vec3[], axis: SliceAxis): boolean {
  const [a, b] = (["x", "y", "z"] as const).filter((k) => k !== SLICE_NORMAL[axis]) as [keyof Vec3, keyof Vec3];
  const p = points.map((v) => [v[a], v[b]] as const);
  const orient = (o: readonly number[], q: readonly number[], r: readonly number[]) =>
    Math.sign((q[0]! - o[0]!) * (r[1]! - o[1]!) - (q[1]! - o[1]!) * (r[0]! - o[0]!));
  for (let i = 0; i + 1 < p.length; i++) {
    for (let j = i + 2; j + 1 < p.length; j++) {
      const [p1, p2, q1, q2] = [p[i]!, p[i + 1]!, p[j]!, p[j + 1]!];
      const d1 = orient(p1, p2, q1), d2 = orient(p1, p2, q2), d3 = orient(q1, q2, p1), d4 = orient(q1, q2, p2);
      if (d1 * d2 < 0 && d3 * d4 < 0) return true;
    }
  }
  return false;
}

/** What keeps `points` from being a DS trace beside `others` (replacing trace `replacing`, if
 * given); null when it may be sent. */
export function dsTraceProblem(points: readonly Vec3[], others: readonly Vec3[][], replacing: number | null = null): string | null {
  if (points.length < 3) return "A trace needs at least 3 points: drag a longer line";
  const s = sliceOf(points);
  if (!s) return "A trace must lie on one axial, coronal or sagittal slice";
  for (const [k, o] of others.entries()) {
    if (k === replacing) continue;
    const t = sliceOf(o);
    if (t && t.axis !== s.axis) return `The traces are on ${t.axis} slices: draw this one on a ${t.axis} slice too`;
    if (t && sameSlice(s, t)) return `Trace ${k + 1} is on this slice already: select it to redraw it`;
  }
  if (crossesItself(points, s.axis)) return "The trace crosses itself: draw it again";
  return null;
}

/** The index of the trace of `traces` on slice `s`, or null. */
export function traceOnSlice(traces: readonly Vec3[][], s: Slice): number | null {
  const k = traces.findIndex((t) => {
    const u = sliceOf(t);
    return u !== null && sameSlice(u, s);
  });
  return k < 0 ? null : k;
}

/** The slices of `traces` in order along their axis (navigation between them). */
export function sortedSlices(traces: readonly Vec3[][]): (Slice & { index: number })[] {
  return traces
    .flatMap((t, index) => {
      const s = sliceOf(t);
      return s ? [{ ...s, index }] : [];
    })
    .sort((a, b) => a.positionMm - b.positionMm);
}

/** A new DS or CP resection of `traces`. */
export function addTracedResection(name: string, method: "ds" | "cp", traces: readonly Vec3[][], target: Resection["target"]): Edit {
  const resection: Resection = {
    name,
    kind: KIND[method],
    traces: traces.map((points): Trace => ({ points: [...points] })),
    marginMm: NEW_MARGIN_MM,
    bandMm: 0,
    ru: NEW_SAMPLES,
    rv: NEW_SAMPLES,
  };
  if (target) resection.target = target;
  return { addResection: { resection } };
}

/** The edit adding `points` to resection `name`, or redrawing its trace `index`. */
export function traceEdit(name: string, points: readonly Vec3[], index: number | null): Edit {
  const trace = { points: [...points] };
  return index === null ? { addTrace: { name, trace } } : { setTrace: { name, index, trace } };
}

/** The drag from `from` to `to` along the plane normal `normal` (unit), rounded to 0.1 mm and
 * kept within ±100 mm. */
export function normalOffset(from: Vec3, to: Vec3, normal: Vec3): number {
  return Math.max(-100, Math.min(100, Math.round(10 * dot(sub(to, from), normal)) / 10));
}

/** A deformation of CP resection `name` at `point` by `offsetMm` along its plane's normal. */
export function deformationEdit(name: string, point: Vec3, offsetMm: number, radiusMm: number): Edit {
  const deformation: Deformation = { point, offsetMm, radiusMm };
  return { addDeformation: { name, deformation } };
}

/** The CP plane normal N at mesh vertex `k` of a CP surface: the CP grid's frame is (E₂, E₁, N)
 * along (u, v, normal), so the surface normal ∂u × ∂v the server sends (or the triangles'
 * winding gives) is E₂ × E₁ = −N. */
export function cpNormal(mesh: Mesh, k: number): Vec3 {
  const n = vertexNormal(mesh, k);
  return { x: -n.x, y: -n.y, z: -n.z };
}

/** The unit normal of vertex `k`: the mesh's, else the area-weighted one of its triangles. */
export function vertexNormal(mesh: Mesh, k: number): Vec3 {
  if (mesh.normals) return unit({ x: mesh.normals[3 * k]!, y: mesh.normals[3 * k + 1]!, z: mesh.normals[3 * k + 2]! });
  const t = mesh.triangles, at = (v: number): Vec3 => ({ x: mesh.positions[3 * v]!, y: mesh.positions[3 * v + 1]!, z: mesh.positions[3 * v + 2]! });
  let sum: Vec3 = { x: 0, y: 0, z: 0 };
  for (let i = 0; i < t.length; i += 3) {
    if (t[i] !== k && t[i + 1] !== k && t[i + 2] !== k) continue;
    const [a, b, c] = [at(t[i]!), at(t[i + 1]!), at(t[i + 2]!)];
    sum = add(sum, cross(sub(b, a), sub(c, a)));
  }
  return unit(sum);
}

/** The index of the vertex of `mesh` nearest `p`. */
export function nearestVertex(mesh: Mesh, p: Vec3): number {
  let best = 0, bestD = Infinity;
  const q = mesh.positions;
  for (let v = 0; v < mesh.vertexCount; v++) {
    const d = (q[3 * v]! - p.x) ** 2 + (q[3 * v + 1]! - p.y) ** 2 + (q[3 * v + 2]! - p.z) ** 2;
    if (d < bestD) (best = v), (bestD = d);
  }
  return best;
}

const sub = (a: Vec3, b: Vec3): Vec3 => ({ x: a.x - b.x, y: a.y - b.y, z: a.z - b.z });
const add = (a: Vec3, b: Vec3): Vec3 => ({ x: a.x + b.x, y: a.y + b.y, z: a.z + b.z });
const dot = (a: Vec3, b: Vec3) => a.x * b.x + a.y * b.y + a.z * b.z;
const dist = (a: Vec3, b: Vec3) => Math.hypot(a.x - b.x, a.y - b.y, a.z - b.z);
const cross = (a: Vec3, b: Vec3): Vec3 => ({ x: a.y * b.z - a.z * b.y, y: a.z * b.x - a.x * b.z, z: a.x * b.y - a.y * b.x });
function unit(v: Vec3): Vec3 {
  const l = Math.hypot(v.x, v.y, v.z) || 1;
  return { x: v.x / l, y: v.y / l, z: v.z / l };
}
