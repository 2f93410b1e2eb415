// The intake's pure part: the role form, the format from the file name, the reconstruction
// form and its events, the summary's rows; and `Api.reconstruct` against a fake server.

import assert from "node:assert/strict";
import http from "node:http";
import type { AddressInfo } from "node:net";
import { test } from "node:test";
import { Api, ApiError } from "../src/api";
import type { ReconstructEvent } from "../src/api";
import {
  DEFAULT_ROLES,
  doneText,
  formatOf,
  labelRows,
  modelText,
  parseRoles,
  reconstructRequest,
  reconstructStep,
  rolesText,
  STARTED,
} from "../src/intake";
import type { ReconstructFields } from "../src/intake";

test("roles: lists with commas or spaces; empty roles left out; the defaults round-trip", () => {
  assert.deepEqual(parseRoles({ parenchyma: " 1, 5 ,6", tumor: "2 7", portal: "", hepatic: "4", vessel: " " }), {
    ok: true,
    value: { parenchyma: [1, 5, 6], tumor: [2, 7], hepatic: [4] },
  });
  assert.deepEqual(rolesText(DEFAULT_ROLES), { parenchyma: "1", tumor: "2", portal: "3", hepatic: "4", vessel: "" });
  assert.deepEqual(parseRoles(rolesText(DEFAULT_ROLES)), { ok: true, value: DEFAULT_ROLES });
  assert.deepEqual(parseRoles({ parenchyma: "65535", tumor: "1" }), { ok: true, value: { parenchyma: [65535], tumor: [1] } });
});

test("roles: every mistake named, none sent", () => {
  assert.deepEqual(parseRoles({ parenchyma: "1, 0", tumor: "2, 2", portal: "3, 65536", hepatic: "1.5, x, 3", vessel: "-4" }), {
    ok: false,
    errors: [
      'Parenchyma: "0" is not a label value (a whole number from 1 to 65535)',
      "Tumour: label 2 is given twice",
      'Portal vein: "65536" is not a label value (a whole number from 1 to 65535)',
      'Hepatic veins: "1.5" is not a label value (a whole number from 1 to 65535)',
      'Hepatic veins: "x" is not a label value (a whole number from 1 to 65535)',
      "Label 3 is in two roles: Portal vein and Hepatic veins",
      'Vessels (not split): "-4" is not a label value (a whole number from 1 to 65535)',
    ],
  });
  assert.deepEqual(parseRoles({ parenchyma: "", tumor: "" }), {
    ok: false,
    errors: ["Parenchyma: give at least one label value", "Tumour: give at least one label value"],
  });
});

test("format from the file name, case-blind; anything else is told by the server", () => {
  const got = ["a.nii", "A.NII.GZ", "b.nrrd", "Segmentation.seg.nrrd", "c.mha", "d.nhdr", "e.mhd", "f", "nii.gz.zip"].map(formatOf);
  assert.deepEqual(got, [
    "LABEL_MAP_FORMAT_NIFTI",
    "LABEL_MAP_FORMAT_NIFTI",
    "LABEL_MAP_FORMAT_NRRD",
    "LABEL_MAP_FORMAT_SEG_NRRD",
    "LABEL_MAP_FORMAT_METAIMAGE",
    "LABEL_MAP_FORMAT_AUTO",
    "LABEL_MAP_FORMAT_AUTO",
    "LABEL_MAP_FORMAT_AUTO",
    "LABEL_MAP_FORMAT_AUTO",
  ]);
});

const fields = (f: Partial<ReconstructFields>): ReconstructFields => ({
  method: "RECONSTRUCTION_METHOD_PSR",
  psrDepth: "",
  smoothing: "",
  decimation: "",
  splitComponents: false,
  minComponentMm3: "",
  ...f,
});

test("reconstruction form: blanks are the engine's defaults, values within the server's limits", () => {
  const limits = { minPsrDepth: 1, maxPsrDepth: 8 };
  assert.deepEqual(reconstructRequest(fields({}), limits), { ok: true, value: { method: "RECONSTRUCTION_METHOD_PSR", options: {} } });
  assert.deepEqual(reconstructRequest(fields({ psrDepth: "8", smoothing: "0", decimation: "0.5", splitComponents: true, minComponentMm3: "0" }), limits), {
    ok: true,
    value: { method: "RECONSTRUCTION_METHOD_PSR", options: { psrDepth: 8, smoothing: 0, decimation: 0.5, minComponentMm3: 0, splitComponents: true } },
  });
  // MCSD has no depth: a bad one is not its concern.
  assert.deepEqual(reconstructRequest(fields({ method: "RECONSTRUCTION_METHOD_MCSD", psrDepth: "99", smoothing: "1" }), limits), {
    ok: true,
    value: { method: "RECONSTRUCTION_METHOD_MCSD", options: { smoothing: 1 } },
  });
  assert.deepEqual(reconstructRequest(fields({ psrDepth: "9", smoothing: "1.1", decimation: "1", minComponentMm3: "-1" }), limits), {
    ok: false,
    errors: [
      "PSR depth must be a whole number from 1 to 8",
      "Smoothing must be from 0 to 1",
      "Decimation must be from 0 up to (not including) 1",
      "Smallest vessel piece must be 0 mm³ or more",
    ],
  });
  assert.deepEqual(reconstructRequest(fields({ psrDepth: "6.5", smoothing: "NaN" }), {}), {
    ok: false,
    errors: ["PSR depth must be a whole number from 1 to 10", "Smoothing must be from 0 to 1"],
  });
});

