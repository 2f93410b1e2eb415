// The side panel (session, plan version, verdicts, volumes, status) and the small forms: the
// session picker and the bearer-token prompt. Plain DOM; text is always set as text.

import { problemText } from "./api";
import type { RiskReport, Session, VolumeReport } from "./api";
import type { Plan } from "./plan";
import { methodOf } from "./traces";

type Child = Node | string;

export function h(tag: string, attrs: Record<string, string> = {}, ...children: Child[]): HTMLElement {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  el.append(...children);
  return el;
}

const mm = (x: number | undefined | null) => (x == null ? "–" : `${x.toFixed(1)} mm`);
const ml = (x: number | undefined) => (x == null ? "–" : `${x.toFixed(0)} ml`);
const pct = (x: number | undefined) => (x == null ? "–" : `${x.toFixed(1)} %`);
const signedMm = (x: number | undefined) => (x == null ? "–" : `${x >= 0 ? "+" : ""}${x.toFixed(1)} mm`);
const perMm = (x: number | undefined) => (x == null ? "–" : `${x.toFixed(4)} mm⁻¹`);
const signedPct = (x: number | undefined) => (x == null ? "–" : `${x >= 0 ? "+" : ""}${x.toFixed(1)} %`);
const KIND_LABEL = { bezier: "Bézier", ds: "DS", cp: "CP" } as const;

function table(head: string[], rows: Child[][]): HTMLElement {
  return h(
    "table",
    {},
    h("thead", {}, h("tr", {}, ...head.map((c) => h("th", {}, c)))),
    h("tbody", {}, ...rows.map((r) => h("tr", {}, ...r.map((c) => h("td", {}, c))))),
  );
}

export class Panel {
  private readonly body = h("div", { class: "panel-body" });
  private readonly status = h("div", { class: "status", role: "status" });
  private readonly actions = h("div", { class: "actions", role: "toolbar", "aria-label": "plan" });
  /** The resection whose control grid is shown and edited. */
  selected: string | null = null;
  onSelect: (name: string) => void = () => {};

  constructor(readonly root: HTMLElement) {
    const all = h("a", { href: "?sessions", class: "all-sessions", title: "The server's sessions, and a form for a new one" }, "All sessions");
    root.replaceChildren(h("header", {}, h("h1", {}, "resecta"), all), this.status, this.actions, this.body);
  }

  /** Shows the undo and redo buttons (with their keyboard shortcuts in the tooltip). */
  setActions(undo: () => void, redo: () => void): void {
    const button = (label: string, keys: string[], run: () => void) => {
      const b = h("button", { type: "button", title: `${label} (${keys.join(", ")})`, "aria-keyshortcuts": keys.join(" ") }, label);
      b.onclick = run;
      return b;
    };
    this.actions.replaceChildren(button("Undo", ["Control+Z"], undo), button("Redo", ["Control+Y", "Control+Shift+Z"], redo));
  }

  setStatus(text: string, kind: "ok" | "busy" | "error" = "ok"): void {
    this.status.textContent = text;
    this.status.className = `status ${kind}`;
  }

  /** The plan's summary: session, version, a verdict per resection, the volumes. */
  show(plan: Plan): void {
    const rows = [...plan.resections].map(([name, r]) => {
      const v = r.verdict;
      const verdict = h("span", { class: v.violation ? "bad" : "good" }, v.violation ? "violation" : "ok");
      const pick = h("button", { type: "button", class: "link", "aria-pressed": String(name === this.selected), title: "Edit its control points" }, name);
      pick.onclick = () => this.onSelect(name);
      return [pick, KIND_LABEL[methodOf(r.resection)], mm(v.minMarginMm), mm(r.resection.marginMm), verdict];
    });
    this.body.replaceChildren(
      h("p", { class: "session" }, plan.session?.displayName ?? plan.sessionId),
      h("p", {}, `Plan version ${plan.planVersion}`),
      h("h2", {}, "Resections"),
      rows.length ? table(["name", "kind", "min margin", "margin", "verdict"], rows) : h("p", { class: "muted" }, "none"),
      h("h2", {}, "Volumes"),
      plan.volumes ? volumesTable(plan.volumes, plan.volumesVersion !== plan.planVersion) : h("p", { class: "muted" }, "not computed yet"),
    );
  }

  /** Lets the person pick one of `sessions`, or name a new one that `create` makes (resolving
   * with its id); resolves with the id of the session to open. */
  pickSession(sessions: Session[], create: (displayName: string) => Promise<string>): Promise<string> {
    return new Promise((resolve) => {
      const items = sessions.map((s) => {
        const b = h("button", { type: "button" }, s.displayName || s.id);
        b.title = `${s.state ?? ""} · plan version ${s.planVersion ?? "0"}`;
        b.onclick = () => resolve(s.id);
        return h("li", {}, b);
      });
      const name = h("input", { id: "new-session-name", required: "", autocomplete: "off" }) as HTMLInputElement;
      const submit = h("button", { type: "submit" }, "Create and open") as HTMLButtonElement;
      const said = h("p", { class: "bad", role: "alert" });
      const form = h(
        "form",
        { class: "new-session", "aria-label": "New session" },
        h("label", { for: "new-session-name" }, "Display name"),
        name,
        h("small", { class: "muted" }, "No patient identifiers if the server is shared."),
        submit,
        said,
      ) as HTMLFormElement;
      form.onsubmit = (e) => {
        e.preventDefault();
        submit.disabled = true;
        said.textContent = "";
        create(name.value.trim()).then(resolve, (err: unknown) => {
          said.textContent = `Not created: ${problemText(err)}`;
          submit.disabled = false;
        });
      };
      this.body.replaceChildren(
        h("h2", {}, "Sessions"),
        items.length ? h("ul", { class: "sessions" }, ...items) : h("p", { class: "muted" }, "The server holds no session."),
        h("h2", {}, "New session"),
        form,
      );
      if (!items.length) name.focus();
    });
  }
}

