#!/usr/bin/env bash
# The test command (README, and .ci/run runs exactly this): installs what the tests need, then
# checks formatting and lints and runs every test of the workspace with every feature.
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages: libgphoto2 for the real camera backend (bindgen needs libclang), socat for the
# serial-trigger pty tests, systemd for `systemd-analyze verify`.
packages=(libgphoto2-dev libclang-dev pkg-config socat systemd)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
fi

cargo fmt --all -- --check
cargo clippy --workspace --all-targets --all-features -- -D warnings
cargo test --workspace --all-features
# Benchmarks are run by hand (cargo bench); here they only have to build.
cargo bench --workspace --all-features --no-run
