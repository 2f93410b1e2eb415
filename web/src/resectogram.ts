// The resectogram (GetResectogram): a resection unrolled to its (u, v) square, u to the right, v
// down. Painted as RGBA pixels by pure functions: margin classes, portal territories shaded
// alternately and outlined, the liver boundary, the cut vessels and the worst point. Then the
// panel's canvas, asked again after every plan change (one request in flight, the newest wins).

import { base64Bytes, problemText } from "./api";
import type { Api, CutVessel, ResectogramResponse } from "./api";
import { CUT_VESSEL_RGB, MARGIN_CLASS_RGBA } from "./colours";
import { Latest } from "./sliceview";

export type Rgba = [number, number, number, number];

/** Pixels along u and v asked for. */
export const SIDE = 200;
/** Margin classes, opaque; outside the liver light grey. */
export const CLASS_RGBA: readonly Rgba[] = MARGIN_CLASS_RGBA.map(([r, g, b]) => [...[r, g, b].map(byte), 255] as Rgba);
export const BOUNDARY_RGBA: Rgba = [0, 0, 0, 255];
export const TERRITORY_EDGE_RGBA: Rgba = [255, 255, 255, 255];
export const WORST_RGBA: Rgba = [255, 0, 255, 255];
export const CUT_VESSEL_RGBA = {
  VESSEL_SYSTEM_PORTAL: [...CUT_VESSEL_RGB.VESSEL_SYSTEM_PORTAL.map(byte), 255] as Rgba,
  VESSEL_SYSTEM_HEPATIC: [...CUT_VESSEL_RGB.VESSEL_SYSTEM_HEPATIC.map(byte), 255] as Rgba,
};
/** Even territories are drawn this much darker. */
export const TERRITORY_SHADE = 0.8;

function byte(x: number): number {
  return Math.round(255 * x);
}

/** A decoded resectogram. */
export interface Resectogram {
  resection: string;
  planVersion: number;
  width: number;
  height: number;
  classes: Uint8Array;
  territories: Uint32Array; // all 0 when the answer has none
  cutVessels: CutVessel[];
  worst: { u: number; v: number } | null;
  minMarginMm: number | null;
}

export function decodeResectogram(m: ResectogramResponse): Resectogram {
  const width = m.width ?? 0, height = m.height ?? 0, n = width * height;
  const classes = base64Bytes(m.classes ?? "");
  if (classes.length !== n) throw new Error(`resectogram of ${classes.length} classes, expected ${width}×${height}`);
  const territories = new Uint32Array(n);
  if (m.territories?.length) {
    if (m.territories.length !== n) throw new Error(`resectogram of ${m.territories.length} territories, expected ${width}×${height}`);
    territories.set(m.territories);
  }
  return {
    resection: m.resection ?? "",
    planVersion: Number(m.planVersion ?? 0),
    width, height, classes, territories,
    cutVessels: m.cutVessels ?? [],
    worst: m.worstU != null && m.worstV != null ? { u: m.worstU, v: m.worstV } : null,
    minMarginMm: m.minMarginMm ?? null,
  };
}

/** Radius of a cut vessel's disc, pixels. */
export function discRadius(width: number, height: number): number {
  return Math.max(1.5, Math.min(width, height) / 50);
}

/** Half the length of the worst point's cross, pixels. */
export function crossArm(width: number, height: number): number {
  return Math.max(2, Math.round(Math.min(width, height) / 40));
}

/** The resectogram's RGBA pixels, row-major (v down). */
export function resectogramRgba(r: Resectogram): Uint8ClampedArray<ArrayBuffer> {
  const { width: w, height: h, classes, territories } = r;
  const out = new Uint8ClampedArray(4 * w * h);
  const set = (k: number, c: Rgba) => out.set(c, 4 * k);
  const inside = (k: number) => classes[k]! > 0;
  for (let k = 0; k < w * h; k++) {
    const c = CLASS_RGBA[classes[k]!] ?? CLASS_RGBA[0]!;
    const t = territories[k]!;
    const f = inside(k) && t > 0 && t % 2 === 0 ? TERRITORY_SHADE : 1;
    set(k, [Math.round(c[0] * f), Math.round(c[1] * f), Math.round(c[2] * f), 255]);
  }
  for (let row = 0; row < h; row++) {
    for (let col = 0; col < w; col++) {
      const k = row * w + col;
      if (!inside(k)) continue;
      const around = [col > 0 ? k - 1 : -1, col + 1 < w ? k + 1 : -1, row > 0 ? k - w : -1, row + 1 < h ? k + w : -1];
      if (around.some((j) => j >= 0 && !inside(j))) set(k, BOUNDARY_RGBA);
      // A territory's edge: one pixel wide, on the side of the pixel left of or above it.
      else if ([around[1]!, around[3]!].some((j) => j >= 0 && territories[j] !== territories[k])) set(k, TERRITORY_EDGE_RGBA);
    }
  }
  const disc = discRadius(w, h);
  for (const v of r.cutVessels) {
    const colour = v.system ? CUT_VESSEL_RGBA[v.system] : undefined;
    if (!colour) continue;
    const cx = (v.u ?? 0) * w, cy = (v.v ?? 0) * h;
    for (let row = Math.max(0, Math.floor(cy - disc)); row < Math.min(h, Math.ceil(cy + disc)); row++) {
      for (let col = Math.max(0, Math.floor(cx - disc)); col < Math.min(w, Math.ceil(cx + disc)); col++) {
        if (Math.hypot(col + 0.5 - cx, row + 0.5 - cy) <= disc) set(row * w + col, colour);
      }
    }
  }
  if (r.worst) {
    const col = pixelOf(r.worst.u, w), row = pixelOf(r.worst.v, h), arm = crossArm(w, h);
    for (let d = -arm; d <= arm; d++) {
      if (col + d >= 0 && col + d < w) set(row * w + col + d, WORST_RGBA);
      if (row + d >= 0 && row + d < h) set((row + d) * w + col, WORST_RGBA);
    }
  }
  return out;
}