function volumesTable(v: VolumeReport, stale: boolean): HTMLElement {
  const rows: Child[][] = [
    ["functional liver", ml(v.totalMl), ""],
    ["remnant (FLR)", ml(v.remnantMl), pct(v.remnantPct)],
    ["resected", ml(v.resectedMl), ""],
    ...(v.resections ?? []).map((r) => [
      `  ${r.name}`,
      r.completeCut ? ml(r.resectedMl) : "incomplete cut",
      r.completeCut ? pct(r.resectedPct) : "",
    ]),
  ];
  const out = h("div", {}, table(["", "volume", "share"], rows));
  if (v.risk) out.append(...riskTables(v.risk));
  else if (v.riskUnavailable) out.append(h("p", { class: "muted risk-unavailable" }, `No risk analysis: ${v.riskUnavailable}`));
  if (v.flrWarning) {
    const what = v.risk ? `Functional remnant ${pct(v.risk.functionalRemnantPct ?? 0)}` : `Future liver remnant ${pct(v.remnantPct)}`;
    out.append(h("p", { class: "bad flr", role: "alert" }, `⚠ ${what} is below ${pct(v.flrThresholdPct)}`));
  }
  for (const r of v.resections ?? []) {
    if (!r.completeCut && r.incompleteReason) out.append(h("p", { class: "bad incomplete" }, `${r.name}: ${r.incompleteReason}`));
  }
  if (v.complete === false) out.append(h("p", { class: "muted" }, "Some cut is incomplete."));
  const metrics = (v.resections ?? []).map((r) => [r.name, signedMm(r.metrics?.marginDeviationMm), perMm(r.metrics?.medianAbsMeanCurvaturePerMm), signedPct(r.metrics?.volumeDeviationPct)]);
  if (metrics.length) {
    const t = table(["metrics", "margin dev.", "median |H|", "volume dev."], metrics);
    t.className = "metrics";
    t.title = "Thesis Sec. 7.4: minimum tumour distance minus the margin; median |mean curvature| inside the liver; volume against a reference plan";
    out.append(t);
  }
  if (stale) out.append(h("p", { class: "muted" }, "Recomputing…"));
  return out;
}

const SYSTEM_LABEL: Record<string, string> = { VESSEL_SYSTEM_PORTAL: "portal", VESSEL_SYSTEM_HEPATIC: "hepatic" };
/** Cut vessels listed (the largest first); the rest are counted. */
const CUT_VESSELS_LISTED = 6;

/** The remnant the cuts leave supplied and drained, what they put at risk, the vessels cut. */
function riskTables(r: RiskReport): HTMLElement[] {
  const risk = table(["risk", "volume", "share"], [
    ["functional remnant", ml(r.functionalRemnantMl ?? 0), pct(r.functionalRemnantPct ?? 0)],
    ["devascularised", r.hasPortal ? ml(r.devascularisedMl ?? 0) : "no portal tree", ""],
    ["congested", r.hasHepatic ? ml(r.congestedMl ?? 0) : "no hepatic tree", ""],
    ["at risk", ml(r.atRiskMl ?? 0), ""],
  ]);
  risk.className = "risk";
  risk.title = "Remnant whose nearest portal (hepatic) centreline is cut off from its root: devascularised (congested)";
  const cuts = r.cutVessels ?? [];
  const out = [risk, h("p", { class: "cut-count" }, `${cuts.length} cut vessel${cuts.length === 1 ? "" : "s"}`)];
  if (cuts.length) {
    const rows = cuts.slice(0, CUT_VESSELS_LISTED).map((c) => [
      `${SYSTEM_LABEL[c.system ?? ""] ?? "vessel"}${c.downstreamOfAnotherCut ? " (downstream)" : ""}`,
      mm(c.radiusMm ?? 0),
      c.resection ?? "",
    ]);
    const t = table(["cut vessel", "radius", "resection"], rows);
    t.className = "cut-vessels";
    out.push(t);
    if (cuts.length > CUT_VESSELS_LISTED) out.push(h("p", { class: "muted" }, `… and ${cuts.length - CUT_VESSELS_LISTED} more`));
  }
  return out;
}

/** A modal form asking for the server's bearer token; null when cancelled. */
export function askToken(retry: boolean): Promise<string | null> {
  return new Promise((resolve) => {
    const input = h("input", { type: "password", autocomplete: "current-password", required: "", minlength: "1" }) as HTMLInputElement;
    const cancel = h("button", { type: "button" }, "Cancel");
    const form = h(
      "form",
      { class: "token" },
      h("p", {}, retry ? "The server refused the token. Token:" : "This server needs a token:"),
      input,
      h("div", {}, h("button", { type: "submit" }, "Connect"), cancel),
    ) as HTMLFormElement;
    const dialog = h("div", { class: "modal" }, form);
    const done = (v: string | null) => {
      dialog.remove();
      resolve(v);
    };
    form.onsubmit = (e) => {
      e.preventDefault();
      done(input.value.trim() || null);
    };
    cancel.onclick = () => done(null);
    document.body.append(dialog);
    input.focus();
  });
}
