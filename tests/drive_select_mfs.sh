#!/usr/bin/env bash
# Drives `markcell select-mfs`'s window under a virtual X server (Xvfb) with xdotool, as
# an installation engineer would with the mouse and keyboard.
#
#   drive_select_mfs.sh MARKCELL IMAGE PANEL OUT LOG ACTION...
#
# ACTION: click:X,Y | drag:X,Y,X2,Y2 | key:NAME (image pixels; the window shows the image
# at its top-left corner). After each action the script waits (10 s at most) for the
# window's log to grow by a line, so no action races the GUI. Prints "exit=N" with
# markcell's exit status, then its log.
set -euo pipefail
markcell=$1 image=$2 panel=$3 out=$4 log=$5
shift 5
work=$(mktemp -d)
# The GUI toolkit's own libraries (Qt, D-Bus, fontconfig) keep allocations to the end of
# the process; LeakSanitizer is told to skip those, and only those.
export LSAN_OPTIONS="suppressions=$(cd "$(dirname "$0")" && pwd)/gui.lsan.supp${LSAN_OPTIONS:+:$LSAN_OPTIONS}"
xvfb_pid= mc_pid=
cleanup() {
  [ -n "$mc_pid" ] && kill "$mc_pid" 2>/dev/null || true
  [ -n "$xvfb_pid" ] && kill "$xvfb_pid" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

Xvfb -displayfd 3 -screen 0 1024x768x24 -nolisten tcp 3>"$work/display" 2>"$work/xvfb.log" &
xvfb_pid=$!
for _ in $(seq 100); do [ -s "$work/display" ] && break; sleep 0.1; done
[ -s "$work/display" ] || { echo "Xvfb did not start:"; cat "$work/xvfb.log"; exit 1; }
export DISPLAY=":$(head -1 "$work/display")"

"$markcell" select-mfs --image "$image" --panel "$panel" --out "$out" >"$log" 2>&1 &
mc_pid=$!
wid=$(timeout 30 xdotool search --sync --onlyvisible --name "markcell select-mfs" | head -1)
[ -n "$wid" ] || { echo "no window"; cat "$log"; exit 1; }
for _ in $(seq 100); do grep -q "open" "$log" && break; sleep 0.1; done
xdotool windowmove --sync "$wid" 0 0 || true
xdotool windowfocus --sync "$wid" || true
sleep 0.5  # the first frame drawn

wait_for_line() {  # the log grows past $1 lines
  for _ in $(seq 200); do
    [ "$(wc -l <"$log")" -gt "$1" ] && return 0
    sleep 0.05
  done
  echo "no answer from the window to: $2"
  return 1
}
for action in "$@"; do
  lines=$(wc -l <"$log")
  kind=${action%%:*} args=${action#*:}
  IFS=, read -r a b c d <<<"$args"
  case "$kind" in
    click) xdotool mousemove --window "$wid" --sync "$a" "$b" click 1 ;;
    drag) xdotool mousemove --window "$wid" --sync "$a" "$b" mousedown 1 sleep 0.2 \
            mousemove --window "$wid" --sync $(((a + c) / 2)) $(((b + d) / 2)) sleep 0.2 \
            mousemove --window "$wid" --sync "$c" "$d" sleep 0.2 mouseup 1 ;;
    key) xdotool key --clearmodifiers "$args" ;;
    *) echo "unknown action $action"; exit 2 ;;
  esac
  wait_for_line "$lines" "$action"
done
status=0
for _ in $(seq 200); do kill -0 "$mc_pid" 2>/dev/null || break; sleep 0.05; done
if kill -0 "$mc_pid" 2>/dev/null; then echo "markcell still running 10 s after the last action"; kill "$mc_pid"; fi
wait "$mc_pid" || status=$?
mc_pid=
echo "exit=$status"
cat "$log"
