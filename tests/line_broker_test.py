#!/usr/bin/env python3
"""Two stations through a real MQTT broker (Debian's mosquitto 2.0, started here on a free
port of 127.0.0.1 with TLS, a password per station and an ACL; docs/line.md "The
broker"), with Debian's python3-paho-mqtt as the line's tracking system and the plant:
an MQTT client that is not the cell's libmosquitto.

    line_broker_test.py MARKCELL SOURCE_DIR WORK_DIR RECORDING_DIR CASE

RECORDING_DIR is the door's recording and inspection record (the operator_page_recording
fixture's `sim/`). `markcell publish-record` is the inspection station's side;
`markcell run --clock real` the marking station's, with `line.panel_id_source: broker`
and the recording as its cameras (the panel arrives at 0.5 s):

    paired    the inspection station publishes the door's record, the tracking system
              announces the door: it is marked; every line of the results file arrives
              on the result topic, identical; the station's retained state goes
              online, ready, marking, ready and, once stopped, offline
    removed   a record for a panel taken off the line ahead of the door: the door is
              marked with its own record, the removed one expires with its reason
    rejected  bad messages on the record topic (over the size limit, no end marker, a
              field wrong, an id that is not the topic's): each rejected with its reason
              in the results file, saved to rejected/, said on the station's state; the
              door is still marked afterwards
    crash     the marking station killed with SIGKILL at 50 random moments while 100
              records flow: each has exactly one accepted line and one result
    bench     `markcell bench broker` on 601 records: every delivery accepted once
    absent    no broker at the start: `markcell run` exits 1 with the reason
    security  a wrong password, another station's credentials, a plaintext client and
              a subscriber without the right to records: each refused, nothing used
    restart   the broker killed (SIGKILL) after the record is published and started
              again from its persistence: the station reconnects, the door is marked
"""
import json
import os
import pathlib
import re
import shutil
import signal
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import operator_page_test  # noqa: E402
from operator_page_test import fail, free_port, record_with_id, wait_for  # noqa: E402

import paho.mqtt.client as mqtt  # noqa: E402

LINE = "line-1"
PANEL = "paper-door-1"
USERS = {"insp-1": "insp-secret-1", "mark-1": "mark-secret-1", "tracking": "track-secret", "plant": "plant-secret"}
ACL = f"""user insp-1
topic write markcell/{LINE}/insp-1/record/#
topic readwrite markcell/{LINE}/insp-1/state

user mark-1
topic read markcell/{LINE}/+/record/#
topic read markcell/{LINE}/arrival
topic readwrite markcell/{LINE}/mark-1/state
topic write markcell/{LINE}/mark-1/result

user tracking
topic write markcell/{LINE}/arrival

user plant
topic read markcell/{LINE}/+/state
topic read markcell/{LINE}/+/result
"""


def run(cmd, **kw):
    return subprocess.run(cmd, check=True, capture_output=True, text=True, **kw)


