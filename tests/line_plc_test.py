#!/usr/bin/env python3
"""Pairing by the line's panel id against an independent Modbus TCP server as the PLC
(Debian's python3-pymodbus, so the register map of docs/line.md is checked against
another implementation than the cell's libmodbus).

    line_plc_test.py MARKCELL SOURCE_DIR WORK_DIR RECORDING_DIR CASE

RECORDING_DIR is the door's recording and inspection record (the operator_page_recording
fixture's `sim/`). Each case runs `markcell run --clock real` with that recording as the
cameras, a PLC script on the simulated lines (the panel arrives at 0.5 s, leaves at
3.7 s, or later where the case says) and `line.panel_id_source: modbus` pointing at a pymodbus server this script runs
on a free port of 127.0.0.1, whose PLC program announces panels in its block and reads
the cell's:

    paired   the line announces the door: it is marked; the cell's block says so
    removed  a record for a panel taken off the line ahead of the door (by order it
             would have been used for the door): the door is marked with its own
             record, the removed one expires with its reason, nothing else sprayed
    unknown  the line announces a panel with no record: it goes by unmarked, its
             result names it, the valve never opens
    silent   the PLC stops answering while the door is being marked: safe stop naming
             plc_link, exit 1, the panel's result a fault
    absent   no PLC answers at the start: `markcell run` does not start (exit 1, the
             reason), the record stays where it is
"""
import asyncio
import datetime
import json
import pathlib
import re
import shutil
import subprocess
import sys
import threading
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import operator_page_test  # noqa: E402
from operator_page_test import fail, free_port, record_with_id, wait_for  # noqa: E402

from pymodbus.datastore import ModbusSequentialDataBlock, ModbusServerContext, ModbusSlaveContext  # noqa: E402
from pymodbus.server.async_io import ModbusTcpServer  # noqa: E402

PANEL = "paper-door-1"
UNIT = 3
PLC_BLOCK = 200   # the map placed away from 0 and 100, as a plant's PLC may
CELL_BLOCK = 400
HOLDING = 3       # Modbus function code of holding registers (pymodbus's context key)
ROLE_BITS = {"spray_valve": 0, "camera_trigger": 1, "plc_panel_present": 2, "plc_cycle_enable": 3, "plc_estop": 4,
             "plc_ready": 5, "plc_busy": 6, "plc_done": 7, "plc_fault": 8}


def text_registers(text, count):
    """Two bytes a register, high byte first, NUL-padded (docs/line.md)."""
    raw = text.encode("ascii").ljust(2 * count, b"\0")
    return [raw[2 * i] << 8 | raw[2 * i + 1] for i in range(count)]


class Plc:
    """A PLC as a Modbus TCP server: its block written here, the cell's read here."""

    def __init__(self):
        self.port = free_port()
        self.store = ModbusSlaveContext(hr=ModbusSequentialDataBlock(0, [0] * 1000), zero_mode=True)
        self.context = ModbusServerContext(slaves={UNIT: self.store}, single=False)
        self.loop = asyncio.new_event_loop()
        self.server = None
        self.counter = 0
        self.set_block(0, "", "")
        ready = threading.Event()

        def run():
            asyncio.set_event_loop(self.loop)
            self.server = ModbusTcpServer(self.context, address=("127.0.0.1", self.port), allow_reuse_address=True,
                                          loop=self.loop)
            task = self.loop.create_task(self.server.serve_forever())
            ready.set()
            try:
                self.loop.run_until_complete(task)
            except (asyncio.CancelledError, Exception):
                pass

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        ready.wait(10)
        wait_for("the PLC's server listening", self.listening, 10)

    def listening(self):
        import socket
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def set_block(self, counter, panel_id, panel_type):
        values = [1, counter] + text_registers(panel_id, 32) + text_registers(panel_type, 16)
        self.store.setValues(HOLDING, PLC_BLOCK, values)

    def announce(self, panel_id, panel_type):
        self.counter += 1
        self.set_block(self.counter, panel_id, panel_type)

    def cell_block(self):
        return self.store.getValues(HOLDING, CELL_BLOCK, 9)

    def stop(self):
        """The PLC goes silent: its server shut, every connection closed."""
        async def shut():
            await self.server.shutdown()
        fut = asyncio.run_coroutine_threadsafe(shut(), self.loop)
        try:
            fut.result(10)
        except Exception:
            pass
        wait_for("the PLC's server closed", lambda: not self.listening(), 10)


