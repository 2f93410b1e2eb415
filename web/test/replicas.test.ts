// A replicated server's 421 SESSION_ELSEWHERE: with the holder's http_url the page moves there
// (`onElsewhere`, once, with `<http_url>/#session=<id>`), without it the call is tried again;
// the watch stream treats a 421 the same way, as an answer or as its error event.

import assert from "node:assert/strict";
import http from "node:http";
import type { AddressInfo } from "node:net";
import { test } from "node:test";
import { Api, ApiError, elsewhereUrl, replicaPageUrl, sessionFromHash } from "../src/api";

const memory = () => {
  const m = new Map<string, string>();
  return { getItem: (k: string) => m.get(k) ?? null, setItem: (k: string, v: string) => void m.set(k, v) };
};

const REPLICA = { id: "b@1", grpc_address: "10.0.0.2:50051", http_url: "http://10.0.0.2:8080", lease_remaining_ms: 2500 };
const elsewhere = (replica?: object) =>
  JSON.stringify({ status: 421, code: "SESSION_ELSEWHERE", title: "Misdirected Request", detail: "held elsewhere", ...(replica ? { replica } : {}) });

async function serve(handler: http.RequestListener): Promise<{ base: string; close: () => void }> {
  const server = http.createServer(handler);
  await new Promise<void>((r) => server.listen(0, "127.0.0.1", r));
  return {
    base: `http://127.0.0.1:${(server.address() as AddressInfo).port}`,
    close: () => {
      server.close();
      server.closeAllConnections();
    },
  };
}

test("page URLs of a replica and the session fragment", () => {
  assert.equal(replicaPageUrl("http://10.0.0.2:8080/", "a b"), "http://10.0.0.2:8080/#session=a%20b");
  assert.equal(replicaPageUrl("http://10.0.0.2:8080", null), "http://10.0.0.2:8080/");
  assert.equal(sessionFromHash("#session=a%20b"), "a b");
  assert.equal(sessionFromHash("#x=1"), null);
  assert.equal(sessionFromHash(""), null);
});

test("a 421 naming the holder moves the page there once; without one the call is repeated", async () => {
  let gets = 0;
  const srv = await serve((req, res) => {
    const problem = { "content-type": "application/problem+json" };
    if (req.url === "/v1/sessions/s1") res.writeHead(421, problem).end(elsewhere(REPLICA));
    else if (req.url === "/v1/sessions/s2") {
      // moving: no replica named twice, then the answer
      if (++gets <= 2) res.writeHead(421, problem).end(elsewhere());
      else res.writeHead(200, { "content-type": "application/json" }).end('{"session":{"id":"s2","displayName":""}}');
    } else res.writeHead(404).end();
  });
  const api = new Api(async () => null, srv.base, memory());
  const moves: [string, string | undefined, string | null][] = [];
  api.onElsewhere = (url, replica, id) => moves.push([url, replica.id, id]);
  try {
    const err = await api.getSession("s1").then(() => null, (e: unknown) => e);
    assert.ok(err instanceof ApiError && err.status === 421);
    assert.equal(elsewhereUrl(err), "http://10.0.0.2:8080");
    assert.deepEqual(moves, [["http://10.0.0.2:8080/#session=s1", "b@1", "s1"]]);
    await api.getSession("s1").catch(() => undefined);
    assert.equal(moves.length, 1, "the page moves once");
    assert.equal((await api.getSession("s2")).session.id, "s2");
    assert.equal(gets, 3);
  } finally {
    srv.close();
  }
});

test("the watch stream moves on a 421 error event and asks again on one without a replica", async () => {
  let n = 0;
  const srv = await serve((req, res) => {
    n++;
    res.writeHead(200, { "content-type": "text/event-stream" });
    if (n === 1) {
      res.write(`event: snapshot\nid: 3\ndata: ${JSON.stringify({ seq: "3", planVersion: "2", snapshot: { complete: true } })}\n\n`);
      res.end(`event: error\ndata: ${elsewhere()}\n\n`); // moving: reconnect
    } else {
      assert.equal(req.headers["last-event-id"], "3");
      res.end(`event: error\ndata: ${elsewhere(REPLICA)}\n\n`); // held by B: move there
    }
  });
  const api = new Api(async () => null, srv.base, memory());
  const moves: string[] = [];
  api.onElsewhere = (url) => moves.push(url);
  const states: string[] = [];
  try {
    await new Promise<void>((done) => {
      api.watch("s1", {
        snapshot: () => states.push("snapshot"),
        delta: () => undefined,
        volumes: () => undefined,
        status: (s, e) => {
          states.push(e instanceof ApiError ? `${s} ${e.status}` : s);
          if (s === "failed") done();
        },
      });
    });
    assert.deepEqual(states, ["live", "snapshot", "reconnecting 421", "live", "failed 421"]);
    assert.deepEqual(moves, ["http://10.0.0.2:8080/#session=s1"]);
    assert.equal(n, 2);
  } finally {
    srv.close();
  }
});