class Broker:
    """mosquitto with TLS (a CA and a server certificate for 127.0.0.1 made by openssl),
    a password file, an ACL and persistence, all in WORK/broker."""

    def __init__(self, work):
        self.dir = work / "broker"
        self.dir.mkdir(parents=True)
        d = self.dir
        run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj", "/CN=markcell test CA",
             "-keyout", str(d / "ca.key"), "-out", str(d / "ca.crt")])
        run(["openssl", "req", "-newkey", "rsa:2048", "-nodes", "-subj", "/CN=127.0.0.1",
             "-keyout", str(d / "server.key"), "-out", str(d / "server.csr")])
        (d / "san.ext").write_text("subjectAltName=IP:127.0.0.1\n")
        run(["openssl", "x509", "-req", "-in", str(d / "server.csr"), "-CA", str(d / "ca.crt"), "-CAkey",
             str(d / "ca.key"), "-CAcreateserial", "-days", "2", "-extfile", str(d / "san.ext"),
             "-out", str(d / "server.crt")])
        first = True
        for user, password in USERS.items():
            run(["mosquitto_passwd", "-b"] + (["-c"] if first else []) + [str(d / "passwords"), user, password])
            first = False
            secret = d / f"{user}.password"
            secret.write_text(password + "\n")
            secret.chmod(0o600)
        (d / "acl").write_text(ACL)
        (d / "persistence").mkdir()
        self.port = free_port()
        user = subprocess.run(["id", "-un"], capture_output=True, text=True).stdout.strip()
        (d / "mosquitto.conf").write_text(f"""user {user}
per_listener_settings false
allow_anonymous false
password_file {d / 'passwords'}
acl_file {d / 'acl'}
persistence true
persistence_location {d / 'persistence'}/
autosave_interval 1
log_dest file {d / 'mosquitto.log'}
log_type all
listener {self.port} 127.0.0.1
cafile {d / 'ca.crt'}
certfile {d / 'server.crt'}
keyfile {d / 'server.key'}
tls_version tlsv1.2
""")
        self.proc = None
        self.start()

    def start(self):
        self.proc = subprocess.Popen(["mosquitto", "-c", str(self.dir / "mosquitto.conf")], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        wait_for("mosquitto listening", lambda: self.proc.poll() is None and self.listening(), 10)

    def listening(self):
        import socket
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", self.port)) == 0

    def kill(self):
        self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)

    def stop(self):
        if self.proc and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()


class Client:
    """The line's tracking system or the plant: a paho MQTT 5 client over TLS."""

    def __init__(self, broker, user, password=None, tls=True, client_id=None, persistent=False):
        self.messages = []
        self.connected = None
        self.c = mqtt.Client(client_id=client_id or f"test-{user}-{os.getpid()}", protocol=mqtt.MQTTv5)
        if tls:
            self.c.tls_set(ca_certs=str(broker.dir / "ca.crt"))
        self.c.username_pw_set(user, USERS.get(user) if password is None else password)
        self.schemas = {}  # topic -> the MQTT 5 user property "schema" of its last message

        def on_message(c, u, m):
            self.messages.append((m.topic, m.payload.decode("utf-8", "replace"), m.retain))
            user = dict(getattr(m.properties, "UserProperty", []) or [])
            self.schemas[m.topic] = user.get("schema")
        self.c.on_message = on_message
        self.c.on_connect = lambda c, u, f, rc, p=None: setattr(self, "connected", rc)
        self.granted = []
        self.c.on_subscribe = lambda c, u, mid, rcs, p=None: self.granted.extend(rcs)
        if persistent:  # the broker keeps its session (and what it missed) for 300 s
            from paho.mqtt.packettypes import PacketTypes
            from paho.mqtt.properties import Properties
            props = Properties(PacketTypes.CONNECT)
            props.SessionExpiryInterval = 300
            self.c.connect("127.0.0.1", broker.port, keepalive=10, clean_start=False, properties=props)
        else:
            self.c.connect("127.0.0.1", broker.port, keepalive=10)
        self.c.loop_start()

    def wait_connected(self):
        wait_for("the paho client's CONNACK", lambda: self.connected is not None, 10)
        return self.connected

    def publish(self, topic, payload, retain=False):
        info = self.c.publish(topic, payload, qos=1, retain=retain)
        info.wait_for_publish(10)

    def subscribe(self, topic):
        self.c.subscribe(topic, qos=1)
        wait_for(f"the broker's answer to subscribing {topic}", lambda: self.granted, 10)

    def close(self):
        self.c.loop_stop()
        self.c.disconnect()


