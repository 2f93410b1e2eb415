#!/usr/bin/env bash
# Runs every check and test of resecta on a fresh machine (installs what it needs first).
# Usage: bash scripts/test.sh
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
# A fresh clone gains nothing from incremental compilation but gigabytes of disk.
if [ -n "${CI:-}" ]; then export CARGO_INCREMENTAL=0; fi
step() { printf '\n== %s ==\n' "$*" >&2; }

step "system packages"
df -h . >&2 || true
# Mesa's lavapipe gives wgpu a CPU Vulkan device (with f64), so the GPU tests really run here;
# Mesa's EGL lets VTK render offscreen (the Slicer module's displayable-manager tests);
# Chromium runs the browser client's end-to-end tests (Playwright drives it, software WebGL).
need_apt=()
for p in mesa-vulkan-drivers libvulkan1 libegl1 libegl-mesa0 libgl1-mesa-dri chromium; do dpkg -s "$p" >/dev/null 2>&1 || need_apt+=("$p"); done
# PostgreSQL's server binaries for the PostgreSQL store's tests (scripts/pg_cluster.sh).
ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || command -v initdb >/dev/null || need_apt+=(postgresql)
if ((${#need_apt[@]})); then
  sudo_=""; [ "$(id -u)" = 0 ] || sudo_=sudo
  export DEBIAN_FRONTEND=noninteractive
  $sudo_ apt-get update -qq && $sudo_ apt-get install -y -qq --no-install-recommends "${need_apt[@]}"
fi
command -v cargo-nextest >/dev/null || cargo install --locked cargo-nextest

step "python venv"
if [ ! -x .venv/bin/python ]; then python3 -m venv .venv; fi
.venv/bin/python -m pip install -q --disable-pip-version-check -r tests/requirements.txt

step "browser client (web/): install, type check, unit tests, build; the embedded bundle is fresh"
command -v npm >/dev/null || { sudo_=""; [ "$(id -u)" = 0 ] || sudo_=sudo; $sudo_ apt-get install -y -qq nodejs npm; }
(cd web && npm ci --no-audit --no-fund --loglevel=error && npm run check && npm test && npm run build)
if ! git diff --quiet -- web/dist || [ -n "$(git ls-files --others --exclude-standard web/dist)" ]; then
  echo "web/dist differs from what web/ builds: run 'npm run build' in web/ and commit web/dist" >&2
  exit 1
fi

step "format, lints, layering"
cargo fmt --all -- --check
cargo clippy --workspace --all-targets --locked -- -D warnings
.venv/bin/python scripts/check_layers.py

step "throwaway PostgreSQL for the store's tests (scripts/pg_cluster.sh)"
pg_dir=$(mktemp -d "${TMPDIR:-/tmp}/resecta-pg.XXXXXX")
trap 'scripts/pg_cluster.sh stop "$pg_dir" || true' EXIT
# Exports RESECTA_TEST_PG (and RESECTA_TEST_PG_CA when openssl made the cluster a certificate).
eval "$(scripts/pg_cluster.sh start "$pg_dir")"

step "rust tests (nextest)"
export WGPU_BACKEND=vulkan
# One build: the test build also builds target/debug/resecta (resecta-cli's tests/cli.rs runs it),
# so the binary shares the tests' dependency features instead of compiling them a second time.
cargo nextest run --workspace --locked --profile ci
test -x target/debug/resecta

step "end-to-end tests, Python client, Slicer module Logic (pytest against target/debug/resecta)"
# One pytest run per suite: each folder has its own conftest.py.
for suite in tests clients/python/tests slicer-module/tests; do
  RESECTA_BIN="$root/target/debug/resecta" .venv/bin/python -m pytest -q "$suite"
done

step "end-to-end tests again with every server on the GPU path (--gpu required: lavapipe here)"
RESECTA_GPU=required RESECTA_BIN="$root/target/debug/resecta" .venv/bin/python -m pytest -q tests

step "end-to-end tests again with every server on PostgreSQL (a replica of the throwaway cluster)"
RESECTA_E2E_STORE="$RESECTA_TEST_PG" RESECTA_BIN="$root/target/debug/resecta" .venv/bin/python -m pytest -q tests
