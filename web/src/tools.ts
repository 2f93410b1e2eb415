// The panel's planning tools: the selected resection's margin and band, moves of the surface, a
// control-point group or one point along the patient axes, rotations, its closest point to the
// tumour; a new resection from a tumour and an end point; each structure's visibility and
// opacity; mesh files; the plan saved to and loaded from a file. The DOM is built once and its
// values refreshed (never while being typed in), so the keyboard focus survives live updates;
// every action is a button or a form field.

import type { Edit, Resection, Vec3 } from "./api";
import { freshName, moveEdit, parseNumber, rotateEdit, tumourTarget } from "./edits";
import type { Axis, Selection } from "./edits";
import { h } from "./panel";
import type { Plan } from "./plan";
import { methodOf } from "./traces";
import type { Method } from "./traces";

/** What the tools ask of the page. */
export interface ToolActions {
  /** Sends an edit against the newest plan version known; resolves true once applied (errors
   * are reported by the page). */
  edit(e: Edit): Promise<boolean>;
  /** Shows resection `name`'s closest point to its tumour. */
  showClosest(name: string): void;
  /** Arms the 3D view: its next click on the liver gives the new resection's end point. */
  pickEndPoint(): void;
  /** Starts drawing a new DS or CP resection. */
  startTracing(method: "ds" | "cp", name: string, target: Resection["target"]): void;
  setLook(name: string, look: { opacity?: number; visible?: boolean }): void;
  look(name: string): { opacity: number; visible: boolean } | null;
  exportModel(name: string, format: string): Promise<void>;
  savePlan(): Promise<void>;
  loadPlan(file: File): Promise<void>;
  /** A message for the status line. */
  report(text: string, kind: "ok" | "busy" | "error"): void;
}

const FORMATS = ["VTP", "STL", "PLY", "OBJ", "VTK"];

/** Direction buttons: label, axis, sign, what a screen reader says. */
const MOVES: [string, Axis, number, string][] = [
  ["R", "x", 1, "right"],
  ["L", "x", -1, "left"],
  ["A", "y", 1, "anterior"],
  ["P", "y", -1, "posterior"],
  ["S", "z", 1, "superior"],
  ["I", "z", -1, "inferior"],
];

type Field = HTMLInputElement | HTMLSelectElement;

function input(attrs: Record<string, string>): HTMLInputElement {
  return h("input", attrs) as HTMLInputElement;
}

function labelled(text: string, field: Field, unit = ""): HTMLElement {
  return h("label", { class: "field" }, h("span", {}, text), field, ...(unit ? [h("span", { class: "unit" }, unit)] : []));
}

function select(label: string, options: [string, string][]): HTMLSelectElement {
  const s = h("select", { "aria-label": label }) as HTMLSelectElement;
  setOptions(s, options);
  return s;
}

function setOptions(s: HTMLSelectElement, options: [string, string][]): void {
  const keep = s.value;
  s.replaceChildren(...options.map(([value, text]) => h("option", { value }, text)));
  if (options.some(([v]) => v === keep)) s.value = keep;
}

function button(text: string, title: string, run: () => void): HTMLButtonElement {
  const b = h("button", { type: "button", title }, text) as HTMLButtonElement;
  b.onclick = run;
  return b;
}

/** Sets a field's value unless the person is typing in it. */
function refill(f: HTMLInputElement, value: string): void {
  if (document.activeElement !== f) f.value = value;
}

const fmt = (v: number) => String(Math.round(v * 100) / 100);

