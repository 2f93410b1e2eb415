// DS and CP resections in the page (thesis Paper II, Sec. 2.5): DS traces drawn on the slice
// view (held here until there are 3, then the resection is made; later ones added, redrawn or
// deleted one by one), CP rings clicked on the liver in the 3D view, and CP deformations
// dragged on the surface with a radius of influence. The panel section lists the traces and
// holds the buttons.

import type { Edit, Resection, Vec3 } from "./api";
import { h } from "./panel";
import type { Plan } from "./plan";
import type { Scene } from "./scene";
import type { SliceView } from "./sliceview";
import {
  addTracedResection, cpNormal, deformationEdit, DS_MIN_TRACES, dsTraceProblem, methodOf, nearestVertex, normalOffset, sliceOf, sortedSlices,
  thin, traceEdit, traceOnSlice,
} from "./traces";

/** What the methods ask of the page. */
export interface MethodActions {
  edit(e: Edit): Promise<boolean>;
  report(text: string, kind?: "ok" | "busy" | "error"): void;
  /** A resection made here: select it once shown. */
  created(name: string): void;
  /** The liver's model names (where CP rings are clicked). */
  liver(): string[];
  render(): void;
}

/** A resection being drawn, not yet on the server. */
interface Drawing {
  method: "ds" | "cp";
  name: string;
  target: Resection["target"];
  traces: Vec3[][]; // CP: one ring
}

/** `window.resecta.drawing()`. */
export interface DrawingState { method: "ds" | "cp"; name: string; traces: Vec3[][] }

/** Thinning of drawn strokes (mm between kept points). */
const STROKE_STEP_MM = 1;

export class Methods {
  readonly root = h("section", { class: "methods", "aria-label": "traces" });
  private plan: Plan | null = null;
  private selected: string | null = null;
  private drawing: Drawing | null = null;
  private selectedTrace: number | null = null;
  private drag: { pointerId: number; name: string; from: Vec3; normal: Vec3; depth: number; to: Vec3 } | null = null;
  private readonly radius = h("input", { type: "range", min: "2", max: "100", step: "1", value: "20", "aria-label": "Deformation radius (mm)" }) as HTMLInputElement;
  private readonly radiusText = h("output", {}, "20 mm");

  constructor(
    private readonly act: MethodActions,
    private readonly scene: Scene,
    private readonly sliceView: SliceView,
    view: HTMLElement,
  ) {
    this.radius.oninput = () => (this.radiusText.textContent = `${this.radius.value} mm`);
    sliceView.onTraceClick = (k) => this.selectTrace(k);
    const capture = { capture: true };
    view.addEventListener("pointerdown", (e) => this.pointerDown(e), capture);
    view.addEventListener("pointermove", (e) => this.pointerMove(e), capture);
    view.addEventListener("pointerup", (e) => this.pointerUp(e), capture);
    view.addEventListener("pointercancel", () => (this.drag = null), capture);
  }

  /** Starts drawing a new DS or CP resection `name` removing `target`. */
  start(method: "ds" | "cp", name: string, target: Resection["target"]): void {
    this.drawing = { method, name, target, traces: method === "cp" ? [[]] : [] };
    this.selectedTrace = null;
    this.act.report(
      method === "ds"
        ? `${name}: drag on the slice view to draw ${DS_MIN_TRACES} traces on ${DS_MIN_TRACES} slices of one orientation`
        : `${name}: click points on the liver in the 3D view around the cut, then Finish`,
      "busy",
    );
    this.refresh();
  }

  drawingState(): DrawingState | null {
    const d = this.drawing;
    return d && { method: d.method, name: d.name, traces: d.traces.map((t) => [...t]) };
  }

  /** Shows `plan` with `selected` as the resection acted on. */
  update(plan: Plan, selected: string | null): void {
    if (selected !== this.selected) this.selectedTrace = null;
    this.plan = plan;
    this.selected = selected;
    this.refresh();
  }

  private resection(): Resection | undefined {
    return this.selected === null ? undefined : this.plan?.resections.get(this.selected)?.resection;
  }

  /** The DS traces acted on: the ones being drawn, else the selected DS resection's. */
  private dsTraces(): { traces: Vec3[][]; pending: boolean } | null {
    if (this.drawing) return this.drawing.method === "ds" ? { traces: this.drawing.traces, pending: true } : null;
    const r = this.resection();
    return methodOf(r) === "ds" ? { traces: (r!.traces ?? []).map((t) => t.points), pending: false } : null;
  }

  private refresh(): void {
    const ds = this.dsTraces();
    this.sliceView.onTrace = ds ? (points) => void this.traceDrawn(points) : null;
    this.sliceView.setTraces((ds?.traces ?? []).map((points, k) => ({ points, pending: ds!.pending, selected: k === this.selectedTrace })));
    const r = this.resection();
    const d = this.drawing;
    if (d) this.scene.showTraces(d.traces, d.method === "cp");
    else this.scene.showTraces(methodOf(r) === "bezier" ? [] : (r!.traces ?? []).map((t) => t.points), methodOf(r) === "cp");
    this.act.render();
    this.root.replaceChildren(...(d ? this.drawingBox(d) : r ? this.resectionBox(r) : []));
  }

