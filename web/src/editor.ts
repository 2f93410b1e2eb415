// Editing in the 3D view: the selected resection's control grid, drawn by the scene, picked
// with the mouse (the control point drawn nearest the pointer, within a few pixels) and dragged
// in the camera's view plane. A drag sends `setControlPoint` edits through the coalescer and
// shows the dragged position at once; the server's answer comes back on the watch stream.
// Shift+drag moves the grabbed point's group with it (thesis Sec. 7.3.6: an inner point moves
// the inner points, a border point the outer ring), sent as whole grids (`setControlPoints`).
// Elsewhere the pointer rotates the camera as before.

import type { Api, Vec3 } from "./api";
import { DragCoalescer } from "./drag";
import type { ControlPointKey, DragValue } from "./drag";
import type { Plan } from "./plan";
import type { Scene, ScreenPoint } from "./scene";

/** How far (CSS pixels) from a control point's centre the pointer still grabs it. */
const GRAB_PX = 14;

interface Drag {
  key: ControlPointKey;
  /** A group drag: the grid as it was when grabbed. */
  groupStart: Vec3[] | null;
  pointerId: number;
  grabbed: ScreenPoint; // where the point was drawn when grabbed
  offset: { x: number; y: number }; // pointer minus that
}

export class GridEditor {
  readonly coalescer: DragCoalescer;
  selected: string | null = null;
  /** Positions dragged here the server has not shown back yet, per resection, by index. */
  private readonly local = new Map<string, Map<number, Vec3>>();
  private drag: Drag | null = null;

  constructor(
    api: Api,
    private readonly plan: Plan,
    private readonly scene: Scene,
    private readonly container: HTMLElement,
    private readonly redraw: () => void,
    private readonly report: (error: unknown) => void,
  ) {
    this.coalescer = new DragCoalescer((k, value: DragValue, base) =>
      api.edit(
        plan.sessionId,
        base,
        Array.isArray(value) ? { setControlPoints: { name: k.name, points: value } } : { setControlPoint: { name: k.name, i: k.i, j: k.j, point: value } },
      ),
    );
    this.coalescer.onAnswer = (e) => e && report(e);
    this.coalescer.onIdle = () => {
      this.refresh();
      redraw();
    };
    const capture = { capture: true };
    container.addEventListener("pointerdown", (e) => this.pointerDown(e), capture);
    container.addEventListener("pointermove", (e) => this.pointerMove(e), capture);
    container.addEventListener("pointerup", (e) => this.pointerUp(e), capture);
    container.addEventListener("pointercancel", (e) => this.pointerUp(e), capture);
  }

  /** The control points of `name` as shown: the server's, with positions dragged here. */
  shownPoints(name: string): Vec3[] {
    const points = this.plan.resections.get(name)?.resection.controlPoints ?? [];
    const local = this.local.get(name);
    if (!local) return points;
    return points.map((p, k) => local.get(k) ?? p);
  }

  /** After a plan change: keeps the selection valid, forgets dragged positions the server
   * shows back, redraws the grid. */
  refresh(): void {
    this.coalescer.rebase(this.plan.planVersion);
    if (this.selected === null || !this.plan.resections.has(this.selected)) {
      this.selected = this.plan.resections.keys().next().value ?? null;
    }
    const caughtUp = Number(this.plan.planVersion) >= this.coalescer.acceptedVersion;
    for (const name of [...this.local.keys()]) {
      if (caughtUp && !this.coalescer.busyWith(name) && this.drag?.key.name !== name) this.local.delete(name);
    }
    const r = this.selected === null ? undefined : this.plan.resections.get(this.selected)?.resection;
    this.scene.showGrid(r ? this.shownPoints(r.name) : [], r?.gridM ?? 0, r?.gridN ?? 0);
  }

  select(name: string): void {
    this.selected = name;
    this.refresh();
    this.redraw();
  }

  /** Where control point P_ij of `name` is drawn on the page; null if it has none. */
  screenPosition(name: string, i: number, j: number): ScreenPoint | null {
    const p = this.point({ name, i, j });
    return p ? this.scene.toScreen(p) : null;
  }

  /** Moves P_ij of `name` to `to`: shown at once, sent coalesced (what a mouse drag does). */
  move(key: ControlPointKey, to: Vec3): void {
    const r = this.plan.resections.get(key.name)?.resection;
    const n = r?.gridN ?? 0;
    if (!r || key.i < 0 || key.j < 0 || key.i >= (r.gridM ?? 0) || key.j >= n) {
      throw new RangeError(`no control point (${key.i}, ${key.j}) in resection ${JSON.stringify(key.name)}`);
    }
    let local = this.local.get(key.name);
    if (!local) this.local.set(key.name, (local = new Map()));
    local.set(key.i * n + key.j, to);
    this.coalescer.push(key, to);
    this.refresh();
    this.redraw();
  }

