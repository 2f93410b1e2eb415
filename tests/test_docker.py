"""Keeps docker/ correct without a Docker engine: the files must agree with the repository and
with what `resecta serve` accepts."""

import json
import re
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import resecta_bin

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
DOCKERFILES = ["Dockerfile", "Dockerfile.gpu"]


def instructions(path):
    """(instruction, argument) pairs of a Dockerfile, continuation lines joined."""
    text = re.sub(r"\\\n", " ", path.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), rest.strip()))
    return out


@pytest.fixture(scope="module")
def serve_help():
    done = subprocess.run([resecta_bin(), "serve", "--help"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def metadata():
    done = subprocess.run(
        ["cargo", "metadata", "--format-version", "1", "--no-deps", "--offline"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


@pytest.mark.parametrize("name", DOCKERFILES)
def test_copy_sources_exist(name):
    for word, arg in instructions(DOCKER / name):
        if word == "COPY" and not arg.startswith("--from"):
            *sources, _dest = arg.split()
            for s in sources:
                assert (ROOT / s).exists(), f"{name}: COPY source {s} does not exist"


@pytest.mark.parametrize("name", DOCKERFILES)
def test_builder_copies_everything_the_build_reads(name):
    copied = {
        arg.split()[0].rstrip("/")
        for word, arg in instructions(DOCKER / name)
        if word == "COPY" and not arg.startswith("--from")
    }
    # Workspace members and the protos the API crate compiles.
    assert {"server", "proto", ".cargo"} <= copied, f"{name} copies only {sorted(copied)}"
    for build_rs in (ROOT / "server").rglob("build.rs"):
        for rel in re.findall(r'"((?:\.\./)+[^"]+)"', build_rs.read_text()):
            target = (build_rs.parent / rel).resolve().relative_to(ROOT)
            assert target.parts[0] in copied, f"{build_rs} reads {target}, not copied by {name}"


@pytest.mark.parametrize("name", DOCKERFILES)
def test_build_names_existing_package_and_binary(name, metadata):
    runs = " ".join(arg for word, arg in instructions(DOCKER / name) if word == "RUN")
    package = re.search(r"-p (\S+)", runs).group(1)
    binary = re.search(r"--bin (\S+)", runs).group(1)
    pkg = next((p for p in metadata["packages"] if p["name"] == package), None)
    assert pkg is not None, f"{name} builds unknown package {package}"
    bins = [t["name"] for t in pkg["targets"] if "bin" in t["kind"]]
    assert binary in bins, f"{name} builds binary {binary}; {package} has {bins}"


@pytest.mark.parametrize("name", DOCKERFILES)
def test_rust_image_matches_toolchain(name):
    rust_version = re.search(r'rust-version = "([\d.]+)"', (ROOT / "Cargo.toml").read_text())[1]
    froms = [arg for word, arg in instructions(DOCKER / name) if word == "FROM"]
    assert froms[0].startswith(f"rust:{rust_version}"), f"{name}: {froms[0]} vs rust-version {rust_version}"


@pytest.mark.parametrize("name", DOCKERFILES)
def test_environment_and_ports_match_serve(name, serve_help):
    env = {}
    exposed = set()
    for word, arg in instructions(DOCKER / name):
        if word == "ENV":
            env.update(dict(re.findall(r"(\w+)=(\S+)", arg)))
        if word == "EXPOSE":
            exposed |= {int(p) for p in arg.split()}
    for key in (k for k in env if k.startswith("RESECTA_")):
        assert f"env: {key}=" in serve_help, f"{name} sets {key}, which `resecta serve` does not read"
    ports = {int(env[k].rsplit(":", 1)[1]) for k in ("RESECTA_GRPC", "RESECTA_HTTP")}
    assert ports == exposed, f"{name}: listens on {ports}, exposes {exposed}"
    entry = next(arg for word, arg in instructions(DOCKER / name) if word == "ENTRYPOINT")
    assert json.loads(entry) == ["resecta", "serve"]
    health = next(arg for word, arg in instructions(DOCKER / name) if word == "HEALTHCHECK")
    assert f"127.0.0.1:{env['RESECTA_HTTP'].rsplit(':', 1)[1]}/healthz" in health


def test_compose_is_consistent():
    compose = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    secrets = compose["secrets"]
    for name, svc in compose["services"].items():
        if "build" not in svc:  # postgres (profile replicas) runs its official image
            assert svc["image"].startswith("postgres:"), f"{name} has neither build nor postgres"
            continue
        build = svc["build"]
        context = (DOCKER / build["context"]).resolve()
        assert (context / build["dockerfile"]).is_file(), f"{name}: no {build['dockerfile']}"
        for mapping in svc["ports"]:
            host, container = mapping.split(":")
            assert host == container
        for s in svc.get("secrets", []):
            assert s in secrets, f"{name} uses undeclared secret {s}"
        assert "resecta_token" in svc["secrets"], f"{name} has no token"
        assert svc["environment"]["RESECTA_TOKEN_FILE"] == "/run/secrets/resecta_token"
    for s in secrets.values():
        secret = (DOCKER / s["file"]).resolve()
        ignored = subprocess.run(["git", "check-ignore", "-q", str(secret)], cwd=ROOT)
        assert ignored.returncode == 0, f"{secret} must be git-ignored (it holds the token)"
