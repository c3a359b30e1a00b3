"""The wire contract is usable by third parties: a client written only against ``zenoh``, a
msgpack codec and the JSON Schema that ``climbd schema`` writes reads telemetry and drives.

Nothing of climbd is imported by the client below: it finds keys and fields in the schema
document, decodes msgpack maps into plain dicts (msgspec is used as a bare msgpack codec) and
checks them against the schema with the small validator here.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import threading
import time

import msgspec
import zenoh
from support.zenoh_roles import ROOT, Proc

JSON_TYPES = {
    "number": (int, float),
    "integer": (int,),
    "string": (str,),
    "boolean": (bool,),
    "array": (list,),
    "object": (dict,),
    "null": (type(None),),
}


def validate(value, schema: dict, defs: dict, where: str = "$") -> None:
    """Check ``value`` against a JSON Schema subset (type, enum, $ref, anyOf, items, maps)."""
    if "$ref" in schema:
        return validate(value, defs[schema["$ref"].rsplit("/", 1)[1]], defs, where)
    if "anyOf" in schema:
        errors = []
        for option in schema["anyOf"]:
            try:
                return validate(value, option, defs, where)
            except AssertionError as e:
                errors.append(str(e))
        raise AssertionError(f"{where}: matches none of {errors}")
    if "enum" in schema:
        assert value in schema["enum"], f"{where}: {value!r} not in {schema['enum']}"
    kind = schema.get("type")
    if kind is not None:
        ok = isinstance(value, JSON_TYPES[kind]) and not (
            kind in ("number", "integer") and isinstance(value, bool)
        )
        assert ok, f"{where}: expected {kind}, found {type(value).__name__}"
    if kind == "array" and "items" in schema:
        for i, item in enumerate(value):
            validate(item, schema["items"], defs, f"{where}[{i}]")
    if kind == "object":
        props = schema.get("properties", {})
        for name in schema.get("required", []):
            assert name in value, f"{where}: missing {name}"
        for name, item in value.items():
            if name in props:
                validate(item, props[name], defs, f"{where}.{name}")
            elif schema.get("additionalProperties") is False:
                raise AssertionError(f"{where}: unexpected field {name}")
            elif isinstance(schema.get("additionalProperties"), dict):
                validate(item, schema["additionalProperties"], defs, f"{where}.{name}")


class ThirdPartyClient:
    """Reads and writes climbd topics with nothing but zenoh, msgpack and the schema document."""

    def __init__(self, schema: dict, robot: str, endpoint: str) -> None:
        self.schema, self.robot = schema, robot
        self.topics = {v["type"]: k for k, v in schema["topics"].items()}
        cfg = zenoh.Config()
        cfg.insert_json5("mode", '"peer"')
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("connect/endpoints", json.dumps([endpoint]))
        self.session = zenoh.open(cfg)
        self.received: dict[str, list[dict]] = {}
        self.lock = threading.Lock()
        self.subs = []

    def key(self, type_name: str) -> str:
        return f"climbd/{self.robot}/{self.topics[type_name]}"

    def read(self, type_name: str) -> None:
        def on_sample(sample: zenoh.Sample) -> None:
            value = msgspec.msgpack.decode(sample.payload.to_bytes())
            with self.lock:
                self.received.setdefault(type_name, []).append(value)

        self.received[type_name] = []
        self.subs.append(self.session.declare_subscriber(self.key(type_name), on_sample))

    def latest(self, type_name: str, pred=lambda v: True, timeout: float = 30.0) -> dict:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self.lock:
                found = [v for v in self.received[type_name] if pred(v)]
            if found:
                return found[-1]
            time.sleep(0.05)
        raise AssertionError(f"no {type_name} matching within {timeout} s")

    def send(self, type_name: str, **fields) -> None:
        message = {"schema": self.schema["schema_version"], "stamp": time.monotonic(), **fields}
        validate(message, self.schema["$defs"][type_name], self.schema["$defs"])
        self.session.put(self.key(type_name), msgspec.msgpack.encode(message))

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()
        self.session.close()


def test_third_party_client_reads_telemetry_and_drives(endpoint: str, tmp_path) -> None:
    schema_file = tmp_path / "climbd-schema.json"
    subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "schema", "-o", str(schema_file)],
        cwd=ROOT,
        check=True,
    )
    schema = json.loads(schema_file.read_text())
    defs = schema["$defs"]
    robot = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                 "--gait", "tripod", "--listen", endpoint)  # fmt: skip
    client = ThirdPartyClient(schema, "widowx", endpoint)
    beating = threading.Event()
    try:
        for t in ("Health", "JointState", "ModeState"):
            client.read(t)
        client.latest("ModeState", lambda v: v["mode"] == "HOLD", 60)
        health = client.latest("Health", lambda v: v["role"] == "control")
        joints = client.latest("JointState")
        validate(health, defs["Health"], defs)
        validate(joints, defs["JointState"], defs)
        assert len(joints["names"]) == len(joints["position"]) == 18

        client.send("SessionClaim", session="tp-1", client="third-party")

        def heartbeat() -> None:
            seq = 0
            while not beating.wait(0.05):
                seq += 1
                client.send("Heartbeat", session="tp-1", seq=seq)

        threading.Thread(target=heartbeat, daemon=True).start()
        time.sleep(0.2)
        client.send("ModeRequest", session="tp-1", mode="ACTIVE")
        active = client.latest("ModeState", lambda v: v["mode"] == "ACTIVE")
        start = client.latest("JointState", lambda v: v["stamp"] > active["stamp"])
        refused = client.latest("Health", lambda v: v["stamp"] > active["stamp"])[
            "refused_commands"
        ]
        for _ in range(40):
            client.send("MotionCommand", session="tp-1", vx=0.04)
            time.sleep(0.05)
        moved = client.latest("JointState")
        step = max(abs(a - b) for a, b in zip(moved["position"], start["position"], strict=True))
        assert step > 0.05, f"walking moves the joints (largest change {step:.3f} rad)"
        sent_at = time.monotonic()
        after = client.latest("Health", lambda v: v["role"] == "control" and v["stamp"] > sent_at)
        assert after["refused_commands"] == refused, "the motion commands were accepted"
        assert after["mode"] == "ACTIVE" and not math.isnan(after["loop"]["rate_hz"])

        client.send("MotionCommand", session="not-mine", vx=0.04)
        sent_at = time.monotonic()
        later = client.latest("Health", lambda v: v["role"] == "control" and v["stamp"] > sent_at)
        assert later["refused_commands"] == refused + 1, "a foreign session is refused, counted"
        beating.set()
        client.send("SessionClaim", session="tp-1", client="third-party", release=True)
        assert robot.stop() == 0
    finally:
        beating.set()
        client.close()
        robot.kill()
