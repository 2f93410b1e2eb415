// A session's label map and models from the browser: a label-map file dropped or chosen, its
// role map, the upload with its progress and the server's summary; the reconstruction with its
// progress, its models as they come and Cancel. The parsing and checks are pure functions
// (tested in Node); the DOM part sets text as text. The watch stream brings the new snapshot
// after an upload and after a reconstruction (the server re-snapshots its watchers), so the
// live view needs nothing from here.

import { problemText } from "./api";
import type { Api, LabelMapSummary, ModelInfo, ReconstructDone, ReconstructEvent, ReconstructRequest, RoleMap, ServerLimits, Session } from "./api";
import { h } from "./panel";

export const ROLES = ["parenchyma", "tumor", "portal", "hepatic", "vessel"] as const;
export type Role = (typeof ROLES)[number];
export const ROLE_NAMES: Record<Role, string> = {
  parenchyma: "Parenchyma",
  tumor: "Tumour",
  portal: "Portal vein",
  hepatic: "Hepatic veins",
  vessel: "Vessels (not split)",
};
/** The roles the server assumes when an upload names none (resecta-geom's `RoleMap::default`).
 * A `.seg.nrrd`'s labels are its segments' label values; the server does not read their names. */
export const DEFAULT_ROLES: RoleMap = { parenchyma: [1], tumor: [2], portal: [3], hepatic: [4] };

export type Checked<T> = { ok: true; value: T } | { ok: false; errors: string[] };

/** The format of a label-map file told from its name; AUTO (the server reads the bytes) else. */
export function formatOf(fileName: string): string {
  const n = fileName.toLowerCase();
  if (n.endsWith(".seg.nrrd")) return "LABEL_MAP_FORMAT_SEG_NRRD";
  if (n.endsWith(".nii") || n.endsWith(".nii.gz")) return "LABEL_MAP_FORMAT_NIFTI";
  if (n.endsWith(".nrrd")) return "LABEL_MAP_FORMAT_NRRD";
  if (n.endsWith(".mha")) return "LABEL_MAP_FORMAT_METAIMAGE";
  return "LABEL_MAP_FORMAT_AUTO";
}

const FORMAT_NAMES: Record<string, string> = {
  LABEL_MAP_FORMAT_SEG_NRRD: "Slicer segmentation",
  LABEL_MAP_FORMAT_NIFTI: "NIfTI",
  LABEL_MAP_FORMAT_NRRD: "NRRD",
  LABEL_MAP_FORMAT_METAIMAGE: "MetaImage",
  LABEL_MAP_FORMAT_AUTO: "format told by the server",
};

/** The role map of the form's fields (label values separated by commas or spaces): whole
 * numbers 1..65535, no label twice, parenchyma and tumour given (the server needs both). */
export function parseRoles(fields: Partial<Record<Role, string>>): Checked<RoleMap> {
  const roles: RoleMap = {};
  const errors: string[] = [];
  const owner = new Map<number, Role>();
  for (const role of ROLES) {
    const name = ROLE_NAMES[role];
    const words = (fields[role] ?? "").split(/[\s,]+/).filter(Boolean);
    if (!words.length && (role === "parenchyma" || role === "tumor")) errors.push(`${name}: give at least one label value`);
    const labels: number[] = [];
    for (const w of words) {
      const v = /^\d{1,5}$/.test(w) ? Number(w) : NaN;
      const first = owner.get(v);
      if (!(v >= 1 && v <= 65535)) errors.push(`${name}: "${w.slice(0, 12)}" is not a label value (a whole number from 1 to 65535)`);
      else if (first === role) errors.push(`${name}: label ${v} is given twice`);
      else if (first) errors.push(`Label ${v} is in two roles: ${ROLE_NAMES[first]} and ${name}`);
      else {
        owner.set(v, role);
        labels.push(v);
      }
    }
    if (labels.length) roles[role] = labels;
  }
  return errors.length ? { ok: false, errors } : { ok: true, value: roles };
}

/** The form's text of a role map. */
export function rolesText(roles: RoleMap): Record<Role, string> {
  return Object.fromEntries(ROLES.map((r) => [r, (roles[r] ?? []).join(", ")])) as Record<Role, string>;
}