export class Tools {
  readonly root = h("div", { class: "tools" });
  private plan: Plan | null = null;
  private selected: string | null = null;
  // The selected resection.
  private readonly resectionTitle = h("h2", {}, "Resection");
  private readonly margin = input({ type: "number", step: "any", min: "0.1", max: "100", required: "", "aria-label": "Margin (mm)" });
  private readonly band = input({ type: "number", step: "any", min: "0", max: "100", required: "", "aria-label": "Band (mm)" });
  private readonly what = select("Which control points move", [
    ["all", "whole surface"],
    ["inner", "inner points"],
    ["outer", "outer ring"],
    ["point", "one point"],
  ]);
  private readonly pointI = input({ type: "number", min: "0", step: "1", value: "1", "aria-label": "row i" });
  private readonly pointJ = input({ type: "number", min: "0", step: "1", value: "1", "aria-label": "column j" });
  private readonly pointPicker = h("span", { class: "point", hidden: "" }, "P(", this.pointI, ",", this.pointJ, ")");
  private readonly step = input({ type: "number", step: "any", min: "0.1", max: "50", value: "5", required: "", "aria-label": "Move by (mm)" });
  private readonly axis = select("Rotation axis", [
    ["x", "R–L axis"],
    ["y", "A–P axis"],
    ["z", "S–I axis"],
  ]);
  private readonly angle = input({ type: "number", step: "any", min: "0.1", max: "180", value: "5", required: "", "aria-label": "Rotate by (degrees)" });
  private readonly resectionTools = h("section", { "aria-label": "selected resection", hidden: "" });
  /** The moves and rotations: Bézier resections only. */
  private readonly bezierTools = h("div", {});
  private readonly resectionKind = h("p", { class: "muted" });
  // A new resection.
  private readonly newName = input({ type: "text", required: "", maxlength: "128", autocomplete: "off" });
  private readonly method = select("Resection kind", [
    ["bezier", "Bézier surface"],
    ["ds", "DS: drawn on slices"],
    ["cp", "CP: deformable plane"],
  ]);
  private readonly tumour = select("Tumour to remove", []);
  private readonly endRow = h("div", { class: "row" });
  private readonly createButton = h("button", { type: "submit" }, "Create") as HTMLButtonElement;
  private readonly end = [0, 1, 2].map((k) => input({ type: "number", step: "any", required: "", "aria-label": `end point ${"RAS"[k]}` }));
  private readonly creator = h("details", { class: "new" });
  // Structures and files.
  private readonly structures = h("tbody");
  private structureNames = "";
  /** Called with a new resection's name once the server made it. */
  onCreated: (name: string) => void = () => {};
  private readonly surface = select("Surface", []);
  private readonly format = select("File format", FORMATS.map((f) => [`MODEL_FORMAT_${f}`, f]));
  private readonly planFile = input({ type: "file", accept: ".json,application/json", hidden: "" });

  constructor(private readonly act: ToolActions) {
    this.buildResection();
    this.buildCreator();
    const exportForm = h("form", { novalidate: "", class: "row" }, this.surface, this.format, h("button", { type: "submit" }, "Download"));
    exportForm.onsubmit = (e) => {
      e.preventDefault();
      if (this.surface.value) void act.exportModel(this.surface.value, this.format.value);
    };
    this.planFile.onchange = () => {
      const f = this.planFile.files?.[0];
      this.planFile.value = "";
      if (f) void act.loadPlan(f);
    };
    this.root.append(
      this.resectionTools,
      this.creator,
      h(
        "details",
        { class: "structures" },
        h("summary", {}, "Structures"),
        h("table", {}, h("thead", {}, h("tr", {}, h("th", {}, "shown"), h("th", {}, "opacity"))), this.structures),
      ),
      h("details", {}, h("summary", {}, "Files"), h("p", { class: "muted" }, "Mesh file of a surface:"), exportForm,
        h("div", { class: "row" },
          button("Save plan", "Download the plan as a resecta-plan/1 file", () => void act.savePlan()),
          button("Load plan…", "Replace the plan with a resecta-plan/1 file", () => this.planFile.click()),
          this.planFile)),
    );
  }

