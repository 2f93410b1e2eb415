// The 2D slice view: one axial, coronal or sagittal plane of the label map, resampled by the
// server (GetLabelSlice), painted in the structures' colours, with every resection's contour on
// that plane (GetSlices) drawn over it. Shown as 3D Slicer shows its slice views: patient right
// on the screen's left in axial and coronal views (radiological), anterior on the screen's left
// in sagittal views, superior (or anterior, axial) up; in raster terms, rotated by 180°.

import { base64Bytes } from "./api";
import type { Api, LabelSliceResponse, RoleMap, Session, SliceAxis, SlicesResponse, Vec3 } from "./api";

export type Axis = "axial" | "coronal" | "sagittal";
export type Rgb = [number, number, number];
export type Rgba = [number, number, number, number];

const AXES: readonly Axis[] = ["axial", "coronal", "sagittal"];
const WIRE_AXIS: Record<Axis, SliceAxis> = { axial: "SLICE_AXIS_AXIAL", coronal: "SLICE_AXIS_CORONAL", sagittal: "SLICE_AXIS_SAGITTAL" };
/** The RAS coordinate each axis' plane fixes. */
const NORMAL: Record<Axis, keyof Vec3> = { axial: "z", coronal: "y", sagittal: "x" };
/** Patient directions at the canvas' left, right, top and bottom edges. */
export const EDGE_LETTERS: Record<Axis, [string, string, string, string]> = {
  axial: ["R", "L", "A", "P"],
  coronal: ["R", "L", "S", "I"],
  sagittal: ["A", "P", "S", "I"],
};
/** Colour of labels of no role, and of the orientation letters. */
const OTHER: Rgba = [128, 128, 128, 255];
const LETTER_COLOUR = "#ffd24a";
/** Colour of DS traces: committed, and held here until the resection is made (dashed). */
const TRACE_COLOUR = "#4ad8ff";
/** How near (canvas pixels) a click must be to a trace to select it; a stroke shorter than
 * this (raster pixels) is a click. */
const TRACE_PX = 8;

/** A trace to draw on the slice it lies on. */
export interface ShownTrace { points: Vec3[]; pending: boolean; selected: boolean }

/** A decoded label slice. */
export interface Raster {
  axis: Axis;
  positionMm: number;
  width: number;
  height: number;
  pixelMm: number;
  origin: Vec3;
  columnAxis: Vec3;
  rowAxis: Vec3;
  labels: Uint16Array;
  minMm: number;
  maxMm: number;
}

const vec = (v: Partial<Vec3> | undefined): Vec3 => ({ x: v?.x ?? 0, y: v?.y ?? 0, z: v?.z ?? 0 });
const dot = (a: Vec3, b: Vec3) => a.x * b.x + a.y * b.y + a.z * b.z;

export function decodeRaster(axis: Axis, positionMm: number, m: LabelSliceResponse): Raster {
  const bytes = base64Bytes(m.labels ?? "");
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const labels = new Uint16Array(bytes.byteLength >> 1);
  for (let i = 0; i < labels.length; i++) labels[i] = view.getUint16(2 * i, true);
  const width = m.width ?? 0, height = m.height ?? 0;
  if (labels.length !== width * height) throw new Error(`label slice of ${labels.length} pixels, expected ${width}×${height}`);
  return {
    axis, positionMm, width, height, labels,
    pixelMm: m.pixelMm ?? 1,
    origin: vec(m.origin),
    columnAxis: vec(m.columnAxis),
    rowAxis: vec(m.rowAxis),
    minMm: m.minPositionMm ?? 0,
    maxMm: m.maxPositionMm ?? 0,
  };
}

/** RGBA (0–255) of every label of `roles`, in the 3D view's colour of its role (`palette`: role →
 * [rgb in 0–1, opacity]), opaque. */
export function labelColours(roles: RoleMap | undefined, palette: Record<string, [Rgb, number]>): Map<number, Rgba> {
  const out = new Map<number, Rgba>();
  for (const [role, labels] of Object.entries(roles ?? {}) as [string, number[] | undefined][]) {
    const rgb = palette[role]?.[0];
    if (!rgb) continue;
    for (const l of labels ?? []) out.set(l, [...rgb.map((c) => Math.round(255 * c)), 255] as Rgba);
  }
  return out;
}

/** The raster as RGBA rows in display order (rotated by 180°): label 0 transparent, labels of
 * no role grey. */