def cell_config(source, work, recording, plc):
    return operator_page_test.cell_config(source, work, recording=recording, extra=[
        (r"(?m)^  record_expiry_s: 300 ", "  record_expiry_s: 3   "),
        (r"(?m)^  panel_id_source: none .*$", "  panel_id_source: modbus"),
        (r"(?m)^  silent_ms: 1000 .*$",
         f"  silent_ms: 500\n  modbus:\n    server: 127.0.0.1:{plc.port}\n    unit_id: {UNIT}\n"
         f"    plc_block: {PLC_BLOCK}\n    cell_block: {CELL_BLOCK}\n    poll_ms: 20"),
    ])


def run_cell(markcell, work, config, seconds):
    log = open(work / "run.log", "w")
    cell = subprocess.Popen([markcell, "run", "--config", str(config), "--clock", "real", "--seconds", str(seconds),
                             "--plc-script", str(work / "plc.txt")], stdout=log, stderr=subprocess.STDOUT)
    return cell


def running(cell, work):
    """The cell still runs (else the test fails with its log)."""
    if cell.poll() is not None:
        print((work / "run.log").read_text())
        fail(f"markcell run ended early (exit {cell.returncode})")
    return True


def finish(cell, work, expect_rc=0):
    log = operator_page_test.wait_cell(cell, work, expect_rc)
    results = [json.loads(l) for l in (work / "results.jsonl").read_text().splitlines()]
    return log, results


