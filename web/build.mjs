// Builds the bundle into dist/ (minified, no source maps, byte-for-byte reproducible), or with
// --tests the unit tests into test-dist/ for `node --test`.
import { build } from "esbuild";
import { copyFile, mkdir, readdir, rm } from "node:fs/promises";

const tests = process.argv.includes("--tests");
const common = { bundle: true, minify: !tests, sourcemap: false, legalComments: "none", logLevel: "warning" };

if (tests) {
  await rm("test-dist", { recursive: true, force: true });
  const entryPoints = (await readdir("test")).filter((f) => /\.test\.ts$/.test(f)).map((f) => `test/${f}`);
  await build({ ...common, entryPoints, outdir: "test-dist", outExtension: { ".js": ".mjs" },
    platform: "node", format: "esm", target: "node20" });
} else {
  await rm("dist", { recursive: true, force: true });
  await mkdir("dist");
  await build({ ...common, entryPoints: { app: "src/main.ts" }, outdir: "dist", platform: "browser",
    format: "esm", target: "es2022", charset: "utf8", loader: { ".glsl": "text" } });
  await copyFile("src/index.html", "dist/index.html");
}