export function rasterRgba(r: Raster, colours: Map<number, Rgba>): Uint8ClampedArray<ArrayBuffer> {
  const out = new Uint8ClampedArray(4 * r.width * r.height);
  const n = r.labels.length;
  for (let k = 0; k < n; k++) {
    const l = r.labels[k]!;
    if (l === 0) continue;
    out.set(colours.get(l) ?? OTHER, 4 * (n - 1 - k));
  }
  return out;
}

/** Where the raster is drawn in a canvas: `scale` canvas pixels per raster pixel (the aspect
 * kept), its top-left corner at (x, y), centred. */
export interface Fit { scale: number; x: number; y: number }

export function fit(width: number, height: number, canvasWidth: number, canvasHeight: number): Fit {
  const scale = Math.min(canvasWidth / width, canvasHeight / height);
  return { scale, x: (canvasWidth - width * scale) / 2, y: (canvasHeight - height * scale) / 2 };
}

/** Canvas position of a RAS point (projected on the plane). */
export function toCanvas(r: Raster, f: Fit, p: Vec3): [number, number] {
  const d = { x: p.x - r.origin.x, y: p.y - r.origin.y, z: p.z - r.origin.z };
  const c = dot(d, r.columnAxis) / r.pixelMm, row = dot(d, r.rowAxis) / r.pixelMm;
  return [f.x + (r.width - 0.5 - c) * f.scale, f.y + (r.height - 0.5 - row) * f.scale];
}

/** The RAS point on the plane at a canvas position. */
export function toRas(r: Raster, f: Fit, x: number, y: number): Vec3 {
  const c = r.width - 0.5 - (x - f.x) / f.scale, row = r.height - 0.5 - (y - f.y) / f.scale;
  const s = r.pixelMm;
  const at = (k: keyof Vec3) => r.origin[k] + (c * r.columnAxis[k] + row * r.rowAxis[k]) * s;
  return { x: at("x"), y: at("y"), z: at("z") };
}

/** At most one call in flight; asks made meanwhile become one call after it, with the newest
 * arguments. Every answer is handed over (the newest known is better than none during a drag). */
export class Latest<A, R> {
  private busy = false;
  private next: { a: A } | null = null;

  constructor(
    private readonly call: (a: A) => Promise<R>,
    private readonly done: (r: R, a: A) => void,
    private readonly failed: (e: unknown) => void,
  ) {}

  ask(a: A): void {
    this.next = { a };
    if (!this.busy) void this.run();
  }

  private async run(): Promise<void> {
    this.busy = true;
    for (let n = this.next; n; n = this.next) {
      this.next = null;
      try {
        this.done(await this.call(n.a), n.a);
      } catch (e) {
        this.failed(e);
      }
    }
    this.busy = false;
  }
}

/** The contours of one resection on one plane: packed x, y, z per point. */
interface Contour { points: Float32Array; closed: boolean }
interface Plane { axis: Axis; positionMm: number }

function decodeContours(axis: Axis, m: SlicesResponse): Contour[] {
  return (m[axis] ?? []).map((l) => {
    const b = base64Bytes(l.points ?? "");
    const view = new DataView(b.buffer, b.byteOffset, b.byteLength);
    const points = new Float32Array(b.byteLength >> 2);
    for (let i = 0; i < points.length; i++) points[i] = view.getFloat32(4 * i, true);
    return { points, closed: l.closed ?? false };
  });
}

/** `window.resecta.slice()`. */
export interface SliceState {
  axis: Axis;
  positionMm: number;
  width: number;
  height: number;
  contours: number;
  picked: Vec3 | null;
  /** DS traces drawn on this slice. */
  traces: number;
}

export class SliceView {
  /** Called with the RAS point under a click on the slice. */
  onPick: ((p: Vec3) => void) | null = null;
  /** While set, a drag on the slice draws a trace, handed over here (RAS, on the slice). */
  onTrace: ((points: Vec3[]) => void) | null = null;
  /** Called with the index (in `setTraces`' list) of a trace clicked on. */
  onTraceClick: ((index: number) => void) | null = null;
  private traces: ShownTrace[] = [];
  private stroke: { pointerId: number; points: Vec3[]; px: number } | null = null;
  private drew = false;
  private sessionId = "";
  private axis: Axis = "axial";
  private focus: Vec3 = { x: 0, y: 0, z: 0 };
  private names: string[] = [];
  private selected: string | null = null;
  private colours = new Map<number, Rgba>();
  private raster: Raster | null = null;
  private contours: { plane: Plane; lines: Map<string, Contour[]> } | null = null;
  private picked: Vec3 | null = null;
  private frame = 0;
  private readonly canvas: HTMLCanvasElement;
  private readonly image = document.createElement("canvas");
  private readonly slider: HTMLInputElement;
  private readonly readout: HTMLElement;
  private readonly buttons = new Map<Axis, HTMLButtonElement>();
  private readonly labelSlices: Latest<Plane, Raster>;
  private readonly contourSlices: Latest<Plane, Map<string, Contour[]>>;

