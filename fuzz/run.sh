#!/usr/bin/env bash
# Runs every fuzz target for a bounded time on the stable toolchain and fails on a crash.
#
#   bash fuzz/run.sh SEEDS SECONDS
#
# SEEDS: a folder with one sub-folder of seed inputs per target (tests/fuzz_smoke.rs writes it
# when LAYERWISE_FUZZ_SEEDS is set); SECONDS: the time each target runs. libFuzzer needs no
# nightly compiler: the coverage instrumentation is LLVM's sanitizer-coverage pass, asked for
# with the same flags cargo-fuzz passes (its AddressSanitizer option alone needs nightly, and is
# not used: Rust code is memory-safe, the bugs sought are panics, aborts, huge allocations and
# hangs). SECONDS=0 skips the step (the instrumented build takes minutes). `--target` keeps
# build scripts uninstrumented. A crashing input is kept in fuzz/artifacts/TARGET/ and becomes a
# regression test in tests/fuzz_smoke.rs.
set -euo pipefail
seeds=$(realpath "${1:?seed folder}")
cd "$(dirname "$0")"
seconds=${2:-25}
if [ "$seconds" -le 0 ]; then
  echo "fuzz: skipped (0 s)"
  exit 0
fi
host=$(rustc -vV | sed -n 's/^host: //p')
export RUSTFLAGS="-Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4 \
-Cllvm-args=-sanitizer-coverage-inline-8bit-counters -Cllvm-args=-sanitizer-coverage-pc-table \
-Cllvm-args=-sanitizer-coverage-trace-compares --cfg fuzzing"
cargo build --release --target "$host" --bins
targets=(vectors config calibration frames journal ct_volume)
failed=()
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t" "artifacts/$t"
  if [ -d "$seeds/$t" ]; then cp -n "$seeds/$t"/* "corpus/$t/" 2>/dev/null || true; fi
  echo "fuzz $t: ${seconds} s on $(find "corpus/$t" -type f | wc -l) inputs"
  # -rss_limit_mb: an allocation sized by a wild header (the malloc limit follows it) is a
  # crash; -timeout: one input may take at most 10 s.
  if ! "target/$host/release/$t" -max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 \
      -print_final_stats=1 -artifact_prefix="artifacts/$t/" "corpus/$t" >"artifacts/$t.log" 2>&1; then
    tail -n 40 "artifacts/$t.log"
    failed+=("$t")
  else
    grep -E "stat::number_of_executed_units|stat::peak_rss_mb" "artifacts/$t.log" | tr '\n' ' '
    echo
  fi
done
if ((${#failed[@]})); then
  echo "fuzz targets that crashed: ${failed[*]} (inputs in fuzz/artifacts/)" >&2
  exit 1
fi
