// The page: picks a session, follows its watch stream and shows it (scene and panel).
// `window.resecta` exposes the state for scripts and tests.

import "./app.css";
import { Api, ApiError, elsewhereUrl, sessionFromHash } from "./api";
import type { Edit, Vec3 } from "./api";
import { GridEditor } from "./editor";
import { Intake } from "./intake";
import { Methods } from "./methods";
import type { DrawingState } from "./methods";
import { nearestVertex } from "./traces";
import { askToken, Panel } from "./panel";
import { Plan } from "./plan";
import type { Change, PublicState } from "./plan";
import { ResectogramView } from "./resectogram";
import type { ResectogramState } from "./resectogram";
import { PALETTE, Scene } from "./scene";
import type { ScreenPoint } from "./scene";
import { SliceView } from "./sliceview";
import type { SliceState } from "./sliceview";
import { RepaintTimer } from "./timings";
import type { Timings } from "./timings";
import { Tools } from "./tools";

declare global {
  interface Window {
    resecta: {
      state(): PublicState | null;
      api: Api;
      /** Where control point P_ij of resection `name` is drawn (client pixels). */
      screenPosition(name: string, i: number, j: number): ScreenPoint | null;
      /** Moves P_ij of `name` to `to` as a mouse drag does. */
      dragControlPoint(name: string, i: number, j: number, to: [number, number, number]): void;
      undo(): Promise<void>;
      redo(): Promise<void>;
      /** The last deltas' times: received → applied, rendered and the frame after (timings.ts). */
      timings(): Timings;
      /** Where the 3D view's camera looks (RAS mm). */
      focalPoint(): Vec3;
      /** The opacity and visibility surface `name` is drawn with. */
      look(name: string): { opacity: number; visible: boolean } | null;
      /** The names of the models shown. */
      models(): string[];
      /** The slice view's plane, raster size, contours drawn and last picked point. */
      slice(): SliceState | null;
      /** What the resectogram shows: its resection, plan version, size and cut vessels. */
      resectogram(): ResectogramState | null;
      /** The DS or CP resection being drawn, not yet sent. */
      drawing(): DrawingState | null;
      /** The vertex of surface `name` nearest the point of it drawn at page position (x, y). */
      probe(name: string, x: number, y: number): { vertex: number; point: Vec3 } | null;
      /** Where vertex `k` of surface `name` is drawn. */
      vertexScreen(name: string, k: number): ScreenPoint | null;
    };
  }
}

const api = new Api(askToken);
const panel = new Panel(document.getElementById("panel")!);
const view = document.getElementById("view")!;
const scene = new Scene(view);
const timer = new RepaintTimer();
const resectogram = new ResectogramView(panel.root.appendChild(document.createElement("section")), api);
const intake = new Intake(panel.root.appendChild(document.createElement("section")), api);
const sliceView = new SliceView(document.getElementById("slice")!, api, PALETTE, PALETTE["resection"]![0], (e) =>
  panel.setStatus(`Slice view: ${message(e)}`, "error"),
);
let plan: Plan | null = null;
let editor: GridEditor | null = null;
/** The newest plan version an edit of this page was answered with. */
let answered = 0;
/** The page's own edits (the tools', undo, redo), one at a time in order. */
let queue: Promise<unknown> = Promise.resolve();
/** A resection made here, selected once the stream shows it. */
let selectWhenShown: string | null = null;
/** The resection whose closest point is marked. */
let marked: string | null = null;
/** While true the next click on the 3D view gives the new resection's end point. */
let pickingEndPoint = false;

const message = (e: unknown) => (e instanceof Error ? e.message : String(e));

/** The plan's state, with the control points as shown (dragged ones where they are dragged). */
function state(): PublicState | null {
  const s = plan?.state() ?? null;
  if (s && editor) for (const [name, r] of Object.entries(s.resections)) r.controlPoints = editor.shownPoints(name);
  return s;
}

/** The newest plan version known here: shown, answered to an edit, or to a drag. */
function knownVersion(): number {
  return Math.max(Number(plan?.planVersion ?? 0), answered, editor?.coalescer.acceptedVersion ?? 0);
}

/** What went wrong with an edit, in words for the person planning. */
function editFailure(e: unknown): string {
  if (e instanceof ApiError) {
    const p = e.problem;
    if (e.status === 409 && p.current_version != null) {
      return `The plan changed meanwhile (now version ${p.current_version}): your change was not applied. Look again and repeat it.`;
    }
    if (p.code?.startsWith("NOTHING_TO_")) return p.code === "NOTHING_TO_UNDO" ? "Nothing to undo" : "Nothing to redo";
    return p.detail || e.message;
  }
  return message(e);
}

