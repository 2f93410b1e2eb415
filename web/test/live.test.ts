// Against a running server (RESECTA_URL=http://127.0.0.1:8080, e.g. `resecta serve --demo`;
// skipped without it): the watch stream's deltas, applied by the client, give bit for bit the
// meshes of a fresh snapshot; and a 401 asks for the token, which is then sent.

import assert from "node:assert/strict";
import { test } from "node:test";
import { Api } from "../src/api";
import type { Snapshot, WatchResponse } from "../src/api";
import { Plan } from "../src/plan";

const url = process.env["RESECTA_URL"];
const skip = url ? false : "RESECTA_URL is not set: no server to test against";
if (!url) console.log(`SKIP: ${skip}`);

const memory = () => {
  const m = new Map<string, string>();
  return { getItem: (k: string) => m.get(k) ?? null, setItem: (k: string, v: string) => void m.set(k, v) };
};
const api = () => new Api(async () => process.env["RESECTA_TOKEN"] ?? null, url, memory());

/** The first snapshot of a new watch of `id`. */
function snapshotOf(id: string): Promise<[Snapshot, WatchResponse]> {
  return new Promise((resolve, reject) => {
    const s = api().watch(id, {
      snapshot: (snap, msg) => (s.close(), resolve([snap, msg])),
      delta: () => {},
      volumes: () => {},
      status: (st, e) => st === "failed" && reject(e),
    });
  });
}

const bits = (a: Float32Array | null) => (a ? Buffer.from(a.buffer, a.byteOffset, a.byteLength).toString("hex") : null);

test("deltas from the watch stream give what a fresh snapshot gives", { skip, timeout: 60_000 }, async () => {
  const client = api();
  const { sessions = [] } = await client.listSessions();
  const ready = sessions.find((s) => s.state === "SESSION_STATE_READY");
  assert.ok(ready, "a session with models (resecta serve --demo)");
  const plan = new Plan(ready.id);
  let deltas = 0;
  let changed: () => void = () => {};
  const stream = client.watch(ready.id, {
    snapshot: (s, m) => (plan.applySnapshot(s, m), changed()),
    delta: (d, m) => {
      plan.applyDelta(d, m);
      deltas += d.resections?.filter((r) => r.meshDelta).length ?? 0; // RSDL, not whole meshes
      changed();
    },
    volumes: (v, m) => plan.applyVolumes(v, m),
    status: () => {},
  });
  const until = (ok: () => boolean) => new Promise<void>((r) => ((changed = () => ok() && r()), changed()));
  try {
    await until(() => plan.resections.size > 0);
    const [name, r] = [...plan.resections][0]!;
    const p = r.resection.controlPoints![1]!;
    for (const dx of [3, -2, 1.5]) {
      const version = plan.planVersion;
      await client.edit(ready.id, version, { setControlPoint: { name, i: 0, j: 1, point: { ...p, x: p.x + dx } } });
      await until(() => plan.planVersion !== version);
    }
    assert.ok(deltas >= 3);
    assert.ok(plan.resections.get(name)!.mesh!.header.kind === "mesh");
    const fresh = new Plan(ready.id);
    fresh.applySnapshot(...(await snapshotOf(ready.id)));
    const [held, want] = [plan.resections.get(name)!, fresh.resections.get(name)!];
    assert.equal(bits(held.mesh!.positions), bits(want.mesh!.positions));
    assert.equal(bits(held.mesh!.normals), bits(want.mesh!.normals));
    assert.equal(bits(held.mesh!.margins), bits(want.mesh!.margins));
    assert.deepEqual(held.mesh!.classes, want.mesh!.classes);
    assert.deepEqual(held.verdict, want.verdict);
    assert.equal(plan.state().planVersion, Number(fresh.planVersion));
  } finally {
    stream.close();
  }
});
