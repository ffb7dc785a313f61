#!/usr/bin/python3
"""Reads a markcell can.log with python-can's CanutilsLogReader (Debian's python3-can) and
decodes every frame with python3-canmatrix and the DBC: the independent reading that
tests/test_sim.cpp compares with markcell's own codec.

    can_log_read.py CAN_LOG DBC OUT

OUT: one line per frame, tab-separated: timestamp (seconds, as python-can read it), the
channel, the id in hex, 1 for a CAN FD frame, the DBC message's name, and each signal's
physical value as name=value (canmatrix's Decimal, printed exactly).
"""
import sys

import can
import canmatrix
import canmatrix.formats


def main(log, dbc_file, out_file):
    db = canmatrix.formats.loadp_flat(dbc_file)
    lines = []
    for msg in can.io.CanutilsLogReader(log):
        frame = db.frame_by_id(canmatrix.ArbitrationId(msg.arbitration_id, extended=msg.is_extended_id))
        name, signals = "-", ""
        if frame is not None:
            name = frame.name
            decoded = frame.decode(bytes(msg.data))
            signals = " ".join(f"{k}={v.phys_value}" for k, v in decoded.items())
        lines.append(f"{msg.timestamp:.6f}\t{msg.channel}\t{msg.arbitration_id:X}\t{int(msg.is_fd)}\t{name}\t{signals}\n")
    with open(out_file, "w") as out:
        out.writelines(lines)
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
