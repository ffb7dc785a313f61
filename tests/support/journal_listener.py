#!/usr/bin/env python3
"""journald's native protocol, the receiving end, for the service's journal test.

An independent reader of what sd_journal_sendv sends (systemd's "Native Journal
Protocol": one datagram per entry, each field `KEY=value\\n`, or `KEY\\n` + a 64-bit
little-endian length + the value + `\\n` when the value holds a newline). Binds
/run/systemd/journal/socket (the test runs it in a mount namespace with a tmpfs on
/run), touches OUT.ready once listening, writes each entry as one JSON object per line
to OUT, and ends after SECONDS without a datagram.

usage: journal_listener.py OUT SECONDS
"""
import json
import os
import socket
import sys

out_path, quiet_s = sys.argv[1], float(sys.argv[2])
os.makedirs("/run/systemd/journal", exist_ok=True)
sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
sock.bind("/run/systemd/journal/socket")
sock.settimeout(quiet_s)
with open(out_path, "w") as out:
    open(out_path + ".ready", "w").close()
    while True:
        try:
            data = sock.recv(1 << 20)
        except socket.timeout:
            break
        entry, i = {}, 0
        while i < len(data):
            nl = data.index(b"\n", i)
            line = data[i:nl]
            if b"=" in line:
                key, value = line.split(b"=", 1)
                i = nl + 1
            else:
                key = line
                size = int.from_bytes(data[nl + 1:nl + 9], "little")
                value = data[nl + 9:nl + 9 + size]
                i = nl + 9 + size + 1
            entry[key.decode()] = value.decode("utf-8", "replace")
        out.write(json.dumps(entry) + "\n")
        out.flush()
