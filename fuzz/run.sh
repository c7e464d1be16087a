#!/usr/bin/env bash
# Runs every fuzz target for a bounded time on the stable toolchain and fails on a crash.
#
#   bash fuzz/run.sh SEEDS SECONDS [--beside DIR]
#
# SEEDS: a folder with one sub-folder of seed inputs per target (tests/it/fuzz_smoke.rs writes it
# when LAYERWISE_FUZZ_SEEDS is set); SECONDS: the time each target runs (0 skips the step).
# libFuzzer needs no nightly compiler: the coverage instrumentation is LLVM's sanitizer-coverage
# pass, asked for with the same flags cargo-fuzz passes (its AddressSanitizer option alone needs
# nightly, and is not used: Rust code is memory-safe, the bugs sought are panics, aborts, huge
# allocations and hangs).
#
# Two builds:
# - by default every crate is instrumented (coverage inside the decoders too), in fuzz/target's
#   release profile; `--target` keeps build scripts uninstrumented. For long runs.
# - `--beside DIR` (tests/run.sh): only layerwise and the targets are instrumented
#   (fuzz/instrument-ours.sh as RUSTC_WRAPPER), in DIR's test profile with the features
#   `cargo test --all-features` built, so the dependencies already built there are reused: the
#   instrumented build of every dependency took 8 to 10 minutes on 2 cores, too long for CI.
#
# Targets run side by side, one per core. A crashing input is kept in fuzz/artifacts/TARGET/ and
# becomes a regression test in tests/it/fuzz_smoke.rs.
set -euo pipefail
seeds=$(realpath "${1:?seed folder}")
seconds=${2:-25}
beside=
if [ "${3:-}" = --beside ]; then beside=$(realpath "${4:?--beside DIR}"); fi
cd "$(dirname "$0")"
if [ "$seconds" -le 0 ]; then
  echo "fuzz: skipped (0 s)"
  exit 0
fi
# The flags cargo-fuzz passes.
sancov="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing"
# --locked: fuzz/Cargo.lock must list what the project's Cargo.toml asks for (a stale one made
# every CI run resolve again against the crates.io index); any cargo command in fuzz/ without
# --locked (`cargo tree`, say) adds what is missing.
if [ -n "$beside" ]; then
  LAYERWISE_SANCOV_FLAGS="$sancov" RUSTC_WRAPPER="$PWD/instrument-ours.sh" \
    CARGO_TARGET_DIR="$beside" cargo build --locked --features beside-tests --bins
  bin="$beside/debug"
  stale="(cd fuzz && CARGO_TARGET_DIR=$beside cargo clean -p layerwise)"
else
  host=$(rustc -vV | sed -n 's/^host: //p')
  RUSTFLAGS="$sancov" cargo build --locked --release --target "$host" --bins
  bin="target/$host/release"
  stale="(cd fuzz && cargo clean -p layerwise)"
fi
# Each target's counters with layerwise instrumented: about 2,700 (vectors) to 30,500 (config);
# the targets' own code alone: 272 to 986.
min_counters=1500

# One target: SECONDS on its corpus; -rss_limit_mb: an allocation sized by a wild header (the
# malloc limit follows it) is a crash; -timeout: one input may take at most 10 s.
fuzz_one() {
  local t=$1
  mkdir -p "corpus/$t" "artifacts/$t"
  if [ -d "$seeds/$t" ]; then cp -n "$seeds/$t"/* "corpus/$t/" 2>/dev/null || true; fi
  local inputs
  inputs=$(find "corpus/$t" -type f | wc -l)
  if ! "$bin/$t" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -print_final_stats=1 \
      -artifact_prefix="artifacts/$t/" "corpus/$t" >"artifacts/$t.log" 2>&1; then
    echo "fuzz $t: CRASHED (${seconds} s on $inputs inputs)"
    tail -n 40 "artifacts/$t.log"
    return 1
  fi
  local counters
  counters=$(sed -n 's/^INFO: Loaded [0-9]* modules *(\([0-9]*\) inline 8-bit counters).*/\1/p' \
    "artifacts/$t.log" | head -n 1)
  if [ "${counters:-0}" -lt "$min_counters" ]; then
    echo "fuzz $t: only ${counters:-no} coverage counters (at least $min_counters expected):" \
      "layerwise was built without coverage instrumentation; run $stale and this again"
    return 1
  fi
  echo "fuzz $t: ${seconds} s on $inputs inputs, $counters counters," \
    "$(grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "artifacts/$t.log" | tr -s ' \n' ' ')"
}

targets=(vectors config calibration frames journal ct_volume web_request)
mkdir -p artifacts
jobs=$(nproc)
failed=()
for ((i = 0; i < ${#targets[@]}; i += jobs)); do
  batch=("${targets[@]:i:jobs}")
  pids=()
  for t in "${batch[@]}"; do
    fuzz_one "$t" >"artifacts/$t.summary" 2>&1 &
    pids+=($!)
  done
  for k in "${!batch[@]}"; do
    wait "${pids[$k]}" || failed+=("${batch[$k]}")
    cat "artifacts/${batch[$k]}.summary"
  done
done
if ((${#failed[@]})); then
  echo "fuzz targets that failed: ${failed[*]} (inputs in fuzz/artifacts/)" >&2
  exit 1
fi
