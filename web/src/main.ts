// The page: picks a session, follows its watch stream and shows it (scene and panel).
// `window.resecta` exposes the state for scripts and tests.

import "./app.css";
import { Api, ApiError } from "./api";
import type { Vec3 } from "./api";
import { GridEditor } from "./editor";
import { askToken, Panel } from "./panel";
import { Plan } from "./plan";
import type { Change, PublicState } from "./plan";
import { Scene } from "./scene";
import type { ScreenPoint } from "./scene";
import { RepaintTimer } from "./timings";
import type { Timings } from "./timings";

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
    };
  }
}

const api = new Api(askToken);
const panel = new Panel(document.getElementById("panel")!);
const view = document.getElementById("view")!;
const scene = new Scene(view);
const timer = new RepaintTimer();
let plan: Plan | null = null;
let editor: GridEditor | null = null;

const message = (e: unknown) => (e instanceof Error ? e.message : String(e));

/** The plan's state, with the control points as shown (dragged ones where they are dragged). */
function state(): PublicState | null {
  const s = plan?.state() ?? null;
  if (s && editor) for (const [name, r] of Object.entries(s.resections)) r.controlPoints = editor.shownPoints(name);
  return s;
}

/** Undo or redo: drops drag positions not yet sent, then asks the server. */
async function history(op: "undo" | "redo"): Promise<void> {
  if (!plan || !editor) return;
  editor.cancelPending();
  try {
    await api.edit(plan.sessionId, 0, { [op]: {} });
  } catch (e) {
    panel.setStatus(e instanceof ApiError && e.problem.code?.startsWith("NOTHING_TO_") ? `Nothing to ${op}` : message(e), "error");
  }
}

window.resecta = {
  state,
  api,
  screenPosition: (name, i, j) => editor?.screenPosition(name, i, j) ?? null,
  dragControlPoint: (name, i, j, [x, y, z]) => editor?.move({ name, i, j }, { x, y, z } satisfies Vec3),
  undo: () => history("undo"),
  redo: () => history("redo"),
  timings: () => timer.timings(),
};

panel.setActions(() => void history("undo"), () => void history("redo"));
document.addEventListener("keydown", (e) => {
  if (!(e.ctrlKey || e.metaKey) || e.altKey || e.target instanceof HTMLInputElement) return;
  const key = e.key.toLowerCase();
  const op = key === "z" ? (e.shiftKey ? "redo" : "undo") : key === "y" && !e.shiftKey ? "redo" : null;
  if (!op) return;
  e.preventDefault();
  void history(op);
});

/** The session of `?session=ID`, else the only one, else the one picked from the list. */
async function chooseSession(): Promise<string> {
  const given = new URLSearchParams(location.search).get("session");
  if (given) return given;
  const { sessions = [] } = await api.listSessions();
  if (sessions.length === 1) return sessions[0]!.id;
  panel.setStatus(`${sessions.length} sessions: pick one`);
  return panel.pickSession(sessions);
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
  editor?.refresh();
  panel.selected = editor?.selected ?? null;
  panel.show(p);
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
    panel.selected = name;
    panel.show(p);
  };
  panel.setStatus("Loading the session…", "busy");
  const stream = api.watch(id, {
    snapshot(s, msg) {
      try {
        redraw(p, p.applySnapshot(s, msg));
        panel.setStatus(p.models.size ? "Live" : "Live: no models yet (reconstruct them first)");
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
      panel.show(p);
    },
    status(s, e) {
      if (s === "reconnecting") panel.setStatus(`Reconnecting…${e ? ` (${message(e)})` : ""}`, "busy");
      else if (s === "failed") panel.setStatus(message(e), "error");
    },
  });
}

main().catch((e: unknown) => {
  panel.setStatus(e instanceof ApiError ? e.message : `Error: ${message(e)}`, "error");
});