  /** Shows `plan` with `selected` as the resection the tools act on. */
  update(plan: Plan, selected: string | null): void {
    this.plan = plan;
    this.selected = selected;
    const r = selected === null ? undefined : plan.resections.get(selected)?.resection;
    this.resectionTools.hidden = !r;
    if (r) {
      this.resectionTitle.textContent = `Resection ${r.name}`;
      this.bezierTools.hidden = methodOf(r) !== "bezier";
      this.resectionKind.textContent = { bezier: "Bézier surface", ds: "DS: drawn on slices", cp: "CP: deformable cutting plane" }[methodOf(r)];
      refill(this.margin, fmt(r.marginMm ?? 10));
      refill(this.band, fmt(r.bandMm ?? 0));
      this.pointI.max = String((r.gridM ?? 1) - 1);
      this.pointJ.max = String((r.gridN ?? 1) - 1);
    }
    if (!plan.resections.size && this.plan.models.size) this.creator.setAttribute("open", "");
    refill(this.newName, this.newName.value && !plan.resections.has(this.newName.value) ? this.newName.value : freshName(plan.resections.keys()));
    const tumours = [...plan.models.values()].filter((m) => m.kind === "tumor");
    setOptions(this.tumour, tumours.map((m) => [m.name, m.name]));
    setOptions(this.surface, [...plan.models.keys(), ...plan.resections.keys()].map((n) => [n, n]));
    const names = [...plan.models.keys()].join("\n");
    if (names !== this.structureNames) {
      this.structureNames = names;
      this.structures.replaceChildren(...[...plan.models.keys()].map((n) => this.structureRow(n)));
    }
  }

  /** Puts `section` below the selected resection's tools. */
  slot(section: HTMLElement): void {
    this.resectionTools.after(section);
  }

  /** Puts `p` in the new resection's end point fields and opens the form. */
  setEndPoint(p: Vec3): void {
    [p.x, p.y, p.z].forEach((v, k) => (this.end[k]!.value = fmt(v)));
    this.creator.setAttribute("open", "");
  }

  private buildResection(): void {
    const settings = h("form", { novalidate: "", class: "row" }, labelled("Margin", this.margin, "mm"), labelled("Band", this.band, "mm"),
      h("button", { type: "submit", title: "Set the safety margin and the warning band" }, "Set"));
    settings.onsubmit = (e) => {
      e.preventDefault();
      void this.setMarginBand();
    };
    this.what.onchange = () => (this.pointPicker.hidden = this.what.value !== "point");
    const moves = MOVES.map(([label, axis, sign, towards]) =>
      button(label, `Move towards the patient's ${towards} (${axis === "x" ? "R–L" : axis === "y" ? "A–P" : "S–I"})`, () =>
        void this.move(axis, sign)));
    const turn = (sign: number, text: string) => button(text, `Rotate ${sign > 0 ? "counter-clockwise" : "clockwise"} about the axis through the control points' centroid`, () => void this.rotate(sign));
    this.bezierTools.append(
      h("div", { class: "row" }, h("span", {}, "Move"), this.what, this.pointPicker),
      h("div", { class: "row moves", role: "group", "aria-label": "move" }, ...moves, labelled("by", this.step, "mm")),
      h("div", { class: "row", role: "group", "aria-label": "rotate" }, h("span", {}, "Rotate"), this.axis, turn(1, "⟲"), turn(-1, "⟳"),
        labelled("by", this.angle, "°")),
    );
    this.resectionTools.append(
      this.resectionTitle,
      this.resectionKind,
      settings,
      this.bezierTools,
      h("div", { class: "row" },
        button("Show closest point", "Turn the view to where the surface comes closest to the tumour", () => {
          if (this.selected) this.act.showClosest(this.selected);
        }),
        button("Delete", "Delete this resection (Undo brings it back)", () => {
          if (this.selected) void this.act.edit({ deleteResection: { name: this.selected } });
        })),
    );
  }

  private buildCreator(): void {
    const pick = button("Pick on a view", "Click the liver in the 3D view or the slice view where the resection should end", () => this.act.pickEndPoint());
    this.endRow.append(h("span", {}, "End point"), ...this.end, h("span", { class: "unit" }, "mm"), pick);
    this.method.onchange = () => {
      const m = this.method.value as Method;
      this.endRow.hidden = m !== "bezier";
      this.createButton.textContent = m === "ds" ? "Draw on slices" : m === "cp" ? "Draw on the liver" : "Create";
    };
    const form = h("form", { novalidate: "" }, labelled("Name", this.newName), labelled("Kind", this.method), labelled("Tumour", this.tumour),
      this.endRow, h("div", { class: "row" }, this.createButton));
    form.onsubmit = (e) => {
      e.preventDefault();
      void this.create();
    };
    this.creator.append(h("summary", {}, "New resection"), form);
  }