const EVENTS: ReconstructEvent[] = [
  { progress: { stage: "built parenchyma", fraction: 0.6 } },
  { progress: { stage: "built tumor_1", fraction: 0.5 } }, // never goes back
  { model: { name: "parenchyma", triangleCount: "110372", volumeMl: 127.544, method: "RECONSTRUCTION_METHOD_PSR" } },
  { model: { name: "tumor_1", triangleCount: "464", volumeMl: 1.81, method: "RECONSTRUCTION_METHOD_MCSD" } },
  { done: { modelCount: 2, elapsedS: 5.2995, dropped: [{ kind: "SURFACE_KIND_PORTAL", count: 2, volumeMl: 0.004 }] } },
];

test("reconstruction events: progress, models as they come, done", () => {
  const views = EVENTS.reduce((vs, e) => [...vs, reconstructStep(vs.at(-1)!, e)], [STARTED]);
  assert.deepEqual(
    views.map((v) => [v.fraction, v.stage, v.models.map((m) => m.name), v.done !== null]),
    [
      [0, "starting", [], false],
      [0.6, "built parenchyma", [], false],
      [0.6, "built tumor_1", [], false],
      [0.6, "built tumor_1", ["parenchyma"], false],
      [0.6, "built tumor_1", ["parenchyma", "tumor_1"], false],
      [1, "done", ["parenchyma", "tumor_1"], true],
    ],
  );
  const last = views.at(-1)!;
  assert.deepEqual(last.models.map(modelText), ["parenchyma: 127.5 ml, 110,372 triangles (PSR)", "tumor_1: 1.8 ml, 464 triangles (MCSD)"]);
  assert.equal(doneText(last.done!), "Built 2 models in 5.3 s; left out as too small: 2 portal (0.00 ml)");
  assert.equal(doneText({ modelCount: 3, elapsedS: 0.03 }), "Built 3 models in 0.0 s");
});

test("summary: rows per label, a role's label missing from the file and a label in no role", () => {
  const { rows, warnings } = labelRows({
    roles: { parenchyma: [1], tumor: [2], hepatic: [4] },
    labels: [
      { label: 1, voxels: "10227", volumeMl: 122.724 },
      { label: 2, voxels: "181", volumeMl: 2.172 },
      { label: 7, voxels: "60", volumeMl: 0.72 },
    ],
  });
  assert.deepEqual(rows, [
    ["1", "Parenchyma", "10,227", "122.7 ml"],
    ["2", "Tumour", "181", "2.2 ml"],
    ["7", "none", "60", "0.72 ml"],
  ]);
  assert.deepEqual(warnings, ["Label 7 is in no role: it is ignored", "Hepatic veins label 4 is not in the file"]);
});

test("Api.reconstruct: posts the request, yields the events until done; an error event throws its problem", async () => {
  const bodies: string[] = [];
  const server = http.createServer((req, res) => {
    let body = "";
    req.on("data", (c) => (body += c));
    req.on("end", () => {
      bodies.push(`${req.method} ${req.url} ${body}`);
      res.writeHead(200, { "content-type": "text/event-stream" });
      if (bodies.length === 1) for (const e of EVENTS) res.write(`event: ${Object.keys(e)[0]}\ndata: ${JSON.stringify(e)}\n\n`);
      else res.write(`: keep-alive\n\nevent: error\ndata: ${JSON.stringify({ status: 409, code: "FAILED_PRECONDITION", detail: "memory budget exceeded" })}\n\n`);
      res.end();
    });
  });
  await new Promise<void>((r) => server.listen(0, "127.0.0.1", r));
  const api = new Api(async () => null, `http://127.0.0.1:${(server.address() as AddressInfo).port}`, { getItem: () => null, setItem: () => {} });
  try {
    const got: ReconstructEvent[] = [];
    for await (const e of api.reconstruct("s/1", { method: "RECONSTRUCTION_METHOD_MCSD", options: { smoothing: 0.3 } })) got.push(e);
    assert.deepEqual(got, EVENTS);
    await assert.rejects(
      async () => {
        for await (const e of api.reconstruct("s1", {})) got.push(e);
      },
      (e: unknown) => e instanceof ApiError && e.status === 409 && e.problem.detail === "memory budget exceeded",
    );
    assert.equal(got.length, EVENTS.length);
    assert.deepEqual(bodies, [
      'POST /v1/sessions/s%2F1/reconstruct {"method":"RECONSTRUCTION_METHOD_MCSD","options":{"smoothing":0.3}}',
      "POST /v1/sessions/s1/reconstruct {}",
    ]);
  } finally {
    server.close();
    server.closeAllConnections();
  }
});

test("Api.reconstruct: aborting closes the request (the server cancels) and throws AbortError", async () => {
  let closed: () => void;
  const serverSawClose = new Promise<void>((r) => (closed = r));
  const server = http.createServer((_req, res) => {
    res.writeHead(200, { "content-type": "text/event-stream" });
    res.write(`event: progress\ndata: ${JSON.stringify(EVENTS[0])}\n\n`); // and nothing more
    res.on("close", () => closed());
  });
  await new Promise<void>((r) => server.listen(0, "127.0.0.1", r));
  const api = new Api(async () => null, `http://127.0.0.1:${(server.address() as AddressInfo).port}`, { getItem: () => null, setItem: () => {} });
  const abort = new AbortController();
  const got: ReconstructEvent[] = [];
  try {
    await assert.rejects(
      async () => {
        for await (const e of api.reconstruct("s1", {}, abort.signal)) {
          got.push(e);
          abort.abort();
        }
      },
      { name: "AbortError" },
    );
    await serverSawClose;
    assert.deepEqual(got, [EVENTS[0]]);
  } finally {
    server.close();
    server.closeAllConnections();
  }
});