/** Sends `edit` after the page's earlier ones, against the newest version known; true when
 * applied, otherwise the status line says why. */
function send(edit: Edit, unchecked = false): Promise<boolean> {
  const run = async () => {
    if (!plan) return false;
    try {
      const a = await api.edit(plan.sessionId, unchecked ? 0 : knownVersion(), edit);
      answered = Math.max(answered, Number(a.planVersion ?? 0));
      return true;
    } catch (e) {
      panel.setStatus(editFailure(e), "error");
      return false;
    }
  };
  const done = queue.then(run);
  queue = done;
  return done;
}

/** Undo or redo: drops drag positions not yet sent, then asks the server. */
async function history(op: "undo" | "redo"): Promise<void> {
  if (!plan || !editor) return;
  editor.cancelPending();
  await send({ [op]: {} }, true);
}

/** Offers `blob` as a download named `name`. */
function download(blob: Blob, name: string): void {
  const url = URL.createObjectURL(blob);
  const a = document.createElement("a");
  a.href = url;
  a.download = name;
  a.click();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

/** Marks resection `name`'s closest point to its tumour and, with `turn`, looks at it. */
function showClosest(name: string, turn: boolean): void {
  const v = plan?.resections.get(name)?.verdict;
  if (!v?.point || v.minMarginMm == null) {
    scene.mark(null);
    marked = null;
    if (turn) panel.setStatus(`No part of ${name} is inside the liver`, "error");
    return;
  }
  marked = name;
  scene.mark(v.point, 1.5);
  if (turn) {
    scene.focus(v.point, 120);
    panel.setStatus(`${name}: ${v.minMarginMm.toFixed(1)} mm from the tumour at its closest point (marked)`);
  }
  requestRender();
}

const tools = new Tools({
  edit: (e) => send(e),
  showClosest: (name) => showClosest(name, true),
  pickEndPoint() {
    pickingEndPoint = true;
    view.style.cursor = "crosshair";
    panel.setStatus("Click the liver in the 3D view or the slice view where the resection should end (Esc: cancel)", "busy");
  },
  setLook(name, look) {
    scene.setLook(name, look);
    requestRender();
  },
  look: (name) => scene.look(name),
  async exportModel(name, format) {
    if (!plan) return;
    try {
      download(await api.exportModel(plan.sessionId, name, format), `${name}.${format.replace("MODEL_FORMAT_", "").toLowerCase()}`);
    } catch (e) {
      panel.setStatus(`Export failed: ${editFailure(e)}`, "error");
    }
  },
  async savePlan() {
    if (!plan) return;
    try {
      const { planJson, planVersion } = await api.exportPlan(plan.sessionId);
      download(new Blob([planJson], { type: "application/json" }), `plan-v${planVersion ?? "0"}.json`);
    } catch (e) {
      panel.setStatus(`Saving the plan failed: ${editFailure(e)}`, "error");
    }
  },
  async loadPlan(file) {
    if (!plan) return;
    if (file.size > 16 << 20) return panel.setStatus("That file is larger than a plan can be (16 MiB)", "error");
    const text = await file.text();
    const id = plan.sessionId;
    const done = queue.then(async () => {
      try {
        const { planVersion } = await api.importPlan(id, text, knownVersion());
        answered = Math.max(answered, Number(planVersion ?? 0));
        panel.setStatus(`Plan loaded: version ${planVersion ?? "?"}`);
      } catch (e) {
        panel.setStatus(`The plan was not loaded: ${editFailure(e)}`, "error");
      }
    });
    queue = done;
    await done;
  },
  report: (text, kind) => panel.setStatus(text, kind),
  startTracing: (method, name, target) => methods.start(method, name, target),
});
tools.onCreated = (name) => {
  if (plan?.resections.has(name)) panel.onSelect(name);
  else selectWhenShown = name; // the stream has not shown it yet
};
const methods = new Methods(
  {
    edit: (e) => send(e),
    report: (text, kind) => panel.setStatus(text, kind),
    created: (name) => tools.onCreated(name),
    liver: () => {
      const names = plan ? [...plan.models.values()].filter((m) => m.kind === "parenchyma").map((m) => m.name) : [];
      return names.length ? names : scene.names();
    },
    render: () => requestRender(),
  },
  scene,
  sliceView,
  view,
);
tools.slot(methods.root);
panel.root.append(tools.root);

view.addEventListener(
  "pointerdown",
  (e) => {
    if (!pickingEndPoint || e.button !== 0) return;
    e.stopPropagation();
    e.preventDefault();
    const names = plan ? [...plan.models.values()].filter((m) => m.kind === "parenchyma").map((m) => m.name) : [];
    const p = scene.pickSurface(e.clientX, e.clientY, names.length ? names : scene.names());
    if (!p) return panel.setStatus("That is not on the liver: click its surface (Esc: cancel)", "busy");
    endPointPicked(p);
  },
  { capture: true },
);

/** The new resection's end point, clicked on the 3D view or the slice view while picking. */
function endPointPicked(p: Vec3): void {
  pickingEndPoint = false;
  view.style.cursor = "";
  tools.setEndPoint(p);
  panel.setStatus("End point set: choose the tumour and Create");
}
sliceView.onPick = (p) => {
  if (pickingEndPoint) endPointPicked(p);
};

window.resecta = {
  state,
  api,
  screenPosition: (name, i, j) => editor?.screenPosition(name, i, j) ?? null,
  dragControlPoint: (name, i, j, [x, y, z]) => editor?.move({ name, i, j }, { x, y, z } satisfies Vec3),
  undo: () => history("undo"),
  redo: () => history("redo"),
  timings: () => timer.timings(),
  focalPoint: () => scene.focalPoint(),
  look: (name) => scene.look(name),
  models: () => [...(plan?.models.keys() ?? [])],
  slice: () => sliceView.state(),
  resectogram: () => resectogram.state(),
  drawing: () => methods.drawingState(),
  probe(name, x, y) {
    const p = scene.pickSurface(x, y, [name]), mesh = scene.mesh(name);
    return p && mesh ? { vertex: nearestVertex(mesh, p), point: p } : null;
  },
  vertexScreen(name, k) {
    const q = scene.mesh(name)?.positions;
    return q && 3 * k + 2 < q.length ? scene.toScreen({ x: q[3 * k]!, y: q[3 * k + 1]!, z: q[3 * k + 2]! }) : null;
  },
};

panel.setActions(() => void history("undo"), () => void history("redo"));
document.addEventListener("keydown", (e) => {
  if (e.key === "Escape" && pickingEndPoint) {
    pickingEndPoint = false;
    view.style.cursor = "";
    panel.setStatus("Picking cancelled");
    return;
  }
  if (!(e.ctrlKey || e.metaKey) || e.altKey || e.target instanceof HTMLInputElement) return;
  const key = e.key.toLowerCase();
  const op = key === "z" ? (e.shiftKey ? "redo" : "undo") : key === "y" && !e.shiftKey ? "redo" : null;
  if (!op) return;
  e.preventDefault();
  void history(op);
});

/** The session of `#session=ID` (a replica's redirect) or `?session=ID`, else the only one, else
 * the one picked from the list. */
async function chooseSession(): Promise<string> {
  const query = new URLSearchParams(location.search);
  const given = sessionFromHash(location.hash) ?? query.get("session");
  if (given) return given;
  const { sessions = [] } = await api.listSessions();
  if (sessions.length === 1 && !query.has("sessions")) return sessions[0]!.id; // `?sessions`: the list
  panel.setStatus(sessions.length ? `${sessions.length} sessions: pick one or make one` : "No session yet: make one");
  return panel.pickSession(sessions, async (name) => (await api.createSession(name)).session.id);
}

let frame = 0;
function redraw(p: Plan, change: Change): void {
  if (change.all) scene.clear();
  for (const name of change.removed) scene.remove(name);
  for (const name of change.surfaces) {
    const model = p.models.get(name);
    const r = p.resections.get(name);
    if (model) scene.show(name, model.mesh, model);
    else if (r?.mesh) scene.show(name, r.mesh, { kind: "resection" });
  }
  if (selectWhenShown && p.resections.has(selectWhenShown) && editor) {
    editor.selected = selectWhenShown;
    selectWhenShown = null;
  }
  editor?.refresh();
  panel.selected = editor?.selected ?? null;
  panel.show(p);
  resectogram.refresh(p.sessionId, panel.selected);
  tools.update(p, panel.selected);
  methods.update(p, panel.selected);
  if (marked) showClosest(marked, false);
  sliceView.planChanged([...p.resections.keys()], editor?.selected ?? null);
  requestRender();
}

/** The vessels the volumes' risk analysis finds cut, marked in the 3D view. */
function showCutVessels(p: Plan): void {
  scene.showCutVessels(p.volumes?.risk?.cutVessels ?? []);
  requestRender();
}

function requestRender(): void {
  frame ||= requestAnimationFrame(() => {
    frame = 0;
    scene.render();
    if (timer.render(performance.now())) requestAnimationFrame(() => timer.paint(performance.now()));
  });
}

async function main(): Promise<void> {
  panel.setStatus("Connecting…", "busy");
  const id = await chooseSession();
  window.history.replaceState(null, "", `?session=${encodeURIComponent(id)}`);
  const p = (plan = new Plan(id));
  const e = (editor = new GridEditor(api, p, scene, view, requestRender, (err) => panel.setStatus(`Edit failed: ${message(err)}`, "error")));
  panel.onSelect = (name) => {
    e.select(name);
    sliceView.select(name);
    panel.selected = name;
    panel.show(p);
    resectogram.refresh(p.sessionId, name);
    tools.update(p, name);
    methods.update(p, name);
  };
  panel.setStatus("Loading the session…", "busy");
  let lost = false;
  let opened = false;
  let sliceKey = ""; // the label map the slice view shows
  const stream = api.watch(id, {
    snapshot(s, msg) {
      try {
        redraw(p, p.applySnapshot(s, msg));
        showCutVessels(p);
        intake.show(p.session);
        const labelMap = p.session?.labelMap;
        const key = labelMap ? JSON.stringify(labelMap) : "";
        if (key !== sliceKey && p.session && labelMap) sliceView.open(p.session, [...p.resections.keys()]);
        sliceKey = key;
        // Later snapshots (after an import, a resync) keep what the status line says.
        const empty = p.session?.state === "SESSION_STATE_EMPTY";
        if (!opened || !p.models.size) {
          panel.setStatus(p.models.size ? "Live" : `Live: no ${empty ? "label map yet (upload one below)" : "models yet (reconstruct them below)"}`);
        }
        opened = true;
      } catch (e) {
        panel.setStatus(`Bad snapshot: ${message(e)}`, "error");
      }
    },
    delta(d, msg, received) {
      try {
        redraw(p, p.applyDelta(d, msg));
        timer.apply(Number(msg.planVersion ?? p.planVersion), received, performance.now());
      } catch (e) {
        panel.setStatus(`${message(e)}; asking for a fresh snapshot`, "busy");
        stream.resync();
      }
    },
    volumes(v, msg) {
      p.applyVolumes(v, msg);
      showCutVessels(p);
      panel.show(p);
      methods.update(p, panel.selected);
    },
    status(s, e) {
      if (s === "live" && lost) panel.setStatus("Live again: reconnected to the server");
      if (s === "reconnecting") panel.setStatus("Connection to the server lost: reconnecting…", "busy");
      else if (s === "failed") panel.setStatus(streamFailure(e), "error");
      lost = s !== "live";
    },
  });
}

/** Why the watch stream stopped for good, in words. */
function streamFailure(e: unknown): string {
  const moved = elsewhereUrl(e);
  if (moved) return `This session is now served by another replica (${moved}): opening it there… You may be asked for the token again.`;
  if (e instanceof ApiError && e.status === 401) return "The server refused the token: reload the page to enter it again";
  if (e instanceof ApiError && e.status === 404) return "This session is no longer on the server (deleted or expired)";
  return `The live view stopped: ${message(e)}`;
}

// A replicated server: another replica holds the session (421). This page cannot call that
// origin (same-origin CSP, no CORS), so it says so and opens the session there; the token is not
// carried over (it lives in this origin's sessionStorage): that page asks for it.
const MOVE_NOTICE_MS = 2500;
api.onElsewhere = (pageUrl, replica) => {
  const where = replica.http_url ?? pageUrl;
  panel.setStatus(
    `This session is now served by another replica (${where}): opening it there… ` +
      "You may be asked for the token again (it is kept per address).",
    "busy",
  );
  window.setTimeout(() => location.assign(pageUrl), MOVE_NOTICE_MS);
};

main().catch((e: unknown) => {
  panel.setStatus(e instanceof ApiError ? e.message : `Error: ${message(e)}`, "error");
});
