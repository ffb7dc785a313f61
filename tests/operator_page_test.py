#!/usr/bin/env python3
"""The operator page and /metrics against real peers: Debian's Chromium (through
chromedriver and python3-selenium) and Prometheus (its server scraping the endpoint, and
promtool checking the text format).

    operator_page_test.py MARKCELL SOURCE_DIR WORK_DIR recording
    operator_page_test.py MARKCELL SOURCE_DIR WORK_DIR browser [--screenshot PNG]
    operator_page_test.py MARKCELL SOURCE_DIR WORK_DIR prometheus

`recording` makes the door's recording and inspection record once (markcell sim); the
other two each run `markcell run --clock real` with that recording as the cameras, the
record in the record folder and a PLC script (the panel arrives at 0.5 s and leaves at
3.7 s; the browser's run has its e-stop pressed at 9 s), with cell.operator_page on a
free port of 127.0.0.1.
"""
import datetime
import json
import pathlib
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request

PANEL = "paper-door-1"
STARTED_UTC = None  # when the cell was started (Python's clock)


def fail(msg):
    print("FAILED: " + msg, file=sys.stderr)
    sys.exit(1)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def get(url, timeout=5):
    with urllib.request.urlopen(url, timeout=timeout) as r:
        return r.status, r.headers, r.read()


def wait_for(what, check, timeout):
    end = time.monotonic() + timeout
    last = None
    while time.monotonic() < end:
        try:
            last = check()
            if last:
                return last
        except Exception as e:  # (not up yet)
            last = e
        time.sleep(0.1)
    fail(f"{what}: not within {timeout} s (last: {last!r})")


def make_recording(markcell, source, work):
    out = work / "sim"
    shutil.rmtree(out, ignore_errors=True)
    subprocess.run([markcell, "sim", "paper-door", "--config", str(source / "config" / "cell.example.yaml"), "--seconds",
                    "3.5", "--fps", "10", "--one-predictor", "-q", "--out", str(out)], check=True, stdout=subprocess.DEVNULL)
    for name in ("recording/recording.yaml", "recording/inspection.yaml"):
        if not (out / name).is_file():
            fail(f"markcell sim wrote no {name}")


def cell_config(source, work, port=None, recording=None, extra=()):
    """The shipped example with the recording as the cameras, as an integrator edits it:
    the operator page on `port` (none: off), the recording `recording` (default: the
    fixture's, in WORK_DIR/sim), then the `extra` (pattern, replacement) edits."""
    text = (source / "config" / "cell.example.yaml").read_text()
    config_dir = source / "config"
    recording = recording or work / "sim"
    page = f"\n  operator_page: 127.0.0.1:{port}" if port else ""
    edits = [
        (r"(?m)^  # results_file: \S+", f"  results_file: {work / 'results.jsonl'}"),
        (r"(?m)^  # record_folder: (\S+)(.*)$", rf"  record_folder: {work / 'records'}\2{page}"),
        (r"(?m)^    source: simulated ", "    source: recording "),
        (r"(?m)^    # recording: /path/to/recording", f"    recording: {recording / 'recording'}"),
        (r"(?m)^(  stereo|  base): calibration/", rf"\1: {config_dir}/calibration/"),
        (r"file: panels/", f"file: {config_dir}/panels/"),
        # This host is no real-time host and shares its two cores with Chromium or
        # Prometheus: an overrun is logged here, not a stop (tests of the scheduler
        # cover the stop).
        (r"on_overrun: safe_stop", "on_overrun: log"),
    ] + list(extra)
    for pattern, replacement in edits:
        text, n = re.subn(pattern, replacement, text)
        if n == 0:
            fail(f"cell.example.yaml no longer has what the test edits: {pattern}")
    path = work / "cell.yaml"
    path.write_text(text)
    return path


def record_with_id(recording, panel_id):
    """The recording's inspection record with another panel id (the line tests' records)."""
    text = (recording / "recording" / "inspection.yaml").read_text()
    text, n = re.subn(r"(?m)^panel_id: .*$", f"panel_id: {panel_id}", text)
    if n != 1:
        fail("the inspection record has no panel_id line")
    return text


