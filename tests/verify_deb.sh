#!/usr/bin/env bash
# Builds the .deb from a build folder (cpack), checks its file list, its conffiles and
# maintainer scripts, and runs the unit inside it through verify_service_unit.sh (with
# the packaged binary).
#
#   verify_deb.sh BUILD ARCH [EMULATOR...]   ARCH: the package's (amd64, arm64); the
#                                            packaged binary runs under EMULATOR when given
set -euo pipefail
build=$1 arch=$2
shift 2
emulator=("$@")
here=$(cd "$(dirname "$0")" && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
(cd "$build" && cpack -G DEB -B "$work/out" >"$work/cpack.log" 2>&1) || { cat "$work/cpack.log"; exit 1; }
deb=$(ls "$work"/out/markcell_*_"$arch".deb) || { ls "$work"/out; echo "no markcell_*_$arch.deb"; exit 1; }
window_deb=$(ls "$work"/out/markcell-select-mfs_*_"$arch".deb) || { ls "$work"/out; echo "no markcell-select-mfs_*_$arch.deb"; exit 1; }
echo "built $(basename "$deb") and $(basename "$window_deb")"
dpkg-deb -c "$deb" | awk '{print $6}' | sed 's|^\./|/|' > "$work/files"
fail=0
for f in /usr/bin/markcell /usr/lib/systemd/system/markcell.service /etc/markcell/cell.yaml \
         /usr/share/markcell/calibration/marking_stereo.yaml /usr/share/markcell/calibration/base.yaml \
         /etc/markcell/panels/door.yaml /etc/markcell/scenarios/paper-door.yaml /usr/share/markcell/markcell_arm.dbc \
         /usr/share/doc/markcell/vision/RECORDING.md /usr/share/doc/markcell/README.md \
         /usr/share/doc/markcell/docs/configuration.md /usr/share/doc/markcell/docs/safety.md \
         /usr/share/man/man1/markcell.1.gz; do
  grep -qx "$f" "$work/files" || { echo "missing from the package: $f"; fail=1; }
done
# The select-mfs window and its man page are the other package's, with its own copyright.
dpkg-deb -c "$window_deb" | awk '{print $6}' | sed 's|^\./|/|' > "$work/window_files"
for f in /usr/bin/markcell-select-mfs /usr/share/man/man1/markcell-select-mfs.1.gz \
         /usr/share/doc/markcell-select-mfs/copyright /usr/share/doc/markcell-select-mfs/changelog.gz; do
  grep -qx "$f" "$work/window_files" || { echo "missing from markcell-select-mfs: $f"; fail=1; }
done
if grep -q markcell-select-mfs "$work/files"; then echo "markcell holds the window's files"; fail=1; fi
dpkg-deb -f "$window_deb" Depends | grep -q "markcell (= " || { echo "markcell-select-mfs does not depend on markcell"; fail=1; }
dpkg-deb -e "$deb" "$work/control"
grep -qx /etc/markcell/cell.yaml "$work/control/conffiles" || { echo "cell.yaml is not a conffile"; fail=1; }
grep -qx /etc/logrotate.d/markcell "$work/control/conffiles" || { echo "the logrotate snippet is not a conffile"; fail=1; }
# Calibrations are state, never conffiles: a purge must not take an edited one.
if grep -q "^/etc/markcell/calibration/" "$work/control/conffiles"; then echo "a calibration is a conffile"; fail=1; fi
grep -q "/var/lib/markcell/calibration" "$work/control/postinst" || { echo "postinst does not seed the calibrations"; fail=1; }
grep -q "adduser --quiet --system --group" "$work/control/postinst" || { echo "postinst does not create the system user"; fail=1; }
grep -q "^Depends:.*libgpiod" "$work/control/control" || { echo "Depends lacks the shared libraries"; fail=1; }
grep -q "^Depends:.*highgui" "$work/control/control" && { echo "markcell depends on highgui"; fail=1; }
grep -qx "Architecture: $arch" "$work/control/control" || { echo "not Architecture: $arch"; fail=1; }
grep "^Depends:" "$work/control/control"
[ "$fail" = 0 ] || exit 1
dpkg-deb -x "$deb" "$work/root"
# The man page: help2man's from --help-all, so every subcommand's usage is in it.
man_text=$(zcat "$work/root/usr/share/man/man1/markcell.1.gz" | sed 's/\\-/-/g')
for sub in check-config run sim replay select-mfs calibrate-stereo calibrate-base calibrations capacity record; do
  grep -q "^$sub\b" <<<"$man_text" || { echo "the man page lacks the subcommand $sub"; exit 1; }
done
# The packaged configuration keeps its state in /var/lib/markcell, which the postinst
# makes: here a folder of the test's stands in for it.
mkdir -p "$work/state/records" "$work/state/calibration"
cp "$work/root/usr/share/markcell/calibration/"*.yaml "$work/state/calibration/"
grep -q "stereo: /var/lib/markcell/calibration/marking_stereo.yaml" "$work/root/etc/markcell/cell.yaml" ||
  { echo "the package's cell.yaml does not take the calibrations from /var/lib/markcell"; exit 1; }
sed "s|/var/lib/markcell|$work/state|" "$work/root/etc/markcell/cell.yaml" >"$work/root/etc/markcell/cell.test.yaml"
${emulator[@]+"${emulator[@]}"} "$work/root/usr/bin/markcell" check-config "$work/root/etc/markcell/cell.test.yaml"
"$here/verify_service_unit.sh" "$work/root/usr/lib/systemd/system/markcell.service" "$work/root/usr/bin/markcell"
echo "the package: file list, conffiles, postinst and unit OK"
