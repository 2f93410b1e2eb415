// What the client holds of a session: its surfaces' decoded meshes, the resections with their
// verdicts, the volumes; kept up to date by the watch stream's events. No DOM: testable in Node.

import { base64Bytes } from "./api";
import type { Deformation, PlanDelta, Resection, ResectionKind, Session, Snapshot, Vec3, Verdict, VolumeReport, WatchResponse } from "./api";
import { applyDelta, decodeMesh } from "./wire";
import type { Mesh } from "./wire";

export interface Model {
  name: string;
  kind: string; // parenchyma, tumor, portal, hepatic, vessel
  label?: number; // the label value it was built from (tumours: the one a target names)
  rgb?: [number, number, number];
  opacity?: number;
  mesh: Mesh;
}

export interface ResectionState {
  resection: Resection;
  verdict: Verdict;
  mesh: Mesh | null;
}

/** What an event changed: everything (a snapshot), or these surfaces. */
export interface Change {
  all: boolean;
  surfaces: string[]; // new or changed meshes
  removed: string[];
}

/** `window.resecta.state()`. */
export interface PublicState {
  sessionId: string;
  planVersion: number;
  resections: Record<
    string,
    {
      kind: ResectionKind;
      minMarginMm: number | null;
      violation: boolean;
      closestPoint: Vec3 | null;
      marginMm: number | null;
      bandMm: number | null;
      controlPoints: Resection["controlPoints"];
      traces: Vec3[][];
      deformations: Deformation[];
    }
  >;
  volumes: VolumeReport | null;
}

export class Plan {
  session: Session | null = null;
  planVersion = "0";
  seq: string | null = null;
  readonly models = new Map<string, Model>();
  readonly resections = new Map<string, ResectionState>();
  volumes: VolumeReport | null = null;
  volumesVersion: string | null = null; // the plan version the volumes belong to

  constructor(readonly sessionId: string) {}

  /** Replaces everything with a (joined) snapshot. Throws `WireError` on a bad mesh. */
  applySnapshot(s: Snapshot, msg: WatchResponse): Change {
    const models = (s.models ?? []).map((m): Model => {
      const c = m.color;
      const model: Model = { name: m.name, kind: kindName(m.kind), mesh: decodeMesh(base64Bytes(m.mesh ?? "")) };
      if (m.label !== undefined) model.label = m.label;
      if (c) {
        model.rgb = [c.r ?? 0, c.g ?? 0, c.b ?? 0];
        model.opacity = c.a ?? 0;
      }
      return model;
    });
    const resections = (s.resections ?? []).map((r) => [
      r.name,
      { resection: resectionOf(r.resection ?? { name: r.name }), verdict: verdictOf(r.verdict ?? {}), mesh: r.fullMesh ? decodeMesh(base64Bytes(r.fullMesh)) : null },
    ] as const);
    this.models.clear();
    this.resections.clear();
    for (const m of models) this.models.set(m.name, m);
    for (const [name, r] of resections) this.resections.set(name, r);
    this.session = s.session ?? this.session;
    this.volumes = s.volumes ?? null;
    this.volumesVersion = s.volumes ? (msg.planVersion ?? null) : null;
    this.advance(msg);
    return { all: true, surfaces: [...this.models.keys(), ...this.resections.keys()], removed: [] };
  }

  /** Applies a plan change. Throws `WireError` when a mesh delta does not apply to the mesh
   * held (then only a fresh snapshot helps); the meshes it had not reached stay as they were. */
  applyDelta(d: PlanDelta, msg: WatchResponse): Change {
    const change: Change = { all: false, surfaces: [], removed: [] };
    for (const r of d.resections ?? []) {
      const held = this.resections.get(r.name);
      let mesh = held?.mesh ?? null;
      if (r.fullMesh) mesh = decodeMesh(base64Bytes(r.fullMesh));
      else if (r.meshDelta) {
        if (!mesh) throw new Error(`a mesh delta for resection ${JSON.stringify(r.name)}, which has no mesh here`);
        applyDelta(mesh, base64Bytes(r.meshDelta), { inPlace: true });
      }
      this.resections.set(r.name, {
        resection: r.resection ? resectionOf(r.resection) : (held?.resection ?? { name: r.name }),
        verdict: r.verdict ? verdictOf(r.verdict) : (held?.verdict ?? {}),
        mesh,
      });
      if (r.fullMesh || r.meshDelta) change.surfaces.push(r.name);
    }
    for (const name of d.removed ?? []) {
      this.resections.delete(name);
      change.removed.push(name);
    }
    this.advance(msg);
    return change;
  }

  applyVolumes(v: VolumeReport, msg: WatchResponse): void {
    this.volumes = v;
    this.volumesVersion = msg.planVersion ?? null;
    this.seq = msg.seq ?? this.seq;
  }

  state(): PublicState {
    const resections: PublicState["resections"] = {};
    for (const [name, r] of this.resections) {
      resections[name] = {
        minMarginMm: r.verdict.minMarginMm ?? null,
        violation: r.verdict.violation ?? false,
        closestPoint: r.verdict.point ?? null,
        marginMm: r.resection.marginMm ?? null,
        bandMm: r.resection.bandMm ?? null,
        controlPoints: r.resection.controlPoints ?? [],
        kind: r.resection.kind ?? "RESECTION_KIND_BEZIER",
        traces: (r.resection.traces ?? []).map((t) => t.points),
        deformations: r.resection.deformations ?? [],
      };
    }
    return { sessionId: this.sessionId, planVersion: Number(this.planVersion), resections, volumes: this.volumes };
  }

  private advance(msg: WatchResponse): void {
    this.planVersion = msg.planVersion ?? this.planVersion;
    this.seq = msg.seq ?? this.seq;
  }
}

/** "parenchyma", "tumor", ... of a proto `SurfaceKind` name. */
export function kindName(kind: string | undefined): string {
  return (kind ?? "SURFACE_KIND_VESSEL").toLowerCase().replace(/^surface_kind_/, "");
}

/** A point of the proto JSON, whose zero coordinates are left out. */
export const vec3 = (p: Partial<Vec3>): Vec3 => ({ x: p.x ?? 0, y: p.y ?? 0, z: p.z ?? 0 });

/** A resection of the proto JSON with its points' left-out zero coordinates back. */
export function resectionOf(r: Resection): Resection {
  const out = { ...r };
  if (r.controlPoints) out.controlPoints = r.controlPoints.map(vec3);
  if (r.traces) out.traces = r.traces.map((t) => ({ points: (t.points ?? []).map(vec3) }));
  if (r.deformations) out.deformations = r.deformations.map((d) => ({ ...d, point: vec3(d.point ?? {}) }));
  return out;
}

function verdictOf(v: Verdict): Verdict {
  return v.point ? { ...v, point: vec3(v.point) } : v;
}