  /** Moves the group of P_ij of `name` (inner points or outer ring) so that P_ij goes to
   * `to`, from the grid `start` (what a Shift+drag does). */
  moveGroup(key: ControlPointKey, to: Vec3, start: Vec3[] = this.shownPoints(key.name)): void {
    const r = this.plan.resections.get(key.name)?.resection;
    const m = r?.gridM ?? 0, n = r?.gridN ?? 0;
    const from = start[key.i * n + key.j];
    if (!r || !from || key.i < 0 || key.j < 0 || key.i >= m || key.j >= n) {
      throw new RangeError(`no control point (${key.i}, ${key.j}) in resection ${JSON.stringify(key.name)}`);
    }
    const members = groupOf(key.i, key.j, m, n);
    const d = { x: to.x - from.x, y: to.y - from.y, z: to.z - from.z };
    const points = start.map((p, k) => (members.includes(k) ? { x: p.x + d.x, y: p.y + d.y, z: p.z + d.z } : p));
    let local = this.local.get(key.name);
    if (!local) this.local.set(key.name, (local = new Map()));
    for (const k of members) local.set(k, points[k]!);
    this.coalescer.push({ name: key.name, i: -1, j: -1 }, points);
    this.refresh();
    this.redraw();
  }

  /** Forgets positions not yet sent (before an undo or a redo). */
  cancelPending(): void {
    this.coalescer.clear();
  }

  private point(key: ControlPointKey): Vec3 | null {
    const r = this.plan.resections.get(key.name)?.resection;
    if (!r) return null;
    return this.shownPoints(key.name)[key.i * (r.gridN ?? 0) + key.j] ?? null;
  }

  /** The control point of the selected resection drawn nearest (`x`, `y`), within GRAB_PX;
   * of several, the one in front. */
  private pick(x: number, y: number): { key: ControlPointKey; at: ScreenPoint } | null {
    const r = this.selected === null ? undefined : this.plan.resections.get(this.selected)?.resection;
    if (!r || !r.gridN) return null;
    let best: { key: ControlPointKey; at: ScreenPoint; score: number } | null = null;
    const points = this.shownPoints(r.name);
    for (let k = 0; k < points.length; k++) {
      const at = this.scene.toScreen(points[k]!);
      const d = Math.hypot(at.x - x, at.y - y);
      if (d > GRAB_PX || at.depth < 0 || at.depth > 1) continue;
      const score = Math.round(d) + at.depth; // nearer the pointer first, then in front
      if (!best || score < best.score) best = { key: { name: r.name, i: Math.floor(k / r.gridN), j: k % r.gridN }, at, score };
    }
    return best;
  }

  private pointerDown(e: PointerEvent): void {
    if (e.button !== 0 || e.ctrlKey || e.altKey || e.metaKey) return;
    const hit = this.pick(e.clientX, e.clientY);
    if (!hit) return; // the camera's (Shift+drag pans)
    const groupStart = e.shiftKey ? this.shownPoints(hit.key.name) : null;
    e.stopPropagation();
    e.preventDefault();
    this.container.setPointerCapture?.(e.pointerId);
    this.drag = { key: hit.key, groupStart, pointerId: e.pointerId, grabbed: hit.at, offset: { x: e.clientX - hit.at.x, y: e.clientY - hit.at.y } };
    this.container.style.cursor = "grabbing";
  }

  private pointerMove(e: PointerEvent): void {
    const d = this.drag;
    if (!d) {
      if (e.buttons === 0) this.container.style.cursor = this.pick(e.clientX, e.clientY) ? "grab" : "";
      return;
    }
    if (e.pointerId !== d.pointerId) return;
    e.stopPropagation();
    e.preventDefault();
    const to = this.scene.fromScreen({ x: e.clientX - d.offset.x, y: e.clientY - d.offset.y, depth: d.grabbed.depth });
    try {
      if (d.groupStart) this.moveGroup(d.key, to, d.groupStart);
      else this.move(d.key, to);
    } catch (err) {
      this.report(err);
    }
  }

  private pointerUp(e: PointerEvent): void {
    const d = this.drag;
    if (!d || e.pointerId !== d.pointerId) return;
    e.stopPropagation();
    this.container.releasePointerCapture?.(e.pointerId);
    this.drag = null;
    this.container.style.cursor = "grab";
    this.refresh();
    this.redraw();
  }
}

/** The indices (row-major) of the group of P_ij in an m × n grid: the border ring when P_ij is
 * on it, else the points inside it (ControlGroup OUTER / INNER). */
export function groupOf(i: number, j: number, m: number, n: number): number[] {
  const border = (a: number, b: number) => a === 0 || b === 0 || a === m - 1 || b === n - 1;
  const outer = border(i, j);
  const out: number[] = [];
  for (let a = 0; a < m; a++) for (let b = 0; b < n; b++) if (border(a, b) === outer) out.push(a * n + b);
  return out;
}
