#!/usr/bin/env bash
# systemd-analyze verify on the unit file, with ExecStart pointed at the binary just
# built (verify checks that the executables exist). Fails on any warning about the unit.
set -euo pipefail
unit=$1
binary=$2
command -v systemd-analyze >/dev/null || { echo "systemd-analyze not found (package systemd)"; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
sed "s|/usr/bin/markcell|$binary|g" "$unit" > "$work/markcell.service"
out=$(systemd-analyze verify "$work/markcell.service" 2>&1) || { echo "$out"; exit 1; }
# Only the unit's own problems count; messages about other units on this machine do not.
if printf '%s\n' "$out" | grep -F "markcell.service" ; then
  echo "systemd-analyze verify reported problems with the unit (above)"
  exit 1
fi
echo "systemd-analyze verify: markcell.service OK"
# The hardening, as systemd rates it: the overall exposure must be SAFE or OK.
sec=$(systemd-analyze security --offline=true "$work/markcell.service" 2>&1) || { echo "$sec"; exit 1; }
overall=$(printf '%s\n' "$sec" | grep -F "Overall exposure level" || true)
echo "systemd-analyze security: $overall"
case "$overall" in
  *" SAFE "*|*" OK "*) ;;
  *) printf '%s\n' "$sec"; echo "systemd-analyze security rates the unit worse than OK"; exit 1 ;;
esac
