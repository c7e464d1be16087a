#!/usr/bin/env bash
# The test command (README, and .ci/run runs exactly this): installs what the tests need, then
# checks formatting and lints and runs every test of the workspace with every feature.
set -euo pipefail
cd "$(dirname "$0")/.."

# System packages: libgphoto2 for the real camera backend (bindgen needs libclang), socat for the
# serial-trigger pty tests, systemd for `systemd-analyze verify`, dicom3tools and dcmtk to validate
# the DICOM we write, cmake and g++ to build CharLS (JPEG-LS), python3-venv for the test venv;
# orthanc, orthanc-dicomweb and iproute2: the real PACS tests/it/pacs.rs pushes to (STOW-RS,
# C-STORE); chromium and chromium-driver for the browser test of the operator page
# (tests/it/web.rs); mosquitto and mosquitto-clients, the broker and the counting subscriber of
# the MQTT tests (tests/it/plant_mqtt.rs); prometheus (and promtool), which scrapes /metrics in
# tests/it/plant_metrics.rs, installed without its recommends (prometheus-node-exporter);
# libjpeg-turbo-progs, whose cjpeg writes the progressive JPEGs tests/it/bounded_inputs.rs decodes.
packages=(libgphoto2-dev libclang-dev pkg-config socat systemd dicom3tools dcmtk cmake g++ python3-venv orthanc orthanc-dicomweb iproute2 chromium chromium-driver mosquitto mosquitto-clients libjpeg-turbo-progs)
lean_packages=(prometheus)
missing=()
lean_missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
for p in "${lean_packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || lean_missing+=("$p")
done
if ((${#missing[@]} + ${#lean_missing[@]})); then
  echo "installing: ${missing[*]} ${lean_missing[*]}"
  sudo_cmd=()
  [ "$(id -u)" -eq 0 ] || sudo_cmd=(sudo)
  "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -qq
  # Debian's orthanc package would start a service listening on every interface: while these
  # packages install, policy-rc.d (exit 101) keeps invoke-rc.d from starting any service. The tests
  # run their own Orthanc in a private network namespace.
  policy=/usr/sbin/policy-rc.d
  added_policy=
  if [ ! -e "$policy" ]; then
    printf '#!/bin/sh\nexit 101\n' | "${sudo_cmd[@]}" tee "$policy" >/dev/null
    "${sudo_cmd[@]}" chmod 755 "$policy"
    added_policy=1
  fi
  status=0
  if ((${#missing[@]})); then
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null || status=$?
  fi
  if ((${#lean_missing[@]})) && [ "$status" -eq 0 ]; then
    "${sudo_cmd[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${lean_missing[@]}" >/dev/null || status=$?
  fi
  if [ -n "$added_policy" ]; then "${sudo_cmd[@]}" rm -f "$policy"; fi
  [ "$status" -eq 0 ] || exit "$status"
fi

# A Python venv with: the PyPI gphoto2 wheel (it bundles libgphoto2 with the vusb virtual PTP
# camera, which tests/it/virtual_camera.rs drives through our real libgphoto2 backend); pydicom
# (with a JPEG-LS decoder) and SimpleITK, which tests/dicom_check.py uses to read our DICOM back;
# asyncua, the OPC UA client tests/opcua_client.py drives our OPC UA server with; Pillow, one
# of the writers of the progressive JPEGs tests/it/bounded_inputs.rs decodes.
venv=target/test-venv
if ! "$venv/bin/python" -c "import gphoto2, pydicom, SimpleITK, numpy, pylibjpeg, asyncua, PIL" 2>/dev/null; then
  python3 -m venv "$venv"
  "$venv/bin/pip" install -q --disable-pip-version-check "gphoto2>=2.5,<3" pydicom SimpleITK numpy pylibjpeg pylibjpeg-libjpeg asyncua pillow
fi
LAYERWISE_VCAM_LIBDIR="$("$venv/bin/python" -c 'import gphoto2, os; print(os.path.join(os.path.dirname(gphoto2.__file__), "libgphoto2"))')"
export LAYERWISE_VCAM_LIBDIR

# A one-off build (CI) gains nothing from incremental artifacts, which take gigabytes.
if [ -n "${CI:-}" ]; then export CARGO_INCREMENTAL=0; fi

cargo fmt --all -- --check
# Clippy's lints with warnings denied (what `cargo clippy --workspace --all-targets --all-features
# -- -D warnings` reports) are checked while the tests build: clippy-driver, the compiler `cargo
# clippy` runs, compiles the workspace's own crates (RUSTC_WORKSPACE_WRAPPER; the dependencies are
# compiled by rustc as before) and lints them as it compiles; CLIPPY_ARGS is how `cargo clippy`
# hands it `-D warnings`. The test build compiles every target `--all-targets` checks (lib and
# its tests, bins, integration tests, examples; the benches in the last step, with the same
# wrapper so that nothing compiles again). A separate `cargo clippy` checked every dependency
# once more: 6 min 40 s on 2 cores, against about 30 s that the lints add to the build.
clippy_driver=$(rustup which clippy-driver 2>/dev/null || command -v clippy-driver)
lint=(env RUSTC_WORKSPACE_WRAPPER="$clippy_driver" CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__")
# Coverage-guided fuzzing (fuzz/: libFuzzer on the stable toolchain, see fuzz/run.sh): the tests
# write the seeds (tests/it/fuzz_smoke.rs, which also feeds every parser deterministic mutants),
# then every target runs LAYERWISE_FUZZ_SECONDS (20; 0 skips it) on them; a crash, an abort, an
# allocation over 2 GB or an input taking over 10 s fails. Built beside the tests, on the
# dependencies built for them: layerwise and the targets are compiled again, instrumented.
fuzz_seconds="${LAYERWISE_FUZZ_SECONDS:-20}"
if [ "$fuzz_seconds" != 0 ]; then export LAYERWISE_FUZZ_SEEDS="$PWD/target/fuzz-seeds"; fi
"${lint[@]}" cargo test --workspace --all-features
bash fuzz/run.sh target/fuzz-seeds "$fuzz_seconds" --beside target
# The binary built without optional features (`--no-default-features`), through the path a user
# takes: a NEF is refused with the feature to build, and check-config refuses a gphoto2 camera
# it cannot drive (issue 13). Only layerwise and the crates whose features differ without rawler,
# the OPC UA stack and CharLS compile again (about 45, and everything above them); the test
# binary leaves out its modules that need testkit, nef or gphoto, and runs the four refusals.
# Those run in a fraction of a second, so what compiles again compiles unoptimised:
# tests/no_default_rebuilds.py names it (cargo tree, with and without the features). At the test
# profile's opt-levels the step took 3 min 4 s on 2 cores, 2 min 20 s of it the dependencies.
mapfile -t unoptimised < <(python3 tests/no_default_rebuilds.py)
cargo test --no-default-features "${unoptimised[@]}" --test it -- without_the_feature
# Benchmarks are run by hand (cargo bench); here they only have to build, in the test profile
# whose dependencies are built above (a release build of every dependency would add ~8 minutes).
"${lint[@]}" cargo test --workspace --all-features --benches --no-run
