#!/bin/sh
# On the host, before the real-kernel replay: renders its recording with the optimised
# markcell (12 s of the paper's door at 5 frames a second) and scores it in simulated
# time, the figures the guest's real-time run is compared with.
#   tests/guest/replay_recording.sh MARKCELL OUT_DIR   (from the source tree's top)
set -eu
markcell=$1
out=$2
if [ ! -x "$markcell" ]; then
  echo "replay_recording: no optimised markcell at $markcell: ./toolchain/run build release builds it (./toolchain/run test does)" >&2
  exit 1
fi
# A newer markcell renders again; an unchanged one reuses the recording.
if [ -f "$out/report.json" ] && [ "$out/report.json" -nt "$markcell" ]; then
  echo "replay_recording: $out is newer than $markcell: kept"
  exit 0
fi
rm -rf "$out"
exec "$markcell" sim paper-door --seconds 12 --fps 5 --one-predictor -q --out "$out"