export interface ReconstructFields {
  method: "RECONSTRUCTION_METHOD_PSR" | "RECONSTRUCTION_METHOD_MCSD";
  psrDepth: string;
  smoothing: string;
  decimation: string;
  splitComponents: boolean;
  minComponentMm3: string;
}

/** The request of the reconstruction form within the server's limits (proto ranges); a blank
 * field is left out (the engine's default). The PSR depth counts only for PSR. */
export function reconstructRequest(f: ReconstructFields, limits: ServerLimits): Checked<ReconstructRequest> {
  const errors: string[] = [];
  const options: NonNullable<ReconstructRequest["options"]> = {};
  const num = (text: string, name: string, ok: (v: number) => boolean, range: string): number | undefined => {
    if (!text.trim()) return undefined;
    const v = Number(text);
    if (Number.isFinite(v) && ok(v)) return v;
    errors.push(`${name} must be ${range}`);
    return undefined;
  };
  if (f.method === "RECONSTRUCTION_METHOD_PSR") {
    const [lo, hi] = [limits.minPsrDepth ?? 1, limits.maxPsrDepth ?? 10];
    const d = num(f.psrDepth, "PSR depth", (v) => Number.isInteger(v) && v >= lo && v <= hi, `a whole number from ${lo} to ${hi}`);
    if (d !== undefined) options.psrDepth = d;
  }
  const smoothing = num(f.smoothing, "Smoothing", (v) => v >= 0 && v <= 1, "from 0 to 1");
  const decimation = num(f.decimation, "Decimation", (v) => v >= 0 && v < 1, "from 0 up to (not including) 1");
  const speck = num(f.minComponentMm3, "Smallest vessel piece", (v) => v >= 0, "0 mm³ or more");
  if (smoothing !== undefined) options.smoothing = smoothing;
  if (decimation !== undefined) options.decimation = decimation;
  if (speck !== undefined) options.minComponentMm3 = speck;
  if (f.splitComponents) options.splitComponents = true;
  return errors.length ? { ok: false, errors } : { ok: true, value: { method: f.method, options } };
}

/** What a reconstruction showed so far. */
export interface ReconstructView {
  fraction: number;
  stage: string;
  models: ModelInfo[];
  done: ReconstructDone | null;
}

export const STARTED: ReconstructView = { fraction: 0, stage: "starting", models: [], done: null };

/** The view after one event of the stream (progress never goes back). */
export function reconstructStep(v: ReconstructView, e: ReconstructEvent): ReconstructView {
  if (e.progress) return { ...v, fraction: Math.max(v.fraction, e.progress.fraction ?? 0), stage: e.progress.stage ?? v.stage };
  if (e.model) return { ...v, models: [...v.models, e.model] };
  if (e.done) return { ...v, fraction: 1, stage: "done", done: e.done };
  return v;
}

const count = (n: number | string | undefined) => Number(n ?? 0).toLocaleString("en-GB");
/** Millilitres: one decimal, two below 1 ml (small vessels and specks). */
const ml = (x = 0) => `${x.toFixed(Math.abs(x) < 1 ? 2 : 1)} ml`;

export function modelText(m: ModelInfo): string {
  const method = m.method === "RECONSTRUCTION_METHOD_PSR" ? "PSR" : "MCSD";
  return `${m.name}: ${ml(m.volumeMl)}, ${count(m.triangleCount)} triangles (${method})`;
}

export function doneText(d: ReconstructDone): string {
  const specks = (d.dropped ?? []).map((x) => `${count(x.count)} ${(x.kind ?? "").replace(/^SURFACE_KIND_/, "").toLowerCase()} (${ml(x.volumeMl)})`);
  return `Built ${count(d.modelCount)} models in ${(d.elapsedS ?? 0).toFixed(1)} s${specks.length ? `; left out as too small: ${specks.join(", ")}` : ""}`;
}

/** The summary's labels as table rows (label, role, voxels, volume) and what looks wrong: a
 * role's label absent from the file, a label of the file in no role. */
export function labelRows(s: LabelMapSummary): { rows: string[][]; warnings: string[] } {
  const roleOf = new Map<number, Role>();
  for (const r of ROLES) for (const l of s.roles?.[r] ?? []) roleOf.set(l, r);
  const present = new Set((s.labels ?? []).map((l) => l.label));
  const warnings: string[] = [];
  const rows = (s.labels ?? []).map((l) => {
    const role = roleOf.get(l.label);
    if (!role) warnings.push(`Label ${l.label} is in no role: it is ignored`);
    return [String(l.label), role ? ROLE_NAMES[role] : "none", count(l.voxels), ml(l.volumeMl)];
  });
  for (const [l, r] of roleOf) if (!present.has(l)) warnings.push(`${ROLE_NAMES[r]} label ${l} is not in the file`);
  return { rows, warnings };
}

