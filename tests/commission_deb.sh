#!/usr/bin/env bash
# Commissions the amd64 .deb as a new user would on stock Debian 12 (docs/service.md
# "Commissioning"): lintian on it, then a real `dpkg -i` into a throwaway copy of this
# machine's own root (overlays over /usr, /etc and /var in a private mount namespace:
# every write lands in a tmpfs that goes with the namespace), the maintainer scripts
# run, and the installed cell used from / as the service user with the unit's settings.
#
#   commission_deb.sh BUILD    (root: the mount namespace, dpkg, the service user)
set -euo pipefail
build=$1
if [ "$(id -u)" -ne 0 ]; then
  echo "commission_deb.sh: needs root (a mount namespace, dpkg -i, the service user); skipped"
  exit 77
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$build" && cpack -G DEB -B "$work/out" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; exit 1; }
deb=$(ls "$work"/out/markcell_*_amd64.deb)
window_deb=$(ls "$work"/out/markcell-select-mfs_*_amd64.deb) || { ls "$work/out"; echo "no markcell-select-mfs package"; exit 1; }
ddeb=$(ls "$work"/out/markcell-dbgsym_*_amd64.ddeb) || { ls "$work/out"; echo "no -dbgsym package"; exit 1; }
for f in "$deb" "$window_deb" "$ddeb"; do echo "built $(basename "$f") ($(stat -c %s "$f") bytes)"; done

# 1. lintian, as Debian checks its own packages: no error and no warning (the package
# ships no overrides); the informational and pedantic tags printed for the record.
lintian --info --display-level '>=warning' "$deb" "$window_deb" >"$work/lintian" 2>&1 || true
echo "lintian:"; sed 's/^/  /' "$work/lintian"
if grep -Eq '^(E|W): ' "$work/lintian"; then
  echo "lintian reports errors or warnings (above)"
  exit 1
fi
lintian --display-level '>=pedantic' --show-overrides "$deb" "$window_deb" 2>/dev/null | sed 's/^/  below warning or overridden: /' || true

# The binary is stripped; its debug information is in the -dbgsym package, under the
# build id gdb looks it up by.
dpkg-deb -x "$deb" "$work/pkg"
dpkg-deb -x "$ddeb" "$work/dbg"
if readelf -S "$work/pkg/usr/bin/markcell" | grep -q '\.debug_info'; then
  echo "/usr/bin/markcell is not stripped"; exit 1
fi
build_id=$(readelf -n "$work/pkg/usr/bin/markcell" 2>/dev/null | awk '/Build ID/ { print $3 }')
debug_file="$work/dbg/usr/lib/debug/.build-id/${build_id:0:2}/${build_id:2}.debug"
[ -f "$debug_file" ] || { echo "no $debug_file in the -dbgsym package"; find "$work/dbg" -type f; exit 1; }
readelf -S "$debug_file" | grep -q '\.debug_info' || { echo "$debug_file holds no .debug_info"; exit 1; }
echo "binary: $(stat -c %s "$build/firmware_host/markcell") bytes in the build, $(stat -c %s "$work/pkg/usr/bin/markcell") stripped in the package"
# The cell's package pulls no GUI toolkit: highgui (and Qt through it) is the window's.
dpkg-deb -f "$deb" Depends | grep -q highgui && { echo "markcell depends on highgui: $(dpkg-deb -f "$deb" Depends)"; exit 1; }
dpkg-deb -f "$window_deb" Depends | grep -q 'libopencv-highgui' || { echo "markcell-select-mfs lacks highgui in Depends"; exit 1; }
echo "markcell-select-mfs Depends: $(dpkg-deb -f "$window_deb" Depends)"

# 2. Installed for real, in a namespace whose /usr, /etc and /var are overlays of this
# machine's with a tmpfs on top; /run/systemd and /run/udev hidden, so the maintainer
# scripts cannot reach this machine's systemd or udev.
cat >"$work/inside.sh" <<'INSIDE'
set -euo pipefail
work=$1 deb=$2 window_deb=$3
mount -t tmpfs -o mode=0755 tmpfs "$work/layer"
for d in usr etc var; do
  mkdir -p "$work/layer/$d/upper" "$work/layer/$d/work"
  mount -t overlay overlay -o "lowerdir=/$d,upperdir=$work/layer/$d/upper,workdir=$work/layer/$d/work" "/$d"
done
for d in /run/systemd /run/udev; do [ -d "$d" ] && mount -t tmpfs tmpfs "$d"; done
if dpkg-query -W markcell >/dev/null 2>&1; then echo "markcell is already installed on this machine"; exit 1; fi

