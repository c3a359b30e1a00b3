"""``climbd estop``: engage a robot's e-stop over Zenoh, reliably and repeatedly; or reset it.

Engaging needs no session (anyone authorised may stop the robot); resetting is an explicit
act of a session holder, so the command claims a session, resets, and releases it.
"""

from __future__ import annotations

import argparse
import os
import socket
import time
import uuid

from climbd.daemon.cli.client import add_credential_arguments, open_client
from climbd.daemon.contract.messages import EStop, ModeRequest, SessionClaim

REPEAT_HZ = 10.0
REPEAT_FOR = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name (profile name)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("--reason", default="operator", help="why (logged by the robot)")
    parser.add_argument("--reset", action="store_true", help="reset a latched e-stop or fault")
    add_credential_arguments(parser)


def main(args: argparse.Namespace) -> int:
    source = f"{socket.gethostname()}:{os.getpid()}"
    net = open_client(args, args.robot, "estop")
    if net is None:
        return 2
    try:
        time.sleep(0.3)  # let the session connect before the first (reliable) put
        if args.reset:
            session = uuid.uuid4().hex
            net.publisher(SessionClaim).put(
                SessionClaim(stamp=time.time(), session=session, client=source)
            )
            time.sleep(0.1)
            net.publisher(ModeRequest).put(
                ModeRequest(stamp=time.time(), session=session, reset=True)
            )
            time.sleep(0.1)
            net.publisher(SessionClaim).put(
                SessionClaim(session=session, client=source, release=True)
            )
            print(f"reset sent to {args.robot}")
            return 0
        pub = net.publisher(EStop)
        for _ in range(int(REPEAT_HZ * REPEAT_FOR)):
            pub.put(EStop(stamp=time.time(), engage=True, source=source, reason=args.reason))
            time.sleep(1.0 / REPEAT_HZ)
        print(f"e-stop sent to {args.robot} ({int(REPEAT_HZ * REPEAT_FOR)} times)")
        return 0
    finally:
        net.close()
