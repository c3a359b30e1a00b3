"""An attacker on plain Zenoh: run as its own process (``python zenoh_attack.py SPEC``).

It imports nothing of climbd, so it does only what any Zenoh peer or client could: SPEC is a
JSON object with ``mode`` ("peer"/"client"), ``connect`` and ``listen`` endpoints, optional
``user``/``password``, ``robot``, and one ``attack``:

- ``puts``: put each of ``messages`` (``{"key": ..., "fields": {...}}``, payloads msgpack-encoded
  as the contract's messages are) ``repeat`` times, every ``period`` s;
- ``session``: claim the session (on ``claim_key``, default cmd/session), send heartbeats with a
  rising ``seq`` for ``seconds``, put ``messages`` after ``after`` s, then release;
- ``replay``: capture the heartbeats another client sends to the ``capture`` endpoint (a
  second session of this process, checking its peers against the ``dictionary`` file), and
  once that client falls silent, send them again, in order, for ``seconds``.

It prints one JSON line per notable event, for the test to read.
"""

from __future__ import annotations

import json
import sys
import time

import msgspec
import zenoh

SCHEMA = 1
"""The contract's schema version (daemon/contract/messages.py SCHEMA_VERSION)."""


def open_session(spec: dict) -> zenoh.Session:
    """A Zenoh session as ``spec`` describes: mode, endpoints, user/password."""
    cfg = zenoh.Config()
    cfg.insert_json5("mode", json.dumps(spec.get("mode", "peer")))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    cfg.insert_json5("connect/endpoints", json.dumps(spec.get("connect", [])))
    cfg.insert_json5("listen/endpoints", json.dumps(spec.get("listen", [])))
    if spec.get("user"):
        usrpwd = {"user": spec["user"], "password": spec["password"]}
        if spec.get("dictionary"):
            usrpwd["dictionary_file"] = spec["dictionary"]
        cfg.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    return zenoh.open(cfg)


def payload(fields: dict) -> bytes:
    """A contract message payload: msgpack of the fields with schema and stamp."""
    return msgspec.msgpack.encode({"schema": SCHEMA, "stamp": time.monotonic(), **fields})


def report(**event: object) -> None:
    print(json.dumps(event), flush=True)


def puts(session: zenoh.Session, spec: dict) -> None:
    """Put each message ``repeat`` times, ``period`` s apart."""
    robot = spec["robot"]
    for _ in range(spec.get("repeat", 1)):
        for m in spec["messages"]:
            session.put(f"climbd/{robot}/{m['key']}", payload(m["fields"]))
        time.sleep(spec.get("period", 0.1))
    report(event="sent")


def hold_session(session: zenoh.Session, spec: dict) -> None:
    """Claim, heartbeat with rising seq and stamp, put the messages after ``after`` s,
    release: a well-behaved client except for what ``messages`` asks."""
    robot, name, sid = spec["robot"], spec["user"], f"{spec['user']}-session"
    claim = {"session": sid, "client": name, **spec.get("claim", {})}
    session.put(f"climbd/{robot}/{spec.get('claim_key', 'cmd/session')}", payload(claim))
    start = time.monotonic()
    seq, sent = 0, False
    while time.monotonic() - start < spec["seconds"]:
        seq += 1
        session.put(f"climbd/{robot}/cmd/heartbeat", payload({"session": sid, "seq": seq}))
        if not sent and time.monotonic() - start >= spec.get("after", 0.3):
            for m in spec.get("messages", []):
                session.put(f"climbd/{robot}/{m['key']}", payload({"session": sid, **m["fields"]}))
            sent = True
            report(event="sent", session=sid)
        time.sleep(0.05)
    session.put(f"climbd/{robot}/cmd/session", payload({"session": sid, "release": True}))
    time.sleep(0.2)


def replay(session: zenoh.Session, spec: dict) -> None:
    """Capture heartbeats until their sender is silent for ``silence`` s, then send them
    again, in order and cycling, every 50 ms for ``seconds``."""
    captured: list[bytes] = []
    heard = [0.0]

    def capture(sample: zenoh.Sample) -> None:
        captured.append(bytes(sample.payload.to_bytes()))
        heard[0] = time.monotonic()

    listener = open_session({**spec, "connect": [], "listen": spec["capture"]})
    sub = listener.declare_subscriber(f"climbd/{spec['robot']}/cmd/heartbeat", capture)
    report(event="listening")
    while len(captured) < spec.get("min_captured", 10) or (
        time.monotonic() - heard[0] < spec.get("silence", 0.05)
    ):
        time.sleep(0.01)
    sub.undeclare()
    listener.close()
    last = msgspec.msgpack.decode(captured[-1])
    report(event="captured", count=len(captured), session=last["session"], stamp=last["stamp"])
    pub = session.declare_publisher(f"climbd/{spec['robot']}/cmd/heartbeat")
    end = time.monotonic() + spec["seconds"]
    k = 0
    while time.monotonic() < end:
        pub.put(captured[k % len(captured)])
        k += 1
        time.sleep(0.05)
    report(event="replayed", count=k)


ATTACKS = {"puts": puts, "session": hold_session, "replay": replay}


def main() -> None:
    spec = json.loads(sys.argv[1])
    session = open_session(spec)
    time.sleep(spec.get("settle", 0.5))  # routes and subscriptions are exchanged
    try:
        ATTACKS[spec["attack"]](session, spec)
    finally:
        session.close()


if __name__ == "__main__":
    main()
