#!/usr/bin/env bash
# The same seed and the same recording give the same bits on x86-64 and on arm64
# (docs/determinism.md): the host's markcell and the arm64 markcell under qemu-user
#   1. make the same 4 s scenario (render, inspection record, run, score): every file equal;
#   2. replay the host's recording: can.log, valve.log, poses.csv and report.json equal.
# report.json names its own folder: the one difference allowed, replaced before comparing.
#
#   cross_arch_replay.sh HOST_MARKCELL ARM64_MARKCELL SYSROOT OUT
set -euo pipefail
host=$1 arm=$2 sysroot=$3 out=$4
here=$(cd "$(dirname "$0")" && pwd)
top=$(cd "$here/.." && pwd)
[ -x "$host" ] || { echo "no host markcell at $host (./toolchain/run build release makes it)"; exit 1; }
[ -x "$arm" ] || { echo "no arm64 markcell at $arm"; exit 1; }
file -b "$arm" | grep -q "ARM aarch64" || { echo "$arm is not an arm64 executable: $(file -b "$arm")"; exit 1; }
emulated=(qemu-aarch64-static -L "$sysroot" "$arm")
rm -rf "$out"
mkdir -p "$out"
cd "$top"

# 4 s: long enough for the first ding to be marked (about 1 s per defect after the
# panel is found), short enough for qemu (the arm64 run renders its own frames).
scenario=(sim paper-door --seconds 4 --fps 10 --seed 3 --one-predictor -q)
"$host" "${scenario[@]}" --out "$out/sim-x86_64" >"$out/sim-x86_64.log" 2>&1
"${emulated[@]}" "${scenario[@]}" --out "$out/sim-arm64" >"$out/sim-arm64.log" 2>&1
rec=$out/sim-x86_64/recording
replay=(replay "$rec" --one-predictor -q --config config/cell.example.yaml)
"$host" "${replay[@]}" --out "$out/replay-x86_64" >"$out/replay-x86_64.log" 2>&1
"${emulated[@]}" "${replay[@]}" --out "$out/replay-arm64" >"$out/replay-arm64.log" 2>&1

differ=0
compare() {  # compare X86_FILE ARM64_FILE: byte for byte, but for the folder report.json names
  local a=$1 b=$2
  if [ ! -f "$b" ]; then echo "missing on arm64: $b"; differ=1; return; fi
  if [ "$(basename "$a")" = report.json ]; then
    local da db
    da=$(dirname "$a") db=$(dirname "$b")
    if ! diff <(cat "$a") <(sed "s|$db|$da|g" "$b") >"$out/diff.txt"; then
      echo "differ: $a $b"; head -20 "$out/diff.txt"; differ=1
    fi
  elif ! cmp -s "$a" "$b"; then
    echo "differ: $a $b ($(cmp "$a" "$b" 2>&1 | head -1))"; differ=1
  fi
}

n=0
while IFS= read -r -d '' f; do
  rel=${f#"$out/sim-x86_64/"}
  compare "$f" "$out/sim-arm64/$rel"
  n=$((n + 1))
done < <(find "$out/sim-x86_64" -type f -print0 | sort -z)
[ "$n" -gt 20 ] || { echo "only $n files in the scenario's folder"; differ=1; }
for name in recording/truth.csv recording/inspection.yaml can.log valve.log poses.csv report.json; do
  [ -s "$out/sim-x86_64/$name" ] || { echo "the scenario wrote no $name"; differ=1; }
done
for name in can.log valve.log poses.csv report.json; do
  [ -s "$out/replay-x86_64/$name" ] || { echo "the replay wrote no $name"; differ=1; }
  compare "$out/replay-x86_64/$name" "$out/replay-arm64/$name"
done
# Something was marked: equal logs of a run that did nothing would prove little.
grep -q '"marked": [1-9]' "$out/replay-x86_64/report.json" || { echo "the replay marked no ding"; differ=1; }
[ "$differ" = 0 ] || exit 1
echo "x86-64 and arm64: the scenario's $n files and the replay's can.log, valve.log, poses.csv, report.json are the same bytes"