dpkg -i "$deb" "$window_deb"
check() { if ! "$@"; then echo "FAILED: $*"; exit 1; fi; }
# The groups and the user the unit names exist; the state folder is the user's alone.
check getent group gpio
for g in gpio dialout video; do check sh -c "id -nG markcell | tr ' ' '\n' | grep -qx $g"; done
check test "$(stat -c '%U:%G %a' /var/lib/markcell)" = "markcell:markcell 750"
check test "$(stat -c '%U:%G %a' /var/lib/markcell/records)" = "markcell:markcell 750"
# The calibrations: state seeded from the package, the service user's.
check test "$(stat -c '%U:%G %a' /var/lib/markcell/calibration)" = "markcell:markcell 750"
for f in marking_stereo.yaml base.yaml inspection_stereo.yaml; do
  check test "$(stat -c '%U:%G %a' /var/lib/markcell/calibration/$f)" = "markcell:markcell 640"
  check cmp -s /usr/share/markcell/calibration/$f /var/lib/markcell/calibration/$f
done
check test -f /usr/lib/udev/rules.d/60-markcell-gpio.rules
check grep -q '^  results_file: /var/lib/markcell/results.jsonl' /etc/markcell/cell.yaml
check test -f /usr/share/man/man1/markcell.1.gz
check test -f /usr/share/man/man1/markcell-select-mfs.1.gz

# The defaults resolve against /etc/markcell whatever the working directory.
cd /
markcell --version
check markcell capacity >/dev/null
unit=/usr/lib/systemd/system/markcell.service
value() { sed -n "s/^$1=//p" "$unit" | tr '\n' ' ' | sed 's/ $//'; }
user=$(value User) group=$(value Group) groups=$(value SupplementaryGroups | tr ' ' ',')
caps=$(value AmbientCapabilities | tr 'A-Z' 'a-z' | sed 's/cap_/+/g; s/ /,/g')
# The unit's resource limits need CAP_SYS_RESOURCE to raise; a root without it (some
# virtual machines and containers) runs without them: the lanes' SCHED_FIFO and mlockall
# rest on the unit's CAP_SYS_NICE and CAP_IPC_LOCK, which bypass those limits anyway.
limits=(prlimit --rtprio="$(value LimitRTPRIO)" --memlock=unlimited)
if ! "${limits[@]}" true 2>/dev/null; then
  echo "this root cannot raise resource limits (no CAP_SYS_RESOURCE): LimitRTPRIO and LimitMEMLOCK not applied"
  limits=()
fi
as_service() {  # the unit's user, groups, capabilities, limits and umask; in a subshell (it execs)
  umask "$(value UMask)"
  exec ${limits[@]+"${limits[@]}"} \
    setpriv --reuid="$user" --regid="$group" --groups="$groups" \
      --inh-caps="$caps" --ambient-caps="$caps" --bounding-set="$caps" -- "$@"
}
# ExecStartPre and ExecStart as the unit has them; the run for 3 s (the unit runs it until
# SIGTERM: stopped as systemd stops it).
pre=$(value ExecStartPre) start=$(value ExecStart)
if ! (as_service $pre); then echo "FAILED: ExecStartPre $pre"; exit 1; fi
set +e
as_service $start >"$work/run.log" 2>&1 &  # the background subshell execs: $! is markcell
pid=$!
sleep 3
kill -TERM "$pid"
wait "$pid"
rc=$?
set -e
cat "$work/run.log"
check test "$rc" -eq 0
check grep -q 'running on the real clock' "$work/run.log"
# Nothing the service user could not write: the run made its results file's folder's
# files as markcell or nothing at all.
if [ -e /var/lib/markcell/results.jsonl ]; then check test "$(stat -c %U /var/lib/markcell/results.jsonl)" = markcell; fi

# The results file rotated by the package's logrotate snippet, by the real logrotate (as
# its daily timer would, forced): the file moved aside, a new one made for the user.
(as_service sh -c 'printf "{\"cell\": \"rotation test\"}\n" >> /var/lib/markcell/results.jsonl')
logrotate -f -s "$work/logrotate.state" /etc/logrotate.d/markcell
check grep -q "rotation test" /var/lib/markcell/results.jsonl.1
check test "$(stat -c '%U:%G %a' /var/lib/markcell/results.jsonl)" = "markcell:markcell 640"
check test ! -s /var/lib/markcell/results.jsonl

