#!/usr/bin/env python3
"""`markcell config-schema` checked by an independent validator (python3-jsonschema).

The schema must be a valid draft-07 schema, accept the example configuration, and agree
with the loader (`markcell check-config`) on each broken copy below: both reject it, the
loader naming the key path. The example's values for the declared sections must be the
schema's defaults (the example documents them).

usage: check_config_schema.py MARKCELL CONFIG_DIR
"""
import copy
import json
import pathlib
import shutil
import subprocess
import sys
import tempfile

import jsonschema
import yaml

markcell, config_dir = sys.argv[1], pathlib.Path(sys.argv[2])
failures = []


def fail(msg):
    failures.append(msg)
    print("FAIL:", msg)


schema_text = subprocess.run([markcell, "config-schema"], check=True, capture_output=True, text=True).stdout
schema = json.loads(schema_text)
jsonschema.Draft7Validator.check_schema(schema)
validator = jsonschema.Draft7Validator(schema)

example = yaml.safe_load((config_dir / "cell.example.yaml").read_text())
errors = [e.message for e in validator.iter_errors(example)]
if errors:
    fail(f"the example is rejected by the schema: {errors}")

# The example writes every declared key of these sections at its default.
props = schema["properties"]
declared = {
    "vision": (props["vision"], example["vision"]),
    "marking": (props["marking"], example["marking"]),
    "spray": (props["spray"], example["spray"]),
    "devices.arm.limits": (props["devices"]["properties"]["arm"]["properties"]["limits"], example["devices"]["arm"]["limits"]),
}
for name, (section, written) in declared.items():
    for key, p in section["properties"].items():
        if key not in written:
            fail(f"{name}.{key}: declared, not written in the example")
        elif written[key] != p["default"] and not (
            isinstance(written[key], float) and abs(written[key] - p["default"]) < 1e-9 * max(1, abs(written[key]))
        ):
            fail(f"{name}.{key}: the example writes {written[key]!r}, the declared default is {p['default']!r}")
    for key in written:
        if key not in section["properties"]:
            fail(f"{name}.{key}: written in the example, not declared")


def put(doc, path, value):
    *parents, last = path.split(".")
    for k in parents:
        doc = doc[k]
    if value is DELETE:
        del doc[last]
    else:
        doc[last] = value


DELETE = object()
# (what is broken, the key path the loader must name)
broken = [
    ("marking.settle_deg", 45, "marking.settle_deg"),              # above its range
    ("vision.lk_window_px", 20, "vision.lk_window_px"),            # even
    ("vision.spray_ms", 3, "vision.spray_ms"),                     # unknown key
    ("spray.pulse_ms", DELETE, "spray.pulse_ms"),                  # required, missing
    ("devices.arm.limits.reach_m", "far", "devices.arm.limits.reach_m"),  # not a number
    ("devices.arm.limits.home_m", [0.3, 0.0], "devices.arm.limits.home_m"),  # two numbers, not three
    ("marking.predictor", "kalmann", "marking.predictor"),         # not a choice
    ("marking.record_timeout_s", 0.01, "marking.record_timeout_s"),  # below its range
    ("executive.tasks.vision_track", {"lane": "vision", "period_us": 33000, "budget_us": 100}, "executive.tasks.vision_track"),
    ("extras", {"a": 1}, "extras"),                                # unknown section
    ("devices.arm.can.node_id", 200, "devices.arm.can.node_id"),   # above its range
    ("devices.arm.serial.baud", "fast", "devices.arm.serial.baud"),  # not an integer
    ("devices.gpio.input_filter_us", 200000, "devices.gpio.input_filter_us"),  # above its range
    ("devices.gpio.lines.plc_done", DELETE, "devices.gpio.lines.plc_done"),  # a role without its line
    ("devices.cameras.trigger", "line0", "devices.cameras.trigger"),  # not a choice
    ("watchdog.device.timeout_s", -1, "watchdog.device.timeout_s"),  # below its range
    ("safe_stop.rearm", "sometimes", "safe_stop.rearm"),           # not a choice
    ("executive.lanes.control.priority", 120, "executive.lanes.control.priority"),  # above its range
    ("executive.base_tick_us", 10, "executive.base_tick_us"),      # below its range
    ("base_calibration.board.cols", 2, "base_calibration.board.cols"),  # below its range
    ("panel_types.door.macro_features", 40, "panel_types.door.macro_features"),  # above its range
]

with tempfile.TemporaryDirectory() as tmp:
    # A copy of the config folder: the example's relative calibration paths resolve.
    folder = pathlib.Path(tmp) / "config"
    shutil.copytree(config_dir, folder)
    target = folder / "cell.yaml"

    def check_config(doc):
        target.write_text(yaml.safe_dump(doc, sort_keys=False))
        r = subprocess.run([markcell, "check-config", str(target)], capture_output=True, text=True)
        return r.returncode, r.stderr

    rc, err = check_config(example)
    if rc != 0:
        fail(f"the example, dumped again, is refused by check-config: {err}")
    for path, value, key_path in broken:
        doc = copy.deepcopy(example)
        put(doc, path, value)
        schema_errors = list(validator.iter_errors(doc))
        if not schema_errors:
            fail(f"{path} = {value!r}: accepted by the schema")
        rc, err = check_config(doc)
        if rc != 2:
            fail(f"{path} = {value!r}: check-config exit {rc}, expected 2")
        elif f": {key_path}:" not in err:
            fail(f"{path} = {value!r}: check-config does not name {key_path}: {err}")
        else:
            shown = "(missing)" if value is DELETE else repr(value)
            print(f"ok: {path} = {shown}: schema ({schema_errors[0].message}) and loader ({err.splitlines()[0]})")

if failures:
    sys.exit(f"{len(failures)} failure(s)")
print("schema and loader agree on the example and on", len(broken), "broken copies")