const bytes = (n: number) => (n >= 1 << 20 ? `${(n / (1 << 20)).toFixed(1)} MiB` : `${(n / 1024).toFixed(1)} KiB`);
const triple = (v: number[] | undefined, digits: number) => (v ?? []).map((x) => x.toFixed(digits)).join(" × ");

/** A form field with its label. */
function field(label: string, input: HTMLElement, hint?: string): HTMLElement {
  const id = `intake-${label.toLowerCase().replace(/[^a-z0-9]+/g, "-")}`;
  input.id = id;
  return h("div", { class: "field" }, h("label", { for: id }, label), input, ...(hint ? [h("small", { class: "muted" }, hint)] : []));
}

const input = (attrs: Record<string, string>) => h("input", attrs) as HTMLInputElement;

/** A message line: `kind` colours it; errors are one line each. */
function say(el: HTMLElement, lines: string | string[], kind: "ok" | "busy" | "error" = "ok"): void {
  el.className = `say ${kind}`;
  el.replaceChildren(...[lines].flat().map((l) => h("div", {}, l)));
}

/** The label-map and model section of the panel; `show(session)` after each snapshot. */
export class Intake {
  private session: Session | null = null;
  private busy = false;
  private prefilled = false;
  private file: File | null = null;
  private limits: ServerLimits = {};
  private abort: AbortController | null = null;
  private readonly details = h("details", { class: "intake-more" }) as HTMLDetailsElement;
  // Upload: file, roles, progress.
  private readonly fileInput = input({ type: "file", accept: ".nii,.nii.gz,.nrrd,.seg.nrrd,.mha", hidden: "" });
  private readonly fileText = h("p", { class: "muted" }, "No file chosen");
  private readonly roleInputs = Object.fromEntries(
    ROLES.map((r) => [r, input({ type: "text", inputmode: "numeric", autocomplete: "off" })]),
  ) as Record<Role, HTMLInputElement>;
  private readonly uploadSet = h("fieldset", {}) as HTMLFieldSetElement;
  private readonly uploadBar = h("progress", { max: "1", value: "0", "aria-label": "Upload progress", hidden: "" }) as HTMLProgressElement;
  private readonly uploadSay = h("div", { class: "say", role: "status" });
  private readonly upload = h("form", { class: "upload", "aria-label": "Upload a label map" }) as HTMLFormElement;
  private readonly summary = h("div", { class: "summary" });
  // Reconstruction: method, options, progress, models.
  private readonly method = h(
    "select",
    {},
    h("option", { value: "RECONSTRUCTION_METHOD_PSR" }, "PSR: Poisson liver, MCSD for the rest"),
    h("option", { value: "RECONSTRUCTION_METHOD_MCSD" }, "MCSD: marching cubes, smoothing, decimation"),
  ) as HTMLSelectElement;
  private readonly psrDepth = input({ type: "number", step: "1", placeholder: "7" });
  private readonly smoothing = input({ type: "number", step: "0.05", min: "0", max: "1", placeholder: "0.5" });
  private readonly decimation = input({ type: "number", step: "0.05", min: "0", max: "0.99", placeholder: "0" });
  private readonly speck = input({ type: "number", step: "1", min: "0", placeholder: "10" });
  private readonly split = input({ type: "checkbox" });
  private readonly reconSet = h("fieldset", {}) as HTMLFieldSetElement;
  private readonly cancel = h("button", { type: "button", disabled: "" }, "Cancel") as HTMLButtonElement;
  private readonly reconBar = h("progress", { max: "1", value: "0", "aria-label": "Reconstruction progress", hidden: "" }) as HTMLProgressElement;
  private readonly reconSay = h("div", { class: "say", role: "status" });
  private readonly modelList = h("ul", { class: "models", "aria-label": "Models built" });
  private readonly recon = h("form", { class: "recon", "aria-label": "Build the models" }) as HTMLFormElement;

