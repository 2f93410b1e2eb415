// The page: picks a session, follows its watch stream and shows it (scene and panel).
// `window.resecta` exposes the state for scripts and tests.

import "./app.css";
import { Api, ApiError } from "./api";
import { askToken, Panel } from "./panel";
import { Plan } from "./plan";
import type { Change, PublicState } from "./plan";
import { Scene } from "./scene";

declare global {
  interface Window {
    resecta: { state(): PublicState | null; api: Api };
  }
}

const api = new Api(askToken);
const panel = new Panel(document.getElementById("panel")!);
const scene = new Scene(document.getElementById("view")!);
let plan: Plan | null = null;
window.resecta = { state: () => plan?.state() ?? null, api };

const message = (e: unknown) => (e instanceof Error ? e.message : String(e));

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
  panel.show(p);
  frame ||= requestAnimationFrame(() => {
    frame = 0;
    scene.render();
  });
}

async function main(): Promise<void> {
  panel.setStatus("Connecting…", "busy");
  const id = await chooseSession();
  history.replaceState(null, "", `?session=${encodeURIComponent(id)}`);
  const p = (plan = new Plan(id));
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
    delta(d, msg) {
      try {
        redraw(p, p.applyDelta(d, msg));
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