def config_for(source, work, recording, broker, station):
    """The marking station's configuration; the inspection station's is the same with its
    own name and credentials (its line.broker and panel_types are what it uses)."""
    return operator_page_test.cell_config(source, work, recording=recording, extra=[
        (r"(?m)^  record_expiry_s: 300 ", "  record_expiry_s: 3   "),
        (r"(?m)^  panel_id_source: none .*$", "  panel_id_source: broker"),
        (r"(?m)^  silent_ms: 1000 .*$",
         f"  silent_ms: 5000\n  broker:\n    server: 127.0.0.1:{broker.port}\n    line: {LINE}\n"
         f"    station: {station}\n    username: {station}\n    password_file: {broker.dir / (station + '.password')}\n"
         f"    ca_file: {broker.dir / 'ca.crt'}\n    keepalive_s: 5\n    record_retain_s: 60"),
    ])


def publish_record(markcell, config, path, expect_rc=0):
    p = subprocess.run([markcell, "publish-record", "--config", str(config), str(path)], capture_output=True, text=True,
                       timeout=60)
    print(p.stdout + p.stderr)
    if p.returncode != expect_rc:
        fail(f"markcell publish-record exited {p.returncode}, expected {expect_rc}: {p.stderr}")
    return p.stdout + p.stderr


def start_cell(markcell, work, config, seconds):
    log = open(work / "run.log", "w")
    return subprocess.Popen([markcell, "run", "--config", str(config), "--clock", "real", "--seconds", str(seconds),
                             "--plc-script", str(work / "plc.txt")], stdout=log, stderr=subprocess.STDOUT)


def running(cell, work):
    if cell.poll() is not None:
        print((work / "run.log").read_text())
        fail(f"markcell run ended early (exit {cell.returncode})")
    return True


def states(plant, station="mark-1"):
    return [json.loads(p) for t, p, _ in plant.messages if t == f"markcell/{LINE}/{station}/state" and p]


def results_on_topic(plant, station="mark-1"):
    return [p for t, p, _ in plant.messages if t == f"markcell/{LINE}/{station}/result"]