def start_cell(markcell, source, work, estop_at=None, seconds=14):
    for name in ("records", "results.jsonl", "run.log"):
        p = work / name
        shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
    (work / "records").mkdir()
    shutil.copy(work / "sim" / "recording" / "inspection.yaml", work / "records" / "0001.yaml")
    port = free_port()
    config = cell_config(source, work, port)
    script = "0.5 plc_panel_present 1\n3.7 plc_panel_present 0\n"
    if estop_at is not None:
        script += f"{estop_at} plc_estop 1\n"
    (work / "plc.txt").write_text(script)
    log = open(work / "run.log", "w")
    global STARTED_UTC
    STARTED_UTC = datetime.datetime.now(datetime.timezone.utc)
    cell = subprocess.Popen([markcell, "run", "--config", str(config), "--clock", "real", "--seconds", str(seconds),
                             "--plc-script", str(work / "plc.txt")], stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    wait_for("the operator page answering", lambda: get(url + "/api/state")[0] == 200, 20)
    return cell, url


def wait_cell(cell, work, expect_rc=0):
    """The run's end (60 s at most) with the exit code expected; its log, printed."""
    try:
        rc = cell.wait(timeout=60)
    except subprocess.TimeoutExpired:
        cell.kill()
        fail("markcell run did not end")
    log = (work / "run.log").read_text()
    print(log)
    if rc != expect_rc:
        fail(f"markcell run exited {rc}, expected {expect_rc}")
    return log


def finish_cell(cell, work):
    log = wait_cell(cell, work)
    if f"panel={PANEL} result=done sprayed=3 skipped=0" not in log:
        fail("the run did not mark the door's three defects")
    check_utc(work)
    return log


def check_utc(work):
    """The results file's UTC times against Python's own clock and the cell's seconds."""
    lines = [json.loads(l) for l in (work / "results.jsonl").read_text().splitlines()]
    result = next(l for l in lines if l.get("panel_id") == PANEL and "started_s" in l)
    accepted = next(l for l in lines if l.get("accepted"))

    def utc(text):
        if not re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", text):
            fail(f"not ISO 8601 UTC to the millisecond: {text!r}")
        return datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))

    now = datetime.datetime.now(datetime.timezone.utc)
    for name, text in (("accepted utc", accepted["utc"]), ("started_utc", result["started_utc"]),
                       ("finished_utc", result["finished_utc"])):
        t = utc(text)
        if not STARTED_UTC - datetime.timedelta(seconds=1) <= t <= now:
            fail(f"{name} {text} is not within the run ({STARTED_UTC.isoformat()} to {now.isoformat()})")
    span = (utc(result["finished_utc"]) - utc(result["started_utc"])).total_seconds()
    if abs(span - (result["finished_s"] - result["started_s"])) > 0.002:
        fail(f"finished_utc - started_utc = {span} s, finished_s - started_s = "
             f"{result['finished_s'] - result['started_s']} s")
    print(f"UTC: accepted {accepted['utc']}, panel {result['started_utc']} to {result['finished_utc']}")


def browser(markcell, source, work, screenshot):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By

    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1600,1000",
                f"--user-data-dir={work / 'chromium-profile'}"):
        options.add_argument(arg)
    # The browser first: the panel is under way from 0.5 s to about 3 s of the run.
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    cell = None
    try:
        cell, url = start_cell(markcell, source, work, estop_at=9.0)
        driver.get(url + "/")
        text = lambda id_: driver.find_element(By.ID, id_).text
        # A mark the page keeps only as long as it is not reloaded.
        driver.execute_script("window.markcellTestMark = 'not reloaded';")
        wait_for("the page's first state", lambda: int(text("updates")) >= 1, 10)
        if "markcell · " not in text("cell"):
            fail(f"the page names no cell: {text('cell')!r}")
        # The panel being marked: its id, the badge, a defect being marked or sprayed.
        states_seen = set()

        def marking():
            states_seen.add(text("marking-state"))
            return (PANEL in text("panel-id") and text("badge") == "marking" and
                    re.search(r"\b(marking|sprayed)\b", text("defects")))
        wait_for("the panel being marked", marking, 20)
        # The live view: a JPEG the browser decoded, with the defects drawn (it is asked
        # for again as each one loads).
        wait_for("the live view", lambda: driver.execute_script(
            "const v = document.getElementById('view'); return v.complete && v.naturalWidth > 0;"), 10)
        first_view = driver.execute_script("return document.getElementById('view').src;")
        wait_for("a newer live view", lambda: driver.execute_script(
            "return document.getElementById('view').src;") != first_view, 10)
        wait_for("a defect sprayed", lambda: "sprayed" in text("defects"), 15)
        if screenshot:
            driver.save_screenshot(str(screenshot))
        updates = int(text("updates"))
        wait_for("the panel's result", lambda: (states_seen.add(text("marking-state")) or True) and
                 PANEL in text("results") and "done" in text("results"), 15)
        if len(states_seen) < 2:
            fail(f"the marking state never changed on the page: {states_seen}")
        if int(text("updates")) <= updates:
            fail("the page stopped updating")
        # The e-stop: the fault banner with its reason, the badge, without a reload.
        wait_for("the e-stop's fault", lambda: driver.find_element(By.ID, "fault").is_displayed() and
                 "safe stop" in text("badge") and "operator_stop" in text("fault"), 15)
        print("fault shown:", text("fault"))
        if driver.execute_script("return window.markcellTestMark;") != "not reloaded":
            fail("the page was reloaded")
        print(f"page updated {text('updates')} times; marking states seen: {sorted(states_seen)}")
        # Read-only: anything but GET and HEAD is refused.
        req = urllib.request.Request(url + "/api/state", data=b"{}", method="POST")
        try:
            urllib.request.urlopen(req, timeout=5)
            fail("a POST was accepted")
        except urllib.error.HTTPError as e:
            if e.code != 405:
                fail(f"a POST got {e.code}, not 405")
    finally:
        driver.quit()
        if cell is not None and cell.poll() is None and sys.exc_info()[0] is not None:
            cell.kill()
    log = finish_cell(cell, work)
    if "operator page on " + url + "/" not in log:
        fail("the run did not log the page's address")