  private structureRow(name: string): HTMLElement {
    const look = this.act.look(name) ?? { opacity: 1, visible: true };
    const shown = input({ type: "checkbox" });
    shown.checked = look.visible;
    shown.onchange = () => this.act.setLook(name, { visible: shown.checked });
    const opacity = input({ type: "range", min: "0", max: "100", step: "5", value: String(Math.round(look.opacity * 100)), "aria-label": `opacity of ${name}` });
    opacity.oninput = () => this.act.setLook(name, { opacity: Number(opacity.value) / 100 });
    return h("tr", {}, h("td", {}, h("label", {}, shown, ` ${name}`)), h("td", {}, opacity));
  }

  /** Sends the edits `build` makes, in order; a message it throws goes to the status line.
   * True when every edit was applied. */
  private async attempt(build: () => Edit | Edit[]): Promise<boolean> {
    let edits: Edit[];
    try {
      const e = build();
      edits = Array.isArray(e) ? e : [e];
    } catch (err) {
      this.act.report(err instanceof Error ? err.message : String(err), "error");
      return false;
    }
    for (const e of edits) if (!(await this.act.edit(e))) return false;
    return true;
  }

  private current() {
    const r = this.selected === null ? undefined : this.plan?.resections.get(this.selected)?.resection;
    if (!r) throw new Error("Select a resection first");
    return r;
  }

  private setMarginBand(): Promise<boolean> {
    return this.attempt(() => {
      const r = this.current();
      const margin = parseNumber("Margin", this.margin.value, 0.1, 100);
      const band = parseNumber("Band", this.band.value, 0, 100);
      const out: Edit[] = [];
      if (margin !== r.marginMm) out.push({ setMargin: { name: r.name, marginMm: margin } });
      if (band !== (r.bandMm ?? 0)) out.push({ setBand: { name: r.name, bandMm: band } });
      return out;
    });
  }

  private move(axis: Axis, sign: number): Promise<boolean> {
    return this.attempt(() => {
      const r = this.current();
      const mm = parseNumber("Move by", this.step.value, 0.1, 50);
      const kind = this.what.value as Selection["kind"];
      const selection: Selection =
        kind === "point" ? { kind, i: Number(this.pointI.value), j: Number(this.pointJ.value) } : { kind };
      return moveEdit(r, selection, axis, sign * mm);
    });
  }

  private rotate(sign: number): Promise<boolean> {
    return this.attempt(() => rotateEdit(this.current(), this.axis.value as Axis, sign * parseNumber("Rotate by", this.angle.value, 0.1, 180)));
  }

  private async create(): Promise<void> {
    const name = this.newName.value.trim();
    const method = this.method.value as Method;
    if (method !== "bezier") {
      await this.attempt(() => {
        if (!name) throw new Error("Name the new resection");
        if (this.plan?.resections.has(name)) throw new Error(`A resection named ${name} exists already`);
        const model = this.plan?.models.get(this.tumour.value);
        this.act.startTracing(method, name, model?.label === undefined ? undefined : tumourTarget(model.label, model.mesh));
        this.creator.removeAttribute("open");
        return [];
      });
      return;
    }
    const made = await this.attempt(() => {
      if (!name) throw new Error("Name the new resection");
      if (this.plan?.resections.has(name)) throw new Error(`A resection named ${name} exists already`);
      const model = this.plan?.models.get(this.tumour.value);
      if (!model || model.label === undefined) throw new Error("Choose the tumour to remove");
      const [x, y, z] = this.end.map((f, k) => parseNumber(`End point ${"RAS"[k]}`, f.value, -1e5, 1e5)) as [number, number, number];
      return { initFromEndPoint: { name, target: tumourTarget(model.label, model.mesh), endPoint: { x, y, z } } };
    });
    if (made) {
      this.creator.removeAttribute("open");
      this.onCreated(name);
    }
  }
}