  constructor(
    root: HTMLElement,
    private readonly api: Api,
    private readonly palette: Record<string, [Rgb, number]>,
    private readonly contourRgb: Rgb,
    onError: (e: unknown) => void,
  ) {
    const bar = el("div", "slice-bar");
    for (const axis of AXES) {
      const b = el("button", "");
      b.type = "button";
      b.textContent = axis[0]!.toUpperCase() + axis.slice(1);
      b.addEventListener("click", () => this.setAxis(axis));
      this.buttons.set(axis, b);
      bar.append(b);
    }
    this.slider = el("input", "");
    this.slider.type = "range";
    this.slider.setAttribute("aria-label", "Slice position");
    this.slider.addEventListener("input", () => this.setPosition(Number(this.slider.value)));
    this.readout = el("span", "slice-mm");
    bar.append(this.slider, this.readout);
    this.canvas = el("canvas", "slice-canvas");
    this.canvas.addEventListener("pointerdown", (e) => this.strokeStart(e));
    this.canvas.addEventListener("pointermove", (e) => this.strokeMove(e));
    this.canvas.addEventListener("pointerup", (e) => this.strokeEnd(e));
    this.canvas.addEventListener("pointercancel", () => (this.stroke = null));
    this.canvas.addEventListener("click", (e) => {
      if (this.drew) return void (this.drew = false);
      const k = this.traceNear(e.clientX, e.clientY);
      if (k !== null && this.onTraceClick) return this.onTraceClick(k);
      const p = this.pointAt(e.clientX, e.clientY);
      if (!p) return;
      this.picked = p;
      this.onPick?.(p);
    });
    root.append(bar, this.canvas);
    new ResizeObserver(() => this.paint()).observe(this.canvas);
    this.labelSlices = new Latest(
      (p) => this.api.labelSlice(this.sessionId, WIRE_AXIS[p.axis], p.positionMm).then((m) => decodeRaster(p.axis, p.positionMm, m)),
      (r) => this.showRaster(r),
      onError,
    );
    this.contourSlices = new Latest((p) => this.fetchContours(p), (lines, plane) => {
      this.contours = { plane, lines };
      this.paint();
    }, onError);
    this.markAxis();
  }

  /** Shows a session: its roles' colours, its label map's centre, its resections. */
  open(session: Session, resections: string[]): void {
    this.sessionId = session.id;
    const lm = session.labelMap;
    this.colours = labelColours(lm?.roles, this.palette);
    this.focus = centre(lm?.dims ?? [1, 1, 1], lm?.spacing ?? [1, 1, 1], lm?.origin ?? [0, 0, 0], lm?.direction ?? [1, 0, 0, 0, 1, 0, 0, 0, 1]);
    this.names = resections;
    this.request(true);
  }

  /** The plan changed: the resections' contours are asked for again. */
  planChanged(resections: string[], selected: string | null): void {
    this.names = resections;
    this.select(selected);
    if (this.sessionId) this.request(false);
  }

  /** Draws the contour of `name` thicker. */
  select(name: string | null): void {
    this.selected = name;
    this.paint();
  }

  /** The DS traces to draw (each on its own slice). */
  setTraces(traces: ShownTrace[]): void {
    this.traces = traces;
    this.paint();
  }

  /** Shows the plane `axis` at `mm`. */
  goTo(axis: Axis, mm: number): void {
    this.axis = axis;
    this.markAxis();
    this.setPosition(mm);
  }

  setAxis(axis: Axis): void {
    this.axis = axis;
    this.markAxis();
    this.request(true);
  }

  setPosition(mm: number): void {
    this.focus = { ...this.focus, [NORMAL[this.axis]]: mm };
    this.readout.textContent = `${mm.toFixed(1)} mm`;
    this.request(true);
  }

  /** The RAS point under a client position, or null off the raster. */
  pointAt(clientX: number, clientY: number): Vec3 | null {
    const r = this.raster;
    if (!r) return null;
    const rect = this.canvas.getBoundingClientRect();
    const dpr = this.canvas.width / Math.max(1, rect.width);
    const x = (clientX - rect.left) * dpr, y = (clientY - rect.top) * dpr;
    const f = fit(r.width, r.height, this.canvas.width, this.canvas.height);
    const inside = x >= f.x && y >= f.y && x <= f.x + r.width * f.scale && y <= f.y + r.height * f.scale;
    return inside ? toRas(r, f, x, y) : null;
  }

