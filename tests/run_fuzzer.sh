#!/usr/bin/env bash
# Runs one libFuzzer target for a bounded time: run_fuzzer.sh BINARY SECONDS [SEED...]
# Seeds are copied into a fresh corpus; a crash, a sanitizer report or a time-out fails.
set -euo pipefail
binary=$1
seconds=$2
shift 2
if [ ! -x "$binary" ]; then
  echo "fuzz target $binary is not built: ./toolchain/run build fuzz (clang) builds it"
  exit 1
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/corpus"
for seed in "$@"; do cp "$seed" "$work/corpus/"; done
cd "$work"
"$binary" -max_total_time="$seconds" -error_exitcode=1 -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 corpus 2>&1 | tail -n 25
status=${PIPESTATUS[0]}
exit "$status"