  private drawingBox(d: Drawing): HTMLElement[] {
    const cancel = button("Cancel drawing", "Forget what was drawn", () => {
      this.drawing = null;
      this.act.report("Drawing cancelled");
      this.refresh();
    });
    if (d.method === "cp") {
      const ring = d.traces[0]!;
      const finish = button("Finish", "Make the CP resection of this ring", () => void this.finishCp());
      finish.disabled = ring.length < 3;
      const undo = button("Remove last point", "Take back the last point clicked", () => {
        ring.pop();
        this.refresh();
      });
      undo.disabled = ring.length === 0;
      return [
        h("h2", {}, `New CP resection ${d.name}`),
        h("p", { class: "muted" }, `${ring.length} point${ring.length === 1 ? "" : "s"} of the ring: click the liver in the 3D view around the part to remove (at least 3).`),
        h("div", { class: "row" }, finish, undo, cancel),
      ];
    }
    return [
      h("h2", {}, `New DS resection ${d.name}`),
      h("p", { class: "muted" }, `${d.traces.length} of ${DS_MIN_TRACES} traces: drag across the liver on the slice view, one trace per slice, all axial, coronal or sagittal. The surface spans from the first to the last trace's slice.`),
      this.traceList(d.traces),
      h("div", { class: "row" }, cancel),
    ];
  }

  private resectionBox(r: Resection): HTMLElement[] {
    const method = methodOf(r);
    if (method === "bezier") return [];
    const incomplete = this.plan?.volumes?.resections?.find((v) => v.name === r.name && !v.completeCut);
    const warning = incomplete ? [h("p", { class: "bad", role: "alert" }, `⚠ ${incomplete.incompleteReason || "The cut is incomplete"}`)] : [];
    if (method === "ds") {
      return [
        h("h3", {}, "Traces (DS)"),
        h("p", { class: "muted" }, "Drag on a slice to add a trace; on a slice that has one, to redraw it. Click a trace to select it."),
        this.traceList((r.traces ?? []).map((t) => t.points)),
        ...warning,
      ];
    }
    const n = r.deformations?.length ?? 0;
    const undo = button("Undo deformation", "Take back this surface's last deformation", () => void this.act.edit({ undoDeformation: { name: r.name } }));
    undo.disabled = n === 0;
    return [
      h("h3", {}, "Deformable plane (CP)"),
      h("p", { class: "muted" }, `${r.traces?.length ?? 0} trace(s), ${n} deformation(s). Drag on the surface in the 3D view to push it along the plane's normal (look at it from the side).`),
      h("label", { class: "field" }, h("span", {}, "Radius"), this.radius, this.radiusText),
      h("div", { class: "row" }, undo),
      ...warning,
    ];
  }

  /** The DS traces by slice: select (and go to) one, delete it; the previous and next ones. */
  private traceList(traces: Vec3[][]): HTMLElement {
    const slices = sortedSlices(traces);
    const rows = slices.map((s) => {
      const pick = button(`${s.axis} ${s.positionMm.toFixed(1)} mm`, "Show this trace's slice and select it", () => this.selectTrace(s.index));
      pick.className = "link";
      pick.setAttribute("aria-pressed", String(s.index === this.selectedTrace));
      const del = button("Delete", "Delete this trace", () => void this.deleteTrace(s.index));
      del.setAttribute("aria-label", `Delete the trace on ${s.axis} ${s.positionMm.toFixed(1)} mm`);
      return h("li", {}, pick, ` (${traces[s.index]!.length} points) `, del);
    });
    const at = slices.findIndex((s) => s.index === this.selectedTrace);
    const step = (by: number) => {
      const i = at < 0 ? (by > 0 ? 0 : slices.length - 1) : (at + by + slices.length) % slices.length;
      this.selectTrace(slices[i]!.index);
    };
    const nav = slices.length > 1
      ? [h("div", { class: "row" }, button("◀ Previous trace", "The trace on the previous slice", () => step(-1)), button("Next trace ▶", "The trace on the next slice", () => step(1)))]
      : [];
    return h("div", {}, h("ol", { class: "traces" }, ...rows), ...nav);
  }

  /** Selects DS trace `k` and shows its slice. */
  private selectTrace(k: number): void {
    const t = this.dsTraces()?.traces[k];
    const s = t && sliceOf(t);
    if (!s) return;
    this.selectedTrace = k;
    this.sliceView.goTo(s.axis, s.positionMm);
    this.refresh();
  }

