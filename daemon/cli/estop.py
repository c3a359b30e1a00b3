"""``climbd estop``: engage a robot's e-stop over Zenoh and confirm it; or reset it.

Engaging needs no session (anyone authorised may stop the robot); resetting is an explicit
act of a session holder, so the command claims a session, resets, and releases it (the robot
is then in HOLD or OFF, which the release leaves as it is).

Nothing counts as done until the robot's mode says so (daemon/cli/confirm.py): the command
exits 0 only then, and otherwise 1 naming what happened: no robot answered, the robot refused
(its mode unchanged, with its reason), or nothing was confirmed within ``--timeout``.
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import time

from climbd.daemon.cli.client import add_credential_arguments, open_client
from climbd.daemon.cli.confirm import DEFAULT_TIMEOUT, Unconfirmed, latched
from climbd.daemon.cli.teleop import TeleopClient
from climbd.daemon.contract.messages import ModeState


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", required=True, help="robot name (profile name)")
    parser.add_argument(
        "--connect", action="append", default=[], help="Zenoh endpoint of the robot (repeatable)"
    )
    parser.add_argument("--reason", default="operator", help="why (logged by the robot)")
    parser.add_argument("--reset", action="store_true", help="reset a latched e-stop or fault")
    parser.add_argument(
        "--timeout",
        type=float,
        default=DEFAULT_TIMEOUT,
        help=f"seconds to wait for the robot to confirm (default {DEFAULT_TIMEOUT:g})",
    )
    add_credential_arguments(parser)


def claim_and_reset(client: TeleopClient) -> ModeState:
    """Reset as a session holder: only a latched robot is claimed (a release would hold one
    running under autonomy), then reset, confirmed, and released again by ``client.close``."""
    latched(client.watch)
    client.claim()
    return client.reset()


def main(args: argparse.Namespace) -> int:
    source = f"{socket.gethostname()}:{os.getpid()}"
    net = open_client(args, args.robot, "estop")
    if net is None:
        return 2
    client = TeleopClient(net, source, endpoints=args.connect, timeout=args.timeout)
    client.start()
    start = time.monotonic()
    try:
        if args.reset:
            state, done = claim_and_reset(client), "reset"
        else:
            state, done = client.estop(args.reason), "e-stop engaged"
    except Unconfirmed as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    finally:
        if client.close():
            time.sleep(0.1)  # let the release leave before the session closes
        net.close()
    took = time.monotonic() - start
    print(f"{done} on {args.robot}: {state.mode.value} ({state.reason}), confirmed in {took:.2f} s")
    return 0