  constructor(
    readonly root: HTMLElement,
    private readonly api: Api,
  ) {
    root.classList.add("intake");
    this.buildUpload();
    this.buildRecon();
    // Without the limits the page checks less before sending; the server checks everything.
    api.info().then(
      (i) => {
        this.limits = i.limits ?? {};
        this.psrDepth.min = String(this.limits.minPsrDepth ?? 1);
        this.psrDepth.max = String(this.limits.maxPsrDepth ?? 10);
      },
      () => {},
    );
  }

  /** Shows what fits the session's state: an empty one the upload, one with a label map its
   * summary and the reconstruction, one with models both folded away. Waits while busy. */
  show(session: Session | null): void {
    this.session = session;
    if (!this.prefilled && session) {
      this.setRoles(session.labelMap?.roles ?? DEFAULT_ROLES);
      this.prefilled = true;
    }
    if (!this.busy) this.layout();
  }

  private layout(): void {
    const s = this.session;
    if (s?.labelMap) this.showSummary(s.labelMap);
    const more = (title: string, ...parts: HTMLElement[]) => (this.details.replaceChildren(h("summary", {}, title), ...parts), this.details);
    if (s?.state === "SESSION_STATE_EMPTY") this.root.replaceChildren(h("h2", {}, "Label map"), this.upload);
    else if (s?.state === "SESSION_STATE_LABEL_MAP")
      this.root.replaceChildren(h("h2", {}, "Label map"), this.summary, h("h2", {}, "Models"), this.recon, more("Replace the label map", this.upload));
    else if (s?.state === "SESSION_STATE_READY") this.root.replaceChildren(more("Label map and models", this.summary, this.upload, this.recon));
    else this.root.replaceChildren();
  }

  private setRoles(roles: RoleMap): void {
    const text = rolesText(roles);
    for (const r of ROLES) this.roleInputs[r].value = text[r];
  }

  private choose(files: FileList | null | undefined): void {
    if (!files?.length) return;
    if (files.length > 1) return say(this.uploadSay, "Drop one label-map file", "error");
    const f = (this.file = files[0]!);
    this.fileText.textContent = `${f.name} (${bytes(f.size)}, ${FORMAT_NAMES[formatOf(f.name)]})`;
    this.fileText.className = "";
    say(this.uploadSay, "");
  }

  private buildUpload(): void {
    const choose = h("button", { type: "button" }, "Choose file…");
    choose.onclick = () => this.fileInput.click();
    this.fileInput.onchange = () => this.choose(this.fileInput.files);
    const what = "Drop a label map here: NIfTI (.nii, .nii.gz), NRRD (.nrrd), Slicer .seg.nrrd or MetaImage (.mha)";
    const drop = h("div", { class: "drop" }, h("p", {}, what), choose, this.fileInput, this.fileText);
    drop.ondragover = (e) => {
      e.preventDefault();
      drop.classList.add("over");
    };
    drop.ondragleave = () => drop.classList.remove("over");
    drop.ondrop = (e) => {
      e.preventDefault();
      drop.classList.remove("over");
      if (!this.busy) this.choose(e.dataTransfer?.files);
    };
    const roles = h(
      "fieldset",
      { class: "roles" },
      h("legend", {}, "Label values per role"),
      h("small", { class: "muted" }, "Separated by commas; a .seg.nrrd's labels are its segments' label values."),
      ...ROLES.map((r) => field(ROLE_NAMES[r], this.roleInputs[r])),
    );
    this.uploadSet.append(drop, roles, h("button", { type: "submit" }, "Upload"));
    this.upload.append(this.uploadSet, this.uploadBar, this.uploadSay);
    this.upload.onsubmit = (e) => {
      e.preventDefault();
      void this.send();
    };
  }

