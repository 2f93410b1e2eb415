// The drag coalescer: one edit in flight, the latest position per point wins, a stale-version
// answer re-bases the next send.

import assert from "node:assert/strict";
import { test } from "node:test";
import { ApiError } from "../src/api";
import type { EditResponse, Vec3 } from "../src/api";
import { DragCoalescer } from "../src/drag";
import type { ControlPointKey, DragValue } from "../src/drag";
import { groupOf } from "../src/editor";

interface Call {
  key: ControlPointKey;
  point: DragValue;
  base: string;
  resolve(a: EditResponse): void;
  reject(e: unknown): void;
}

function harness() {
  const calls: Call[] = [];
  const c = new DragCoalescer(
    (key, point, base) => new Promise<EditResponse>((resolve, reject) => calls.push({ key, point, base, resolve, reject })),
  );
  let idle = 0;
  c.onIdle = () => idle++;
  return { c, calls, idle: () => idle };
}

const at = (x: number): Vec3 => ({ x, y: 0, z: 0 });
const p11 = { name: "r1", i: 1, j: 1 };
const p12 = { name: "r1", i: 1, j: 2 };
const tick = () => new Promise((r) => setImmediate(r));

test("one edit in flight; the latest parked position per point wins, oldest point first", async () => {
  const { c, calls, idle } = harness();
  c.rebase("3");
  c.push(p11, at(1));
  c.push(p11, at(2));
  c.push(p12, at(10));
  c.push(p11, at(3));
  assert.equal(calls.length, 1);
  assert.deepEqual([calls[0]!.point, calls[0]!.base], [at(1), "3"]);
  assert.equal(c.busyWith("r1"), true);
  assert.deepEqual([...c.pendingPoints("r1").values()].map((p) => (p.point as Vec3).x), [3, 10]);
  calls[0]!.resolve({ planVersion: "4" });
  await tick();
  assert.equal(calls.length, 2);
  assert.deepEqual([calls[1]!.key, calls[1]!.point, calls[1]!.base], [p11, at(3), "4"]);
  calls[1]!.resolve({ planVersion: "5" });
  await tick();
  assert.deepEqual([calls[2]!.key, calls[2]!.point, calls[2]!.base], [p12, at(10), "5"]);
  assert.equal(idle(), 0);
  calls[2]!.resolve({ planVersion: "6" });
  await tick();
  assert.equal(calls.length, 3);
  assert.equal(idle(), 1);
  assert.equal(c.busy, false);
  assert.equal(c.acceptedVersion, 6);
  assert.deepEqual(c.counts, { pushed: 4, sent: 3, replaced: 1, stale: 0, failed: 0 });
});

test("a stale-version answer re-bases and sends the position again", async () => {
  const { c, calls } = harness();
  c.rebase("3");
  c.push(p11, at(1));
  calls[0]!.reject(new ApiError(409, { status: 409, code: "STALE_VERSION", current_version: "7" }));
  await tick();
  assert.equal(calls.length, 2);
  assert.deepEqual([calls[1]!.point, calls[1]!.base], [at(1), "7"]);
  calls[1]!.resolve({ planVersion: "8" });
  await tick();
  assert.equal(c.baseVersion, "8");
  assert.equal(c.counts.stale, 1);
});

test("after a stale answer a newer parked position is sent, not the stale one", async () => {
  const { c, calls } = harness();
  c.push(p11, at(1));
  c.push(p11, at(2));
  calls[0]!.reject(new ApiError(409, { status: 409, current_version: "9" }));
  await tick();
  assert.deepEqual([calls[1]!.point, calls[1]!.base], [at(2), "9"]);
  calls[1]!.resolve({ planVersion: "10" });
  await tick();
  assert.equal(calls.length, 2);
});

test("the watch stream's version only moves the base forward; other errors are reported", async () => {
  const { c, calls } = harness();
  const errors: unknown[] = [];
  c.onAnswer = (e) => void (e && errors.push(e));
  c.rebase("5");
  c.rebase("4");
  assert.equal(c.baseVersion, "5");
  c.push(p11, at(1));
  calls[0]!.reject(new ApiError(400, { status: 400, code: "INVALID_ARGUMENT" }));
  await tick();
  assert.equal(calls.length, 1);
  assert.equal(errors.length, 1);
  assert.equal(c.busy, false);
  assert.equal(c.counts.failed, 1);
});

test("a group drag parks whole grids under one key, the latest replacing the earlier", async () => {
  const { c, calls } = harness();
  const all = { name: "r1", i: -1, j: -1 };
  c.push(all, [at(1), at(2)]);
  c.push(all, [at(3), at(4)]);
  c.push(all, [at(5), at(6)]);
  assert.equal(calls.length, 1);
  calls[0]!.resolve({ planVersion: "2" });
  await tick();
  assert.deepEqual([calls[1]!.key, calls[1]!.point, calls[1]!.base], [all, [at(5), at(6)], "2"]);
  assert.equal(c.counts.replaced, 1);
});

test("groups of a 4 × 4 grid: the 12 border points, the 4 inner ones", () => {
  assert.deepEqual(groupOf(0, 2, 4, 4), [0, 1, 2, 3, 4, 7, 8, 11, 12, 13, 14, 15]);
  assert.deepEqual(groupOf(2, 1, 4, 4), [5, 6, 9, 10]);
  assert.deepEqual(groupOf(1, 1, 3, 5), [6, 7, 8]);
});