  state(): SliceState | null {
    const r = this.raster;
    if (!r) return null;
    const lines = this.shownContours();
    const contours = lines ? [...lines.values()].reduce((n, ls) => n + ls.length, 0) : 0;
    const traces = this.tracesShown(r).length;
    return { axis: r.axis, positionMm: r.positionMm, width: r.width, height: r.height, contours, picked: this.picked, traces };
  }

  /** The traces lying on the raster's plane, with their indices. */
  private tracesShown(r: Raster): [number, ShownTrace][] {
    const k = NORMAL[r.axis];
    return [...this.traces.entries()].filter(([, t]) => t.points.length > 0 && t.points.every((p) => Math.abs(p[k] - r.positionMm) <= 0.01));
  }

  /** The trace drawn within TRACE_PX of a client position, or null. */
  private traceNear(clientX: number, clientY: number): number | null {
    const r = this.raster;
    if (!r) return null;
    const rect = this.canvas.getBoundingClientRect();
    const dpr = this.canvas.width / Math.max(1, rect.width);
    const x = (clientX - rect.left) * dpr, y = (clientY - rect.top) * dpr;
    const f = fit(r.width, r.height, this.canvas.width, this.canvas.height);
    let best: number | null = null, bestD = TRACE_PX * dpr;
    for (const [k, t] of this.tracesShown(r)) {
      const xy = t.points.map((p) => toCanvas(r, f, p));
      for (let i = 0; i + 1 < xy.length; i++) {
        const d = segmentDistance([x, y], xy[i]!, xy[i + 1]!);
        if (d <= bestD) (best = k), (bestD = d);
      }
    }
    return best;
  }

  private strokeStart(e: PointerEvent): void {
    if (!this.onTrace || e.button !== 0) return;
    const p = this.pointAt(e.clientX, e.clientY);
    if (!p) return;
    this.canvas.setPointerCapture?.(e.pointerId);
    this.stroke = { pointerId: e.pointerId, points: [p], px: 0 };
  }

  private strokeMove(e: PointerEvent): void {
    const s = this.stroke;
    if (!s || e.pointerId !== s.pointerId) return;
    const p = this.pointAt(e.clientX, e.clientY);
    if (!p) return;
    const r = this.raster!;
    s.px += Math.hypot(...(["x", "y", "z"] as const).map((k) => p[k] - s.points[s.points.length - 1]![k])) / r.pixelMm;
    s.points.push(p);
    if (s.px > TRACE_PX) this.paint();
  }

  private strokeEnd(e: PointerEvent): void {
    const s = this.stroke, r = this.raster;
    if (!s || e.pointerId !== s.pointerId || !r) return;
    this.stroke = null;
    this.canvas.releasePointerCapture?.(e.pointerId);
    if (s.px <= TRACE_PX) return; // a click
    this.drew = true;
    setTimeout(() => (this.drew = false), 0); // no click follows a drag that left the canvas
    const k = NORMAL[r.axis];
    this.onTrace?.(s.points.map((p) => ({ ...p, [k]: r.positionMm })));
    this.paint();
  }

  private plane(): Plane {
    return { axis: this.axis, positionMm: this.focus[NORMAL[this.axis]] };
  }

  private request(labels: boolean): void {
    const plane = this.plane();
    if (labels) this.labelSlices.ask(plane);
    this.contourSlices.ask(plane);
  }

  private async fetchContours(p: Plane): Promise<Map<string, Contour[]>> {
    const answers = await Promise.all(
      this.names.map((n) => this.api.slices(this.sessionId, n, { [p.axis]: p.positionMm }).then((m) => [n, decodeContours(p.axis, m)] as const)),
    );
    return new Map(answers);
  }

  private showRaster(r: Raster): void {
    this.raster = r;
    this.image.width = r.width;
    this.image.height = r.height;
    this.image.getContext("2d")!.putImageData(new ImageData(rasterRgba(r, this.colours), r.width, r.height), 0, 0);
    this.slider.min = String(r.minMm);
    this.slider.max = String(r.maxMm);
    this.slider.step = String(r.pixelMm);
    // An older plane's answer during a drag leaves the slider where the hand is.
    if (r.axis === this.axis && r.positionMm === this.plane().positionMm) {
      this.slider.value = String(r.positionMm);
      this.readout.textContent = `${r.positionMm.toFixed(1)} mm`;
    }
    this.paint();
  }

