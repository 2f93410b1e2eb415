// The repaint timer: deltas applied before a render are painted by the frame after it.

import assert from "node:assert/strict";
import { test } from "node:test";
import { RepaintTimer } from "../src/timings";

test("deltas are timed from arrival to the frame after their render", () => {
  const t = new RepaintTimer();
  t.apply(2, 10, 12);
  t.apply(3, 11, 13);
  assert.equal(t.render(15), true);
  t.apply(4, 16, 17); // after the render: waits for the next one
  t.paint(20);
  assert.deepEqual(t.timings().planVersion, [2, 3]);
  assert.deepEqual(t.timings().arrivalToApplyMs, [2, 2]);
  assert.deepEqual(t.timings().arrivalToRenderMs, [5, 4]);
  assert.deepEqual(t.timings().arrivalToPaintMs, [10, 9]);
  assert.equal(t.render(30), true);
  t.paint(31);
  assert.deepEqual(t.timings().arrivalToPaintMs, [10, 9, 15]);
  assert.equal(t.render(40), false); // nothing new: no extra frame
});

test("only the last `keep` are kept", () => {
  const t = new RepaintTimer(2);
  for (let v = 1; v <= 5; v++) {
    t.apply(v, v, v);
    t.render(v);
    t.paint(v + 1);
  }
  assert.deepEqual(t.timings().planVersion, [4, 5]);
  assert.deepEqual(t.timings().paintAt, [5, 6]);
});
