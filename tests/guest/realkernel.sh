#!/bin/sh
# Runs INSIDE the guest kernel (toolchain/guest/run): sets up vcan0 and a gpio-sim chip
# whose lines carry the names of the example configuration, then runs the given test
# program with where to find them in the environment.
set -eu
ip link add dev vcan0 type vcan
ip link set vcan0 mtu 72   # CAN FD frames
ip link set up vcan0
export MARKCELL_VCAN=vcan0

cfg=/sys/kernel/config/gpio-sim/markcell
mkdir "$cfg" "$cfg/bank0"
# Role order of devices.gpio.lines in config/cell.example.yaml.
set -- "$@"
i=0
for name in MC_SPRAY_VALVE MC_CAM_TRIGGER PLC_PANEL_PRESENT PLC_CYCLE_ENABLE PLC_ESTOP PLC_READY PLC_BUSY PLC_DONE PLC_FAULT; do
  mkdir "$cfg/bank0/line$i"
  echo "$name" > "$cfg/bank0/line$i/name"
  i=$((i + 1))
done
echo "$i" > "$cfg/bank0/num_lines"
echo markcell-sim > "$cfg/bank0/label"
echo 1 > "$cfg/live"
dev=$(cat "$cfg/dev_name")
chip=$(cat "$cfg/bank0/chip_name")
export MARKCELL_GPIO_CHIP="$chip"
export MARKCELL_GPIO_SIM="/sys/devices/platform/$dev/$chip"
echo "guest: kernel $(uname -r), vcan0 up, gpio-sim $chip ($dev) with $i lines"
exec "$@"