def crash(markcell, source, work, recording, broker, plant, tracking):
    """The marking station killed with SIGKILL at 50 random moments while an inspection
    station publishes RECORDS records (one every 40 ms) and panels come every simulated
    second: afterwards every record has exactly one accepted line and one result (its
    panel's, or `interrupted` when the kill came between the two), none lost, none used
    twice. The cell is the simulated default (`--clock sim`: each panel's present pulse
    starts it with the next record and ends it unmarked 0.4 s later, which is a result
    all the same); records pair in order (their names are their ids' order)."""
    import random
    import threading
    records, kills = 100, 50
    rng = random.Random(20261207)
    text = (source / "config" / "cell.example.yaml").read_text()
    for pattern, replacement in [
        (r"(?m)^  # results_file: \S+", f"  results_file: {work / 'results.jsonl'}"),
        (r"(?m)^  # record_folder: (\S+)", f"  record_folder: {work / 'records'}"),
        (r"(?m)^(  stereo|  base): calibration/", rf"\1: {source / 'config'}/calibration/"),
        (r"file: panels/", f"file: {source / 'config'}/panels/"),
        (r"on_overrun: safe_stop", "on_overrun: log"),
        (r"(?m)^  silent_ms: 1000 .*$",
         f"  silent_ms: 1000\n  broker:\n    server: 127.0.0.1:{broker.port}\n    line: {LINE}\n"
         f"    station: mark-1\n    username: mark-1\n    password_file: {broker.dir / 'mark-1.password'}\n"
         f"    ca_file: {broker.dir / 'ca.crt'}\n    keepalive_s: 5"),
    ]:
        text, n = re.subn(pattern, replacement, text)
        if n == 0:
            fail(f"cell.example.yaml no longer has what the test edits: {pattern}")
    config = work / "crash.yaml"
    config.write_text(text)
    with open(work / "plc.txt", "w") as f:
        for k in range(10_000):  # (a PLC script is at most 1 MiB)
            f.write(f"{k + 0.5:.1f} plc_panel_present 1\n{k + 0.9:.1f} plc_panel_present 0\n")
    base = record_with_id(recording, "x")
    ids = [f"rec-{i:04d}" for i in range(1, records + 1)]
    insp = Client(broker, "insp-1")
    insp.wait_connected()

    def publish_all():
        for i in ids:
            insp.publish(f"markcell/{LINE}/insp-1/record/{i}", base.replace("panel_id: x", f"panel_id: {i}"), retain=True)
            time.sleep(0.04)
    publisher = threading.Thread(target=publish_all)
    publisher.start()
    log = open(work / "run.log", "w")

    def start():
        return subprocess.Popen([markcell, "run", "--config", str(config), "--clock", "sim", "--seconds", "100000",
                                 "--plc-script", str(work / "plc.txt")], stdout=log, stderr=subprocess.STDOUT)
    moments = []
    for k in range(kills):
        cell = start()
        moment = rng.uniform(0.1, 1.2)
        time.sleep(moment)
        if cell.poll() is not None:
            print((work / "run.log").read_text()[-3000:])
            fail(f"run {k + 1} ended by itself (exit {cell.returncode})")
        cell.send_signal(signal.SIGKILL)
        cell.wait(10)
        moments.append(moment)
    publisher.join()
    insp.close()

    def lines():
        out = []
        for line in (work / "results.jsonl").read_text().splitlines():
            try:
                out.append(json.loads(line))
            except ValueError:
                pass  # (a line a kill cut short; the next start ended it)
        return out

    def answered():
        got = lines()
        done = {r["panel_id"] for r in got if "panel" in r or r.get("interrupted")}
        return all(i in done for i in ids)
    cell = start()
    wait_for("every record answered after the kills", lambda: cell.poll() is None and answered(), 120)
    cell.send_signal(signal.SIGTERM)
    cell.wait(30)
    got = lines()
    problems = []
    for i in ids:
        accepted = [r for r in got if r.get("panel_id") == i and r.get("accepted")]
        results = [r for r in got if r.get("panel_id") == i and ("panel" in r or r.get("interrupted"))]
        if len(accepted) != 1 or len(results) != 1:
            problems.append(f"{i}: {len(accepted)} accepted, {len(results)} result(s)")
    strays = [r for r in got if r.get("panel_id") not in ids and "rejected" not in r]
    rejected = [r for r in got if "rejected" in r]
    interrupted = sum(1 for r in got if r.get("interrupted"))
    print(f"{kills} kills at {min(moments):.2f}-{max(moments):.2f} s into a run; {records} records; "
          f"{interrupted} interrupted; {len(rejected)} rejected: {[r['rejected'][-80:] for r in rejected][:5]}")
    if problems:
        fail("not exactly once: " + "; ".join(problems[:10]))
    if strays:
        fail(f"results for panels never published: {strays[:3]}")
    # A kill after a record's accepted line and before its file left the folder: the next
    # start finds the file again and rejects it as the duplicate it is, naming the panel.
    if any("duplicate" not in r["rejected"] or r["panel_id"] not in ids for r in rejected):
        fail(f"a record rejected for another reason than a duplicate, or without its id: {rejected}")


def bench(markcell, source, work):
    """`markcell bench broker` on a small load: its own mosquitto, 3 lines of 1 inspection
    and 2 marking stations as processes; every delivery accepted once (no time is
    asserted: the figures are the benchmark's, docs/benchmarks.md)."""
    out = work / "bench.json"
    p = subprocess.run([markcell, "bench", "broker", "--config", str(source / "config" / "cell.example.yaml"),
                        "--records", "601", "--rate", "100", "--work", str(work / "bench"), "--json", str(out)],
                       capture_output=True, text=True, timeout=240)
    print(p.stdout + p.stderr)
    if p.returncode != 0:
        fail(f"markcell bench broker exited {p.returncode}")
    j = json.loads(out.read_text())
    if (j["records"], j["deliveries"], j["lost"], j["duplicated"]) != (601, 1202, 0, 0):
        fail(f"bench broker: {j}")
    lat = j["latency_ms"]
    if not 0 < lat["p50"] <= lat["p99"] <= lat["max"]:
        fail(f"bench broker: latencies out of order {lat}")
    if (work / "bench").exists():
        fail("the bench's folder was not removed")


