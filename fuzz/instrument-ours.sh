#!/usr/bin/env bash
# RUSTC_WRAPPER of `fuzz/run.sh --beside DIR`: LLVM's sanitizer-coverage instrumentation (run.sh's
# LAYERWISE_SANCOV_FLAGS) for layerwise and the fuzz targets only; every other crate compiles as
# cargo asked, so the dependencies the tests already built in DIR are reused, not built again.
# Cargo does not see these flags, so layerwise's artifact here must never be one a test build
# also uses: it is not (cargo names a path package by its path from the workspace root, and fuzz/
# is a workspace of its own), and run.sh checks the coverage counters libFuzzer loads.
rustc=$1
shift
crate=
prev=
for arg in "$@"; do
  if [ "$prev" = --crate-name ]; then
    crate=$arg
    break
  fi
  prev=$arg
done
case "$crate" in
  layerwise | layerwise_fuzz | vectors | config | calibration | frames | journal | ct_volume | web_request)
    read -ra sancov <<<"${LAYERWISE_SANCOV_FLAGS:?set by fuzz/run.sh}"
    exec "$rustc" "$@" "${sancov[@]}"
    ;;
esac
exec "$rustc" "$@"
