#!/usr/bin/env bash
# Issue #21's checks on a lent NVIDIA machine (the `device` tool), in one call.
#
#   bash scripts/gpu_device.sh prepare   # here: release binaries and the Vulkan loader packages
#   run(command="bash scripts/gpu_device.sh run", carry=[".gl", "target/gpu-bin"], timeout_s=570)
#
# `prepare` builds (release, stripped) the `resecta` binary, the resecta-gpu test binary and the
# volumetry bench into target/gpu-bin, and downloads the loader packages into .gl (both ignored
# through .git/info/exclude). `run` (on the device, as root) unpacks the loaders, then writes
# under $OUT: the device, the GPU tests against their CPU twins, `bench server --compare-gpu`
# (CPU baseline and GPU in one run, with the capacity ramp), `bench recon --backend both` at
# d = 7, 8, 9, and the volumetry bench. Figures go to docs/benchmarks.md with the card named.
set -uo pipefail
cd "$(dirname "$0")/.."
bin=target/gpu-bin

prepare() {
  set -e
  grep -qx '/.gl/' .git/info/exclude || echo /.gl/ >>.git/info/exclude
  cargo build --release -p resecta-cli
  local tests bench
  tests=$(cargo test --release -p resecta-gpu --lib --no-run --message-format=json 2>/dev/null |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])')
  bench=$(cargo bench -p resecta-gpu --bench volumetry --no-run --message-format=json 2>/dev/null |
    python3 -c 'import json,sys; print([m["executable"] for m in map(json.loads, sys.stdin) if m.get("executable")][-1])')
  mkdir -p "$bin"
  cp target/release/resecta "$bin/resecta"
  cp "$tests" "$bin/gpu-tests"
  cp "$bench" "$bin/volumetry-bench"
  strip "$bin"/*
  mkdir -p .gl /tmp/amd64/partial
  local o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
  # shellcheck disable=SC2086
  apt-get $o update -qq && (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0)
  du -sh "$bin" .gl
}

run() {
  local out=${OUT:-/tmp/gpu-device}
  mkdir -p "$out"
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
  if [ -f /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ]; then
    export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  fi
  export WGPU_BACKEND=vulkan RUST_LOG=warn
  { nvidia-smi -L; nproc; } >"$out/device.txt" 2>&1
  timeout 120 "$bin/gpu-tests" --test-threads 4 >"$out/gpu-tests.txt" 2>&1
  echo "gpu tests rc=$?" >>"$out/device.txt"
  timeout 200 "$bin/resecta" bench server --compare-gpu --json --seconds 3 --max-sessions 512 \
    >"$out/compare.json" 2>"$out/compare.err"
  echo "compare rc=$?" >>"$out/device.txt"
  timeout 150 "$bin/resecta" bench recon --backend both --depths 7,8,9 --json \
    >"$out/recon.json" 2>"$out/recon.err"
  echo "recon rc=$?" >>"$out/device.txt"
  timeout 60 "$bin/volumetry-bench" --bench >"$out/volumetry.txt" 2>&1
  echo "volumetry rc=$?" >>"$out/device.txt"
  cat "$out/device.txt"
}

case "${1:-}" in
  prepare) prepare ;;
  run) run ;;
  *) echo "usage: $0 prepare|run" >&2; exit 2 ;;
esac
