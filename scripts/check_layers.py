#!/usr/bin/env python3
"""Checks that crate dependencies point down the layers listed in ARCHITECTURE.md.

Layers, lowest first; a crate may depend only on crates in its own or a lower layer. The geometry
and io layers must not reach async runtimes, RPC/HTTP stacks or GPU APIs, even transitively.
"""
import json
import subprocess
import sys

LAYERS = {"geometry": 0, "io": 1, "compute": 2, "engine": 3, "edge": 4}
FORBIDDEN_BELOW_ENGINE = {"tokio", "tonic", "axum", "wgpu", "hyper", "prost"}


def main() -> int:
    meta = json.loads(subprocess.check_output(
        ["cargo", "metadata", "--format-version", "1", "--locked"], text=True))
    members = set(meta["workspace_members"])
    pkgs = {p["id"]: p for p in meta["packages"]}
    layer_of = {}
    for pid in members:
        path = pkgs[pid]["manifest_path"]
        parts = path.split("/server/crates/")
        if len(parts) != 2:
            print(f"crate {pkgs[pid]['name']} is not under server/crates/<layer>/")
            return 1
        layer = parts[1].split("/")[0]
        if layer not in LAYERS:
            print(f"crate {pkgs[pid]['name']} is in unknown layer folder {layer!r}")
            return 1
        layer_of[pid] = layer
    nodes = {n["id"]: n for n in meta["resolve"]["nodes"]}
    errors = []
    for pid, layer in layer_of.items():
        name = pkgs[pid]["name"]
        for dep in nodes[pid]["deps"]:
            kinds = {k["kind"] for k in dep["dep_kinds"]}
            if kinds == {"dev"}:
                continue
            if dep["pkg"] in layer_of and LAYERS[layer_of[dep["pkg"]]] > LAYERS[layer]:
                errors.append(f"{name} ({layer}) depends upward on {pkgs[dep['pkg']]['name']}"
                              f" ({layer_of[dep['pkg']]})")
        if LAYERS[layer] < LAYERS["compute"]:
            # Transitive normal dependencies.
            seen, stack = set(), [pid]
            while stack:
                cur = stack.pop()
                for dep in nodes[cur]["deps"]:
                    if any(k["kind"] in (None, "build") for k in dep["dep_kinds"]) and dep["pkg"] not in seen:
                        seen.add(dep["pkg"])
                        stack.append(dep["pkg"])
            bad = sorted({pkgs[d]["name"] for d in seen} & FORBIDDEN_BELOW_ENGINE)
            if bad:
                errors.append(f"{name} ({layer}) reaches {', '.join(bad)}")
    for e in errors:
        print("layering:", e)
    print(f"layering: {len(layer_of)} crates checked, {len(errors)} violations")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