  private async deleteTrace(k: number): Promise<void> {
    this.selectedTrace = null;
    if (this.drawing) {
      this.drawing.traces.splice(k, 1);
      return this.refresh();
    }
    const r = this.resection();
    if (r && (await this.act.edit({ removeTrace: { name: r.name, index: k } }))) this.act.report(`Trace deleted from ${r.name}`);
  }

  /** A stroke drawn on the slice view. */
  private async traceDrawn(stroke: Vec3[]): Promise<void> {
    const ds = this.dsTraces();
    if (!ds) return;
    const points = thin(stroke, STROKE_STEP_MM);
    const s = sliceOf(points);
    const replacing = s ? traceOnSlice(ds.traces, s) : null;
    const problem = dsTraceProblem(points, ds.traces, replacing);
    if (problem) return this.act.report(problem, "error");
    const d = this.drawing;
    if (d) {
      if (replacing === null) d.traces.push(points);
      else d.traces[replacing] = points;
      this.selectedTrace = replacing ?? d.traces.length - 1;
      this.refresh();
      if (d.traces.length < DS_MIN_TRACES) return this.act.report(`${d.traces.length} of ${DS_MIN_TRACES} traces drawn`, "busy");
      return this.make(d);
    }
    const r = this.resection()!;
    if (await this.act.edit(traceEdit(r.name, points, replacing))) {
      this.selectedTrace = replacing ?? ds.traces.length;
      this.act.report(replacing === null ? `Trace added to ${r.name}` : `Trace ${replacing + 1} of ${r.name} redrawn`);
    }
  }

  private finishCp(): Promise<void> {
    const d = this.drawing;
    return d ? this.make(d) : Promise.resolve();
  }

  /** Sends the resection drawn; kept here when the server refuses it. */
  private async make(d: Drawing): Promise<void> {
    this.act.report(`Making ${d.name}…`, "busy");
    if (!(await this.act.edit(addTracedResection(d.name, d.method, d.traces, d.target)))) return;
    if (this.drawing === d) this.drawing = null;
    this.selectedTrace = null;
    this.act.report(`${d.name} made`);
    this.act.created(d.name);
    this.refresh();
  }

  private pointerDown(e: PointerEvent): void {
    if (e.button !== 0 || e.ctrlKey || e.altKey || e.metaKey || e.shiftKey) return;
    const d = this.drawing;
    if (d?.method === "cp") {
      const p = this.scene.pickSurface(e.clientX, e.clientY, this.act.liver());
      if (!p) return; // the camera's
      e.stopImmediatePropagation();
      e.preventDefault();
      d.traces[0]!.push(p);
      return this.refresh();
    }
    const r = this.resection();
    if (d || methodOf(r) !== "cp") return;
    const from = this.scene.pickSurface(e.clientX, e.clientY, [r!.name]);
    const mesh = this.scene.mesh(r!.name);
    if (!from || !mesh) return;
    e.stopImmediatePropagation();
    e.preventDefault();
    (e.currentTarget as HTMLElement).setPointerCapture?.(e.pointerId);
    const normal = cpNormal(mesh, nearestVertex(mesh, from));
    this.drag = { pointerId: e.pointerId, name: r!.name, from, normal, depth: this.scene.toScreen(from).depth, to: from };
  }

  private pointerMove(e: PointerEvent): void {
    const g = this.drag;
    if (!g || e.pointerId !== g.pointerId) return;
    e.stopImmediatePropagation();
    e.preventDefault();
    g.to = this.scene.fromScreen({ x: e.clientX, y: e.clientY, depth: g.depth });
    const offset = normalOffset(g.from, g.to, g.normal);
    const n = g.normal;
    this.scene.mark({ x: g.from.x + offset * n.x, y: g.from.y + offset * n.y, z: g.from.z + offset * n.z }, 1.5);
    this.act.render();
    this.act.report(`Deformation of ${g.name}: ${offset >= 0 ? "+" : ""}${offset.toFixed(1)} mm, radius ${this.radius.value} mm`, "busy");
  }

  private pointerUp(e: PointerEvent): void {
    const g = this.drag;
    if (!g || e.pointerId !== g.pointerId) return;
    e.stopImmediatePropagation();
    this.drag = null;
    (e.currentTarget as HTMLElement).releasePointerCapture?.(e.pointerId);
    this.scene.mark(null);
    this.act.render();
    const offset = normalOffset(g.from, g.to, g.normal);
    if (offset === 0) return this.act.report("No deformation: drag along the surface's normal");
    const edit = deformationEdit(g.name, g.from, offset, Number(this.radius.value));
    void this.act.edit(edit).then((ok) => ok && this.act.report(`${g.name} deformed by ${offset.toFixed(1)} mm`));
  }
}

function button(text: string, title: string, run: () => void): HTMLButtonElement {
  const b = h("button", { type: "button", title }, text) as HTMLButtonElement;
  b.onclick = run;
  return b;
}