  /** The contours of the raster's plane, if they have come. */
  private shownContours(): Map<string, Contour[]> | null {
    const c = this.contours, r = this.raster;
    return c && r && c.plane.axis === r.axis && c.plane.positionMm === r.positionMm ? c.lines : null;
  }

  private markAxis(): void {
    for (const [axis, b] of this.buttons) b.setAttribute("aria-pressed", String(axis === this.axis));
  }

  private paint(): void {
    this.frame ||= requestAnimationFrame(() => {
      this.frame = 0;
      this.draw();
    });
  }

  private draw(): void {
    const c = this.canvas;
    const dpr = window.devicePixelRatio || 1;
    c.width = Math.max(1, Math.round(c.clientWidth * dpr));
    c.height = Math.max(1, Math.round(c.clientHeight * dpr));
    const g = c.getContext("2d")!;
    g.clearRect(0, 0, c.width, c.height);
    const r = this.raster;
    if (!r) return;
    const f = fit(r.width, r.height, c.width, c.height);
    g.imageSmoothingEnabled = false;
    g.drawImage(this.image, f.x, f.y, r.width * f.scale, r.height * f.scale);
    g.strokeStyle = `rgb(${this.contourRgb.map((v) => Math.round(255 * v)).join(",")})`;
    g.lineJoin = "round";
    for (const [name, lines] of this.shownContours() ?? []) {
      g.lineWidth = (name === this.selected ? 3 : 1.5) * dpr;
      for (const { points, closed } of lines) {
        g.beginPath();
        for (let i = 0; i < points.length; i += 3) {
          const [x, y] = toCanvas(r, f, { x: points[i]!, y: points[i + 1]!, z: points[i + 2]! });
          if (i === 0) g.moveTo(x, y);
          else g.lineTo(x, y);
        }
        if (closed) g.closePath();
        g.stroke();
      }
    }
    g.strokeStyle = TRACE_COLOUR;
    const stroke = this.stroke && this.stroke.px > TRACE_PX ? [[-1, { points: this.stroke.points, pending: true, selected: false }] as const] : [];
    for (const [, t] of [...this.tracesShown(r), ...stroke]) {
      g.lineWidth = (t.selected ? 3.5 : 2) * dpr;
      g.setLineDash(t.pending ? [6 * dpr, 4 * dpr] : []);
      g.beginPath();
      t.points.forEach((p, i) => {
        const [x, y] = toCanvas(r, f, p);
        if (i === 0) g.moveTo(x, y);
        else g.lineTo(x, y);
      });
      g.stroke();
    }
    g.setLineDash([]);
    const [left, right, top, bottom] = EDGE_LETTERS[r.axis];
    const m = 6 * dpr;
    g.fillStyle = LETTER_COLOUR;
    g.font = `${Math.round(14 * dpr)}px system-ui, sans-serif`;
    g.textBaseline = "middle";
    g.textAlign = "left";
    g.fillText(left, m, c.height / 2);
    g.textAlign = "right";
    g.fillText(right, c.width - m, c.height / 2);
    g.textAlign = "center";
    g.textBaseline = "top";
    g.fillText(top, c.width / 2, m);
    g.textBaseline = "bottom";
    g.fillText(bottom, c.width / 2, c.height - m);
  }
}

/** Distance from `p` to the segment `a`–`b` (2D). */
export function segmentDistance(p: readonly number[], a: readonly number[], b: readonly number[]): number {
  const [dx, dy] = [b[0]! - a[0]!, b[1]! - a[1]!];
  const l2 = dx * dx + dy * dy;
  const t = l2 > 0 ? Math.max(0, Math.min(1, ((p[0]! - a[0]!) * dx + (p[1]! - a[1]!) * dy) / l2)) : 0;
  return Math.hypot(p[0]! - a[0]! - t * dx, p[1]! - a[1]! - t * dy);
}

/** RAS of a label map's central voxel position. */
export function centre(dims: number[], spacing: number[], origin: number[], direction: number[]): Vec3 {
  const half = [0, 1, 2].map((a) => ((dims[a] ?? 1) - 1) / 2 * (spacing[a] ?? 1));
  const at = (row: number) => (origin[row] ?? 0) + [0, 1, 2].reduce((s, a) => s + (direction[3 * row + a] ?? 0) * half[a]!, 0);
  return { x: at(0), y: at(1), z: at(2) };
}

function el<K extends keyof HTMLElementTagNameMap>(tag: K, className: string): HTMLElementTagNameMap[K] {
  const e = document.createElement(tag);
  if (className) e.className = className;
  return e;
}
