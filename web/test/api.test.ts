// The watch stream's client against a fake server: event parsing, snapshot parts joined,
// reconnection resuming from the last event id, the token asked for on a 401.

import assert from "node:assert/strict";
import http from "node:http";
import type { AddressInfo } from "node:net";
import { test } from "node:test";
import { Api, sseEvents } from "../src/api";

const memory = () => {
  const m = new Map<string, string>();
  return { getItem: (k: string) => m.get(k) ?? null, setItem: (k: string, v: string) => void m.set(k, v) };
};

function streamOf(chunks: string[]): ReadableStream<Uint8Array> {
  const enc = new TextEncoder();
  return new ReadableStream({
    start(c) {
      for (const s of chunks) c.enqueue(enc.encode(s));
      c.close();
    },
  });
}

test("server-sent events: fields, comments, CRLF split across chunks, multi-line data", async () => {
  const got = [];
  for await (const e of sseEvents(streamOf([": hello\r", "\nevent: delta\r\nid: 4\r\ndata: {\"a\":", "1}\r", "\n\r\n", "data: x\ndata: y\n\n", "data: cut"]))) {
    got.push(e);
  }
  assert.deepEqual(got, [
    { event: "delta", id: "4", data: '{"a":1}' },
    { event: "message", id: "4", data: "x\ny" },
  ]);
});

test("watch joins snapshot parts, resumes after the last event and reconnects after a 503", async () => {
  const seen: (string | undefined)[] = [];
  const server = http.createServer((req, res) => {
    const n = seen.push(req.headers["last-event-id"] as string | undefined);
    assert.match(req.url!, /^\/v1\/sessions\/s1\/watch\?allowZstd=true&allowQuantized=true$/);
    if (req.headers.authorization !== "Bearer t0ken") {
      res.writeHead(401, { "content-type": "application/problem+json" }).end('{"status":401,"code":"UNAUTHENTICATED"}');
      return;
    }
    res.writeHead(200, { "content-type": "text/event-stream" });
    const send = (event: string, id: string, data: object) => res.write(`event: ${event}\nid: ${id}\ndata: ${JSON.stringify(data)}\n\n`);
    if (n === 2) {
      send("snapshot", "5", { seq: "5", planVersion: "2", snapshot: { models: [{ name: "a" }] } });
      send("snapshot", "5", { seq: "5", planVersion: "2", snapshot: { models: [{ name: "b" }], complete: true } });
      send("delta", "6", { seq: "6", planVersion: "3", delta: { removed: ["r1"] } });
      res.end(); // the connection drops
    } else if (n === 3) {
      res.end(`event: error\ndata: ${JSON.stringify({ status: 503, code: "UNAVAILABLE" })}\n\n`);
    } else send("volumes", "7", { seq: "7", planVersion: "3", volumes: { totalMl: 1 } });
  });
  await new Promise<void>((r) => server.listen(0, "127.0.0.1", r));
  const base = `http://127.0.0.1:${(server.address() as AddressInfo).port}`;
  let asked = 0;
  const api = new Api(async () => (asked++, "t0ken"), base, memory());
  const events: string[] = [];
  await new Promise<void>((done) => {
    const stream = api.watch("s1", {
      snapshot: (s) => events.push(`snapshot ${s.models!.map((m) => m.name).join(",")}`),
      delta: (d) => events.push(`delta ${d.removed}`),
      volumes: (v) => {
        events.push(`volumes ${v.totalMl}`);
        stream.close();
        done();
      },
      status: (s) => events.push(s),
    });
  });
  server.close();
  server.closeAllConnections();
  assert.equal(asked, 1);
  assert.deepEqual(seen, [undefined, undefined, "6", "6"]);
  assert.deepEqual(events, ["live", "snapshot a,b", "delta r1", "reconnecting", "live", "reconnecting", "live", "volumes 1"]);
});

test("resync drops the resume point: the next connection asks for a fresh snapshot", async () => {
  const seen: (string | undefined)[] = [];
  const server = http.createServer((req, res) => {
    seen.push(req.headers["last-event-id"] as string | undefined);
    res.writeHead(200, { "content-type": "text/event-stream" });
    res.write(`event: snapshot\nid: 9\ndata: ${JSON.stringify({ seq: "9", snapshot: { complete: true } })}\n\n`);
    res.write(`event: delta\nid: 10\ndata: ${JSON.stringify({ seq: "10", delta: {} })}\n\n`);
  });
  await new Promise<void>((r) => server.listen(0, "127.0.0.1", r));
  const base = `http://127.0.0.1:${(server.address() as AddressInfo).port}`;
  let snapshots = 0;
  await new Promise<void>((done) => {
    const stream = new Api(async () => null, base, memory()).watch("s1", {
      snapshot: () => {
        if (++snapshots === 2) {
          stream.close();
          done();
        }
      },
      delta: () => stream.resync(), // as after a delta that does not apply
      volumes: () => {},
      status: () => {},
    });
  });
  server.close();
  server.closeAllConnections();
  assert.deepEqual(seen, [undefined, undefined]);
});