def main(argv):
    markcell, case = argv[1], argv[5]
    source, work, recording = (pathlib.Path(a).resolve() for a in argv[2:5])
    work = work / case
    shutil.rmtree(work, ignore_errors=True)
    if case == "bench":
        work.mkdir(parents=True)
        bench(markcell, source, work)
        print("line_broker bench: passed")
        return
    (work / "records").mkdir(parents=True)
    # The panel stays 2 s after its marking (about 3 s) so that the results are all in.
    (work / "plc.txt").write_text("0.5 plc_panel_present 1\n5.5 plc_panel_present 0\n")
    broker = Broker(work)
    try:
        marking = config_for(source, work, recording, broker, "mark-1")
        (work / "inspection").mkdir()
        inspection = config_for(source, work / "inspection", recording, broker, "insp-1")
        (work / "inspection" / "records").mkdir()
        sprayed_door = f"panel={PANEL} result=done sprayed=3 skipped=0"
        door_record = work / "door.yaml"
        door_record.write_text(record_with_id(recording, PANEL))
        plant = Client(broker, "plant")
        if plant.wait_connected() != 0:
            fail(f"the plant's client was refused: {plant.connected}")
        plant.subscribe(f"markcell/{LINE}/#")
        tracking = Client(broker, "tracking")
        tracking.wait_connected()
        nonlocal_clients = {"plant": plant, "tracking": tracking}

        def announce(counter, panel_id):
            nonlocal_clients["tracking"].publish(f"markcell/{LINE}/arrival",
                             json.dumps({"schema": 1, "counter": counter, "panel_id": panel_id, "panel_type": "door"}),
                             retain=True)

        def marked_door(seconds=9, before_cell=None):
            if before_cell:
                before_cell()
            cell = start_cell(markcell, work, marking, seconds)
            wait_for("the station's state ready", lambda: running(cell, work) and
                     any(s["state"] == "ready" for s in states(nonlocal_clients["plant"])), 20)
            announce(1, PANEL)
            log = operator_page_test.wait_cell(cell, work, 0)
            if sprayed_door not in log:
                fail("the door was not marked with its record")
            return log, [json.loads(l) for l in (work / "results.jsonl").read_text().splitlines()]

        if case == "paired":
            publish_record(markcell, inspection, door_record)
            log, results = marked_door()
            lines = (work / "results.jsonl").read_text().splitlines()
            wait_for("every results line on the result topic", lambda: len(results_on_topic(plant)) >= len(lines), 10)
            if results_on_topic(plant) != lines:
                fail(f"the result topic {results_on_topic(plant)} is not the results file {lines}")
            for topic in (f"markcell/{LINE}/mark-1/result", f"markcell/{LINE}/mark-1/state"):
                if plant.schemas.get(topic) != "1":
                    fail(f"{topic}: user property schema {plant.schemas.get(topic)!r}, expected '1'")
            if not results[0].get("accepted"):
                fail(f"the first result line is not the record's acceptance: {results[:1]}")
            seen = [s["state"] for s in states(plant)]
            compact = [s for i, s in enumerate(seen) if i == 0 or seen[i - 1] != s]
            if compact[-5:] != ["online", "ready", "marking", "ready", "offline"]:
                fail(f"the station's states {compact}, expected online, ready, marking, ready, offline")
            last = states(plant)[-1]
            if last["reason"] != "duration elapsed" or last["station"] != "mark-1" or last["role"] != "marking":
                fail(f"the last state {last}")
            if list((work / "records").glob("mqtt-*.yaml")):
                fail("a record is left in the record folder")
            if not (work / "records" / "accepted" / f"mqtt-{PANEL}.yaml").is_file():
                fail("the record is not in accepted/ under its topic's name")
            print(f"results file and result topic: {len(lines)} identical line(s); states {compact}")
        elif case == "removed":
            removed = work / "removed.yaml"
            removed.write_text(record_with_id(recording, "removed-0"))
            publish_record(markcell, inspection, removed)
            publish_record(markcell, inspection, door_record)
            log, results = marked_door()
            accepted = [r["panel_id"] for r in results if r.get("accepted")]
            if accepted != [PANEL]:
                fail(f"accepted records {accepted}, expected only {PANEL}'s")
            expired = [r for r in results if "rejected" in r and r["panel_id"] == "removed-0"]
            if len(expired) != 1 or "expired: the line announced no panel 'removed-0'" not in expired[0]["rejected"]:
                fail(f"the removed panel's record did not expire with its reason: {expired}")
        elif case == "rejected":
            insp = Client(broker, "insp-1")
            insp.wait_connected()
            good = record_with_id(recording, "bad-1")
            bad = {
                "big-1": (good.replace("...\n", "") + "# " + "x" * 1_100_000 + "\n...\n", "more than the 1048576 allowed"),
                "nomarker-1": (record_with_id(recording, "nomarker-1").replace("\n...\n", "\n"),
                               "end-of-document marker"),
                "frame-1": (record_with_id(recording, "frame-1").replace("frame: CamL_SL", "frame: CamR_SL"),
                            "frame: must be CamL_SL"),
                "other-1": (record_with_id(recording, "not-other-1"), "is not the topic's"),
            }
            for level, (payload, _) in bad.items():
                insp.publish(f"markcell/{LINE}/insp-1/record/{level}", payload, retain=True)
            # A record of a format version this station does not read (MQTT 5 user property).
            from paho.mqtt.packettypes import PacketTypes
            from paho.mqtt.properties import Properties
            props = Properties(PacketTypes.PUBLISH)
            props.UserProperty = ("schema", "2")
            insp.c.publish(f"markcell/{LINE}/insp-1/record/v2-1", record_with_id(recording, "v2-1"), qos=1, retain=True,
                           properties=props).wait_for_publish(10)
            bad["v2-1"] = ("", "schema '2' is not one this station reads (1)")
            insp.close()
            publish_record(markcell, inspection, door_record)
            log, results = marked_door()
            rejected = [r for r in results if "rejected" in r]
            for level, (_, why) in bad.items():
                hits = [r for r in rejected if f"/record/{level}" in r["rejected"] and why in r["rejected"]]
                if len(hits) != 1:
                    fail(f"the message on record/{level} was not rejected once with '{why}': {rejected}")
            saved = sorted(p.name for p in (work / "records" / "rejected").glob("mqtt-*.yaml"))
            if len(saved) != 4:
                fail(f"rejected/ holds {saved}: expected the four payloads under the size limit")
            said = [s["reason"] for s in states(plant) if s["reason"].startswith("record rejected: ")]
            if len(said) < 1:
                fail(f"no rejection was said on the station's state: {states(plant)}")
            if log.count("markcell: record rejected: ") != 5:
                fail("not every bad message was logged once")
        elif case == "security":
            out = publish_record(markcell, config_for(source, work / "inspection", recording, broker, "insp-1"),
                                 door_record, expect_rc=0)
            # A wrong password.
            wrong = broker.dir / "wrong.password"
            wrong.write_text("not-the-password\n")
            wrong.chmod(0o600)
            text = inspection.read_text().replace(str(broker.dir / "insp-1.password"), str(wrong))
            bad_config = work / "inspection" / "wrong.yaml"
            bad_config.write_text(text)
            out = publish_record(markcell, bad_config, door_record, expect_rc=1)
            if "Bad user name or password" not in out and "Not authorized" not in out:
                fail(f"a wrong password was not refused by name: {out}")
            if "not-the-password" in out:
                fail("the password is in the output")
            # Another station's credentials: the marking station's user may not publish records.
            other = work / "inspection" / "other.yaml"
            other.write_text(text.replace(str(wrong), str(broker.dir / "mark-1.password"))
                             .replace("username: insp-1", "username: mark-1").replace("station: insp-1", "station: mark-2"))
            intruder = work / "intruder.yaml"
            intruder.write_text(record_with_id(recording, "intruder-1"))
            out = publish_record(markcell, other, intruder, expect_rc=1)
            if "Not authorized" not in out:
                fail(f"a record published with a marking station's credentials was not refused: {out}")
            # A plaintext client on the TLS listener.
            plain = Client(broker, "plant", tls=False, client_id="plain")
            time.sleep(2)
            if plain.connected == 0:
                fail("a plaintext client was accepted")
            plain.close()
            # A subscriber without the right to records (the plant's user) gets none.
            if not [m for m in plant.messages if "/record/" in m[0]] == []:
                fail("the plant's user received a record")
            log, results = marked_door()
            accepted = [r["panel_id"] for r in results if r.get("accepted")]
            if accepted != [PANEL]:
                fail(f"accepted {accepted}: expected the door's record only (the intruder's never arrives)")
            if any("/record/" in m[0] for m in plant.messages):
                fail("the plant's user received a record")
            for secret in USERS.values():
                if secret in log:
                    fail("a password is in the station's log")
        elif case == "restart":
            # The broker dies while the door is being marked and comes back from its
            # persistence: the station marks on (its record is in its folder), reconnects,
            # and its result reaches the plant's persistent session.
            plant.close()
            plant = Client(broker, "plant", client_id="plant-persistent", persistent=True)
            plant.wait_connected()
            plant.subscribe(f"markcell/{LINE}/#")
            publish_record(markcell, inspection, door_record)
            cell = start_cell(markcell, work, marking, 9)
            wait_for("the station's state ready", lambda: running(cell, work) and
                     any(s["state"] == "ready" for s in states(plant)), 20)
            announce(1, PANEL)
            wait_for("the record accepted", lambda: running(cell, work) and
                     "record panel=paper-door-1 accepted" in (work / "run.log").read_text(), 10)
            plant.close()
            tracking.close()
            time.sleep(1.2)  # (the broker's autosave: the plant's session on disk)
            broker.kill()
            wait_for("the station's log: the broker gone", lambda: running(cell, work) and
                     "markcell: broker: " in (work / "run.log").read_text().split("accepted")[-1], 10)
            broker.start()
            wait_for("the station's log: connected again", lambda: running(cell, work) and
                     "markcell: broker: connected again" in (work / "run.log").read_text(), 10)
            plant = Client(broker, "plant", client_id="plant-persistent", persistent=True)
            plant.wait_connected()
            log = operator_page_test.wait_cell(cell, work, 0)
            if sprayed_door not in log:
                fail("the door was not marked across the broker's restart")
            lines = (work / "results.jsonl").read_text().splitlines()
            wait_for("the door's result on the plant's session", lambda: lines[-1] in results_on_topic(plant), 10)
            if "(records wait at the broker; retrying)" not in log:
                fail("the lost connection was not logged")
        elif case == "crash":
            crash(markcell, source, work, recording, broker, plant, tracking)
            return
        elif case == "absent":
            plant.close()
            tracking.close()
            broker.stop()
            cell = start_cell(markcell, work, marking, 5)
            log = operator_page_test.wait_cell(cell, work, 1)
            want = f"markcell: start-up failed: the broker: connect (127.0.0.1:{broker.port}): Connection refused"
            if want not in log:
                fail(f"no '{want}' in the log")
            if (work / "results.jsonl").exists() and (work / "results.jsonl").read_text().strip():
                fail("a result was written by a cell that did not start")
            print("the station without its broker: " + want)
            return
        else:
            fail(f"unknown case {case}")
        plant.close()
        tracking.close()
    finally:
        broker.stop()
    print(f"line_broker {case}: passed")


if __name__ == "__main__":
    main(sys.argv)