/** The pixel column (or row) of coordinate `t` (0..1) on `n` pixels. */
export function pixelOf(t: number, n: number): number {
  return Math.min(n - 1, Math.max(0, Math.floor(t * n)));
}

/** `window.resecta.resectogram()`: what the canvas shows. */
export interface ResectogramState {
  resection: string;
  planVersion: number;
  width: number;
  height: number;
  cutVessels: number;
}

interface Ask { sessionId: string; resection: string }

/** The panel's resectogram of the selected resection. */
export class ResectogramView {
  private readonly canvas = document.createElement("canvas");
  private readonly caption = document.createElement("p");
  private readonly requests: Latest<Ask, Resectogram>;
  private wanted: Ask | null = null;
  private shown: Resectogram | null = null;

  constructor(private readonly root: HTMLElement, api: Api) {
    root.className = "resectogram";
    root.setAttribute("aria-label", "Resectogram");
    const title = document.createElement("h2");
    const axes = document.createElement("span");
    axes.className = "axes";
    axes.textContent = "— u →, v ↓";
    title.append("Resectogram ", axes);
    this.canvas.className = "resectogram-canvas";
    this.canvas.width = this.canvas.height = SIDE;
    this.canvas.setAttribute("role", "img");
    this.caption.className = "muted";
    root.append(title, this.canvas, this.caption, legend());
    root.hidden = true;
    this.requests = new Latest(
      (a) => api.resectogram(a.sessionId, a.resection, SIDE, SIDE).then(decodeResectogram),
      (r, a) => this.draw(r, a),
      (e) => this.say(`Resectogram unavailable: ${problemText(e)}`),
    );
  }

  /** Asks for resection `name`'s resectogram of the current plan (none: hides the panel). */
  refresh(sessionId: string, name: string | null): void {
    this.root.hidden = name === null;
    if (name === null) return void (this.wanted = null);
    this.wanted = { sessionId, resection: name };
    this.requests.ask(this.wanted);
  }

  state(): ResectogramState | null {
    const r = this.shown;
    return r && { resection: r.resection, planVersion: r.planVersion, width: r.width, height: r.height, cutVessels: r.cutVessels.length };
  }

  private draw(r: Resectogram, a: Ask): void {
    if (a.resection !== this.wanted?.resection) return; // another resection was selected meanwhile
    this.shown = r;
    this.canvas.width = r.width;
    this.canvas.height = r.height;
    this.canvas.getContext("2d")!.putImageData(new ImageData(resectogramRgba(r), r.width, r.height), 0, 0);
    const margin = r.minMarginMm == null ? "no part inside the liver" : `closest ${r.minMarginMm.toFixed(1)} mm (magenta cross)`;
    const cuts = r.cutVessels.length ? `, ${r.cutVessels.length} cut vessel${r.cutVessels.length > 1 ? "s" : ""}` : "";
    this.canvas.setAttribute("aria-label", `Resectogram of ${r.resection}: margin classes, u to the right, v down; ${margin}${cuts}`);
    this.say(`${r.resection}, plan version ${r.planVersion}: ${margin}${cuts}`);
  }

  private say(text: string): void {
    this.caption.textContent = text;
  }
}

/** The colour key: margin classes, boundary, territory edges, cut vessels, the worst point. */
function legend(): HTMLElement {
  const list = document.createElement("ul");
  list.className = "legend";
  const items: [Rgba, string][] = [
    [CLASS_RGBA[1]!, "safe"],
    [CLASS_RGBA[2]!, "warning"],
    [CLASS_RGBA[3]!, "violation"],
    [CLASS_RGBA[0]!, "outside the liver"],
    [BOUNDARY_RGBA, "liver boundary"],
    [TERRITORY_EDGE_RGBA, "portal territory edge"],
    [CUT_VESSEL_RGBA.VESSEL_SYSTEM_PORTAL, "cut portal vessel"],
    [CUT_VESSEL_RGBA.VESSEL_SYSTEM_HEPATIC, "cut hepatic vessel"],
    [WORST_RGBA, "closest to the tumour"],
  ];
  for (const [[r, g, b], text] of items) {
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = `rgb(${r}, ${g}, ${b})`;
    const li = document.createElement("li");
    li.append(swatch, text);
    list.append(li);
  }
  return list;
}