def prometheus(markcell, source, work):
    cell, url = start_cell(markcell, source, work)
    port = free_port()
    (work / "prometheus.yml").write_text(
        "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\n"
        "scrape_configs:\n  - job_name: markcell\n    static_configs:\n"
        f"      - targets: ['{url.removeprefix('http://')}']\n")
    shutil.rmtree(work / "prometheus-data", ignore_errors=True)
    server = subprocess.Popen(["prometheus", f"--config.file={work / 'prometheus.yml'}",
                               f"--storage.tsdb.path={work / 'prometheus-data'}",
                               f"--web.listen-address=127.0.0.1:{port}"],
                              stdout=subprocess.DEVNULL, stderr=open(work / "prometheus.log", "w"))
    try:
        api = f"http://127.0.0.1:{port}/api/v1/query?query="

        def query(expr):
            status, _, body = get(api + urllib.parse.quote(expr))
            data = json.loads(body)
            if data["status"] != "success":
                raise RuntimeError(data)
            return {json.dumps(r["metric"], sort_keys=True): float(r["value"][1]) for r in data["data"]["result"]}

        wait_for("Prometheus scraping markcell (up == 1)",
                 lambda: list(query('up{job="markcell"}').values()) == [1.0], 30)
        frames = wait_for("frames counted", lambda: query("markcell_vision_frames_total"), 10)
        print("markcell_vision_frames_total:", frames)
        runs = wait_for("the vision task's runs", lambda: query('markcell_task_exec_seconds_count{task="vision"}'), 10)
        print("vision runs:", runs)
        done = wait_for("the panel counted done",
                        lambda: query('markcell_panels_total{result="done"} == 1'), 20)
        print("panels done:", done)
        sprayed = query('markcell_defects_total{outcome="sprayed"}')
        if list(sprayed.values()) != [3.0]:
            fail(f"markcell_defects_total{{outcome=\"sprayed\"}} is {sprayed}, not 3")
        # The text format itself, by Prometheus's own linter.
        _, headers, body = get(url + "/metrics")
        if not headers["Content-Type"].startswith("text/plain; version=0.0.4"):
            fail(f"/metrics has Content-Type {headers['Content-Type']}")
        lint = subprocess.run(["promtool", "check", "metrics"], input=body, capture_output=True)
        print("promtool check metrics:", lint.returncode, lint.stdout.decode(), lint.stderr.decode())
        if lint.returncode != 0:
            fail("promtool refused the metrics")
    finally:
        server.terminate()
        server.wait(timeout=30)
    finish_cell(cell, work)


def main(argv):
    if len(argv) < 5:
        print(__doc__, file=sys.stderr)
        return 2
    markcell, source, work, mode = argv[1], pathlib.Path(argv[2]).resolve(), pathlib.Path(argv[3]).resolve(), argv[4]
    work.mkdir(parents=True, exist_ok=True)
    if mode == "recording":
        make_recording(markcell, source, work)
    elif mode == "browser":
        screenshot = pathlib.Path(argv[argv.index("--screenshot") + 1]) if "--screenshot" in argv else None
        browser(markcell, source, work, screenshot)
    elif mode == "prometheus":
        prometheus(markcell, source, work)
    else:
        print(__doc__, file=sys.stderr)
        return 2
    print("ok")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
