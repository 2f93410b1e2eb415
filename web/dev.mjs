// Development server: rebuilds dev-dist/ on every change and serves it, passing the API (/v1/…,
// /healthz) through to a running `resecta serve`, so the page is same-origin as in production.
//   node dev.mjs [--server http://127.0.0.1:8080] [--port 5173] [--dist]
import { context } from "esbuild";
import { createReadStream, existsSync } from "node:fs";
import { copyFile, mkdir } from "node:fs/promises";
import http from "node:http";
import { extname, join, normalize } from "node:path";

const arg = (name, fallback) => {
  const i = process.argv.indexOf(name);
  return i > 0 ? process.argv[i + 1] : fallback;
};
const server = new URL(arg("--server", "http://127.0.0.1:8080"));
const port = Number(arg("--port", "5173"));

// --dist: serve the committed release bundle as it is (benchmarks); else rebuild on every change
// into dev-dist/ (not dist/: that is the committed release bundle).
const release = process.argv.includes("--dist");
const out = release ? "dist" : "dev-dist";
if (!release) {
  await mkdir(out, { recursive: true });
  const ctx = await context({
    entryPoints: { app: "src/main.ts" }, outdir: out, bundle: true, format: "esm", platform: "browser",
    target: "es2022", sourcemap: "inline", logLevel: "info",
    plugins: [{ name: "html", setup: (b) => b.onEnd(() => copyFile("src/index.html", `${out}/index.html`)) }],
  });
  await ctx.watch();
}

const types = { ".html": "text/html", ".js": "text/javascript", ".css": "text/css" };
http
  .createServer((req, res) => {
    const path = new URL(req.url ?? "/", "http://x").pathname;
    if (path.startsWith("/v1/") || path === "/healthz") {
      const up = http.request(
        { host: server.hostname, port: server.port, path: req.url, method: req.method, headers: { ...req.headers, host: server.host } },
        (r) => {
          res.writeHead(r.statusCode ?? 502, r.headers);
          r.pipe(res);
        },
      );
      up.on("error", (e) => {
        res.writeHead(502, { "content-type": "text/plain" });
        res.end(`resecta server at ${server.href}: ${e.message}`);
      });
      req.pipe(up);
      res.on("close", () => up.destroy());
      return;
    }
    const file = join(out, normalize(path === "/" ? "index.html" : path).replace(/^(\.\.[/\\])+/, ""));
    if (!existsSync(file)) {
      res.writeHead(404).end();
      return;
    }
    res.writeHead(200, { "content-type": types[extname(file)] ?? "application/octet-stream", "cache-control": "no-store" });
    createReadStream(file).pipe(res);
  })
  .listen(port, "127.0.0.1", () => console.log(`http://127.0.0.1:${port}/ → API at ${server.href}`));