  private async send(): Promise<void> {
    const file = this.file;
    const id = this.session?.id;
    if (!file || !id) return say(this.uploadSay, "Choose a label-map file first (drop it above or Choose file…)", "error");
    const roles = parseRoles(Object.fromEntries(ROLES.map((r) => [r, this.roleInputs[r].value])));
    if (!roles.ok) return say(this.uploadSay, roles.errors, "error");
    const max = Number(this.limits.maxUploadBytes ?? 0);
    if (max && file.size > max) return say(this.uploadSay, `The file has ${bytes(file.size)}; this server takes at most ${bytes(max)}`, "error");
    this.setBusy(true);
    this.uploadBar.hidden = false;
    this.uploadBar.value = 0;
    say(this.uploadSay, `Uploading ${bytes(file.size)}…`, "busy");
    try {
      const { labelMap } = await this.api.uploadLabelMap(id, file, { format: formatOf(file.name), roles: roles.value }, (sent, total) => {
        this.uploadBar.value = total ? sent / total : 0;
        say(this.uploadSay, sent < total ? `Uploading: ${bytes(sent)} of ${bytes(total)}` : "Reading the label map on the server…", "busy");
      });
      if (labelMap) this.showSummary(labelMap);
      say(this.uploadSay, "Uploaded: check the labels and their roles");
    } catch (e) {
      say(this.uploadSay, `Upload refused: ${problemText(e)}`, "error");
    } finally {
      this.uploadBar.hidden = true;
      this.setBusy(false);
    }
  }

  private showSummary(s: LabelMapSummary): void {
    const { rows, warnings } = labelRows(s);
    const table = h(
      "table",
      {},
      h("thead", {}, h("tr", {}, ...["label", "role", "voxels", "volume"].map((c) => h("th", {}, c)))),
      h("tbody", {}, ...rows.map((r) => h("tr", {}, ...r.map((c) => h("td", {}, c))))),
    );
    this.summary.replaceChildren(
      h("p", {}, `${triple(s.dims, 0)} voxels of ${triple(s.spacing, 2)} mm`),
      table,
      h("p", {}, `Functional liver: ${ml(s.liverVolumeMl)}`),
      ...warnings.map((w) => h("p", { class: "warn" }, w)),
    );
  }

  private buildRecon(): void {
    this.method.onchange = () => (this.psrDepth.disabled = this.method.value !== "RECONSTRUCTION_METHOD_PSR");
    this.cancel.onclick = () => this.abort?.abort();
    this.reconSet.append(
      field("Method", this.method),
      field("PSR depth", this.psrDepth, "finest grid 2^depth cells across the liver"),
      field("Smoothing", this.smoothing, "MCSD, 0 to 1"),
      field("Decimation", this.decimation, "MCSD, fraction of triangles removed"),
      field("Smallest vessel piece (mm³)", this.speck),
      h("label", { class: "check" }, this.split, " One model per vessel piece"),
      h("button", { type: "submit" }, "Reconstruct"),
    );
    this.recon.append(this.reconSet, this.cancel, this.reconBar, this.reconSay, this.modelList);
    this.recon.onsubmit = (e) => {
      e.preventDefault();
      void this.reconstruct();
    };
  }

  private async reconstruct(): Promise<void> {
    const id = this.session?.id;
    if (!id) return;
    const req = reconstructRequest(
      {
        method: this.method.value as ReconstructFields["method"],
        psrDepth: this.psrDepth.value,
        smoothing: this.smoothing.value,
        decimation: this.decimation.value,
        splitComponents: this.split.checked,
        minComponentMm3: this.speck.value,
      },
      this.limits,
    );
    if (!req.ok) return say(this.reconSay, req.errors, "error");
    const abort = (this.abort = new AbortController());
    this.setBusy(true);
    this.modelList.replaceChildren();
    let view = STARTED;
    const render = () => {
      this.reconBar.value = view.fraction;
      say(this.reconSay, `Reconstructing: ${view.stage} (${Math.round(view.fraction * 100)} %)`, "busy");
      this.modelList.replaceChildren(...view.models.map((m) => h("li", {}, modelText(m))));
    };
    this.reconBar.hidden = false;
    render();
    try {
      for await (const e of this.api.reconstruct(id, req.value, abort.signal)) {
        view = reconstructStep(view, e);
        render();
      }
      say(this.reconSay, doneText(view.done ?? {}));
      this.details.open = true; // the result stays in sight when the models fold it away
    } catch (e) {
      if (abort.signal.aborted) say(this.reconSay, "Reconstruction cancelled: the session is as it was", "error");
      else say(this.reconSay, `Reconstruction failed: ${problemText(e)}`, "error");
    } finally {
      this.abort = null;
      this.reconBar.hidden = true;
      this.setBusy(false);
    }
  }

  private setBusy(busy: boolean): void {
    this.busy = busy;
    this.uploadSet.disabled = this.reconSet.disabled = busy;
    this.cancel.disabled = !this.abort;
    if (!busy) this.layout();
  }
}