def main(argv):
    markcell, case = argv[1], argv[5]
    source, work, recording = (pathlib.Path(a).resolve() for a in argv[2:5])
    work = work / case
    shutil.rmtree(work, ignore_errors=True)
    (work / "records").mkdir(parents=True)
    (work / "plc.txt").write_text("0.5 plc_panel_present 1\n3.7 plc_panel_present 0\n")
    plc = Plc()
    config = cell_config(source, work, recording, plc)
    sprayed_door = f"panel={PANEL} result=done sprayed=3 skipped=0"

    if case == "paired":
        (work / "records" / "0001.yaml").write_text(record_with_id(recording, PANEL))
        # The panel stays 2 s after its marking (about 3 s) so that the PLC sees the done line.
        (work / "plc.txt").write_text("0.5 plc_panel_present 1\n5.5 plc_panel_present 0\n")
        cell = run_cell(markcell, work, config, 8)
        # Announced once the cell answers (its first exchange comes before its PLC script's
        # clock starts): the time from the announcement to the record's acceptance.
        wait_for("the cell's first exchange", lambda: running(cell, work) and plc.cell_block()[1] != 0, 20)
        announced_at = datetime.datetime.now(datetime.timezone.utc)
        plc.announce(PANEL, "door")
        history = []  # the cell's block as the PLC saw it, every 20 ms

        def cell_says_done():
            running(cell, work)
            history.append(plc.cell_block())
            b = history[-1]
            return b[6] == 1 and b[7] == 1 and (b[2] >> ROLE_BITS["plc_done"]) & 1
        wait_for("the cell's block: one panel done, its done line high", cell_says_done, 20)
        b = history[-1]
        if b[0] != 1:
            fail(f"the cell's block: map version {b[0]}, expected 1")
        if b[5] != 1:
            fail(f"the cell's block: arrival heard {b[5]}, expected 1")
        lines = b[2]
        for role, want in (("plc_done", 1), ("plc_busy", 0), ("plc_fault", 0), ("plc_panel_present", 1),
                           ("plc_ready", 1), ("plc_cycle_enable", 1)):
            if (lines >> ROLE_BITS[role]) & 1 != want:
                fail(f"the cell's block: lines {lines:#06x}: {role} is not {want}")
        if not any((h[2] >> ROLE_BITS["plc_busy"]) & 1 and h[6] == 0 for h in history):
            fail("the cell's block never showed the panel under way (busy, none done)")
        beat = b[1]
        time.sleep(0.3)
        if plc.cell_block()[1] == beat:
            fail("the cell's heartbeat (register +1) does not change")
        log, results = finish(cell, work)
        if sprayed_door not in log:
            fail("the announced door was not marked")
        if f"line: panel {PANEL} type door announced (arrival 1)" not in log:
            fail("the announcement is not in the journal")
        accepted = next(r for r in results if r.get("accepted"))
        at = datetime.datetime.fromisoformat(accepted["utc"].replace("Z", "+00:00"))
        # (the results file's UTC is rounded down to the millisecond)
        if at < announced_at - datetime.timedelta(milliseconds=1):
            fail(f"the record was accepted at {accepted['utc']}, before the announcement at {announced_at.isoformat()}")
        print(f"announcement to the record accepted: {(at - announced_at).total_seconds() * 1e3:.0f} ms")
        print(f"cell block after the panel: {b}")

    elif case == "removed":
        # The removed panel's record comes first in name order: by order, the door would be
        # marked with its defects.
        (work / "records" / "0000.yaml").write_text(record_with_id(recording, "removed-0"))
        (work / "records" / "0001.yaml").write_text(record_with_id(recording, PANEL))
        plc.announce(PANEL, "door")
        cell = run_cell(markcell, work, config, 6)
        log, results = finish(cell, work)
        if sprayed_door not in log:
            fail("the door was not marked with its own record")
        accepted = [r["panel_id"] for r in results if r.get("accepted")]
        if accepted != [PANEL]:
            fail(f"accepted records {accepted}, expected only {PANEL}'s")
        expired = [r for r in results if r.get("rejected") and r.get("panel_id") == "removed-0"]
        if len(expired) != 1 or "expired: the line announced no panel 'removed-0' within 3 s" not in expired[0]["rejected"]:
            fail(f"the removed panel's record did not expire with its reason: {expired}")
        if not (work / "records" / "rejected" / "0000.yaml").is_file():
            fail("the expired record is not in rejected/")
        done = [r for r in results if "started_s" in r]
        if [r["panel_id"] for r in done] != [PANEL]:
            fail(f"panel results {[r['panel_id'] for r in done]}, expected only {PANEL}")

    elif case == "unknown":
        (work / "records" / "0001.yaml").write_text(record_with_id(recording, PANEL))
        plc.announce("other-7", "door")
        (work / "plc.txt").write_text("0.5 plc_panel_present 1\n7.0 plc_panel_present 0\n")
        cell = run_cell(markcell, work, config, 8)
        log, results = finish(cell, work)
        done = [r for r in results if "started_s" in r]
        if len(done) != 1 or done[0]["panel_id"] != "other-7" or not done[0]["fault"] or \
                done[0]["reason"] != "panel 'other-7' present without its inspection record":
            fail(f"the unknown panel's result: {done}")
        if "result=fault sprayed=0 skipped=0" not in log or re.search(r"sprayed=[1-9]", log):
            fail("something was sprayed on a panel without its record")
        # Its own record waited for an announcement that never came, then expired.
        expired = [r for r in results if r.get("rejected") and r.get("panel_id") == PANEL]
        if len(expired) != 1 or "expired: the line announced no panel" not in expired[0]["rejected"]:
            fail(f"the unannounced record did not expire: {expired}")
        if any(r.get("accepted") for r in results):
            fail("a record was accepted for a panel the line did not announce")

    elif case == "silent":
        (work / "records" / "0001.yaml").write_text(record_with_id(recording, PANEL))
        plc.announce(PANEL, "door")
        cell = run_cell(markcell, work, config, 8)
        wait_for("the panel under way (the cell's busy line)",
                 lambda: running(cell, work) and (plc.cell_block()[2] >> ROLE_BITS["plc_busy"]) & 1, 20)
        plc.stop()
        log, results = finish(cell, work, expect_rc=1)
        if "code=device_fault source=plc_link" not in log or "has not answered for" not in log:
            fail("the safe stop does not name plc_link and the silence")
        if "the PLC does not answer" not in log:
            fail("the journal does not say the PLC stopped answering")
        done = [r for r in results if "started_s" in r]
        if any(d["sprayed"] for r in done for d in r["defects"]):
            fail("a defect was sprayed: the PLC went silent about 1.2 s into the run, its first spray is due at about 2 s")
        if len(done) != 1 or not done[0]["fault"] or done[0]["reason"] != "safe stop during the marking sequence":
            fail(f"the panel's result: {done}")
    elif case == "absent":
        # No PLC answers at the start: the cell does not start, nothing is taken or moved.
        plc.stop()
        (work / "records" / "0001.yaml").write_text(record_with_id(recording, PANEL))
        cell = run_cell(markcell, work, config, 4)
        log = operator_page_test.wait_cell(cell, work, 1)
        want = (f"markcell: start-up failed: the line's PLC: connect (Modbus TCP 127.0.0.1:{plc.port}, unit {UNIT}): "
                "Connection refused")
        if want not in log:
            fail(f"the start-up failure does not say: {want}")
        if "running on the real clock" in log or not (work / "records" / "0001.yaml").is_file():
            fail("the cell started or took the record without its PLC")
    else:
        fail(f"unknown case {case}")
    print(f"line_plc {case}: passed")


if __name__ == "__main__":
    main(sys.argv)