# The commissioning checklist's last step on this root, with the rig standing in for the
# line: a recording and its inspection record made by the installed `markcell sim`, the
# installed cell.yaml pointed at the recording as its cameras (as an integrator edits
# it), the record dropped into the record folder, and `run` as the unit runs it with a
# PLC script: the panel marked, its result in the results file.
(as_service markcell sim paper-door --seconds 3 --fps 10 --one-predictor -q --out /var/lib/markcell/commissioning) >/dev/null
sed -i 's|^    source: simulated |    source: recording |; s|^    # recording: /path/to/recording|    recording: /var/lib/markcell/commissioning/recording|' \
  /etc/markcell/cell.yaml
check grep -q '^    recording: /var/lib/markcell/commissioning/recording' /etc/markcell/cell.yaml
(as_service cp /var/lib/markcell/commissioning/recording/inspection.yaml /var/lib/markcell/records/0001.yaml)
printf '0.0 plc_panel_present 1\n3.2 plc_panel_present 0\n' >"$work/plc.txt"
chmod 0644 "$work/plc.txt"
chmod 0755 "$work"
(as_service markcell run --config /etc/markcell/cell.yaml --clock sim --seconds 6 --plc-script "$work/plc.txt") >"$work/marked.log" 2>&1 ||
  { cat "$work/marked.log"; echo "FAILED: run with the recording"; exit 1; }
check grep -q '<6>markcell: panel=paper-door-1 result=done sprayed=3 skipped=0' "$work/marked.log"
check grep -q '"panel":1,"panel_id":"paper-door-1","started_s"' /var/lib/markcell/results.jsonl
check test -f /var/lib/markcell/records/accepted/0001.yaml
grep 'result=' "$work/marked.log"

# A calibration replaced as the service user (calibrate-base on the simulated arm): the
# seed kept in history/, both listed by `markcell calibrations`, named by check-config.
check test "$( (as_service markcell calibrate-base --out /var/lib/markcell/calibration/base.yaml) | tail -1)" = \
  "wrote /var/lib/markcell/calibration/base.yaml"
kept=$(ls /var/lib/markcell/calibration/history/base.*.yaml)
check cmp -s "$kept" /usr/share/markcell/calibration/base.yaml
check test "$(stat -c %U /var/lib/markcell/calibration/base.yaml)" = markcell
markcell calibrations >"$work/calibrations.log"
cat "$work/calibrations.log"
check grep -q "^base: /var/lib/markcell/calibration/base.yaml (in use)" "$work/calibrations.log"
check grep -q "calibrate-base), RMS" "$work/calibrations.log"
check grep -q "1 earlier version(s) in /var/lib/markcell/calibration/history" "$work/calibrations.log"
check sh -c "markcell check-config /etc/markcell/cell.yaml | grep -q '^base calibration /var/lib/markcell/calibration/base.yaml: calibrated '"
# A reinstall (the postinst again) leaves the cell's calibration alone.
dpkg -i "$deb" >/dev/null
check sh -c "! cmp -s /usr/share/markcell/calibration/base.yaml /var/lib/markcell/calibration/base.yaml"

# select-mfs without --mf runs the window's program (here without a display: it says so);
# with that package removed, markcell says what is missing.
markcell select-mfs --from-scenario paper-door --image "$work/door.png" --out "$work/door.yaml" >/dev/null
set +e
env -u DISPLAY markcell select-mfs --image "$work/door.png" --panel door --out "$work/window.yaml" >"$work/window.log" 2>&1
rc=$?
set -e
check test "$rc" -eq 1
check grep -q 'no display to open the window on' "$work/window.log"
dpkg -r markcell-select-mfs >/dev/null
set +e
markcell select-mfs --image "$work/door.png" --panel door --out "$work/window.yaml" >"$work/window.log" 2>&1
rc=$?
set -e
check test "$rc" -eq 1
check grep -q 'the window is the program /usr/bin/markcell-select-mfs, which is not installed' "$work/window.log"

# Removed and purged: the state (results, records, calibrations and their history) stays,
# the configuration goes with the purge.
dpkg -r markcell >/dev/null
check test -f /etc/markcell/cell.yaml
dpkg -P markcell >/dev/null
check test ! -e /etc/markcell/cell.yaml
check test -d /var/lib/markcell
check test -f /var/lib/markcell/calibration/base.yaml
check test -f "$kept"
echo "commissioned: dpkg -i, the user, groups and state folder, check-config and a run as the unit runs them, a panel marked, remove and purge"
INSIDE
mkdir -p "$work/layer"
unshare --mount --propagation private bash "$work/inside.sh" "$work" "$deb" "$window_deb"
