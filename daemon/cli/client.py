"""What the operator tools (estop, status, teleop, top, record, replay, view) share at start-up:
their credential options, the Zenoh config from ``--connect`` and ``--tls``/``--user``, and the
robot's profile where a tool needs it (view, record --scene)."""

from __future__ import annotations

import argparse
import os
import sys

import zenoh

from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime.access import AccessError, client_credentials
from climbd.daemon.runtime.certificates import DEFAULT_DIR, default_credentials
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config


def add_credential_arguments(parser) -> None:
    """Options of operator tools (teleop, estop, status) for a robot with network.auth."""
    parser.add_argument(
        "--tls",
        nargs=3,
        metavar=("CA", "CERT", "KEY"),
        help="mutual TLS: CA certificate, this operator's certificate and key (climbd certs; "
        f"default: {DEFAULT_DIR}/ca.pem, operator.pem, operator.key when present)",
    )
    parser.add_argument("--user", help="Zenoh user name (password from $CLIMBD_PASSWORD)")


def client_config(args, role: str) -> zenoh.Config:
    """Zenoh config of an operator tool: its --connect endpoints and --tls/--user credentials,
    or without either the operator's certificate in DEFAULT_DIR when it is there."""
    cfg = zenoh_config(None, role, Endpoints([], list(args.connect)))
    user = None
    if args.user:
        password = os.environ.get("CLIMBD_PASSWORD")
        if password is None:
            raise AccessError("--user needs the password in $CLIMBD_PASSWORD")
        user = (args.user, password)
    tls = tuple(args.tls) if args.tls else None
    if tls is None and user is None:
        tls = default_credentials()
    client_credentials(cfg, tls, user)
    return cfg


def open_client(args: argparse.Namespace, robot: str, role: str) -> Network | None:
    """The operator tool's Zenoh session on ``robot``'s keys, or None once it has said on
    stderr why it cannot open one (its ``main`` then exits 2)."""
    try:
        return Network(robot, client_config(args, role))
    except AccessError as e:
        print(f"error: {e}", file=sys.stderr)
        return None


def find_profile(robot: str, path: str | None) -> profiles.Profile:
    """``path``'s profile, or the stock profile named ``robot``; ProfileError when neither."""
    if path is not None:
        return profiles.load(path)
    stock = profiles.stock_profiles()
    if robot in stock:
        return profiles.load(stock[robot])
    raise profiles.ProfileError(
        f"no stock profile for robot {robot!r} (stock: {', '.join(sorted(stock))}): "
        "pass --profile with the robot's profile"
    )
