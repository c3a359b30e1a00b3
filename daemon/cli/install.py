"""``climbd install``: write the systemd units and udev rules for this machine's paths.

Renders ``systemd/*.service.in`` with the robot's profile, the climbd executable, the user
and the working directory, and copies the udev rules. It validates the profile first, so a
unit never starts a daemon that would refuse its profile. With ``--torque-bridge`` (torque
legs) it adds the bridge's unit and a drop-in that points the control role at it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime.access import AccessError, check_network

ROOT = Path(__file__).resolve().parents[2]
"""The climbd package root: systemd/ and docs/ are shipped beside daemon/."""
ROLES = ("control", "perception")
BRIDGE_ENDPOINT = "127.0.0.1:47170"
CONTROL_ENDPOINT = "127.0.0.1:47171"
"""Loopback UDP endpoints of the torque bridge and of the control role that it serves."""
BRIDGE_DROP_IN = "climbd-control.service.d/torque-bridge.conf"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--profile", required=True, help="robot profile the units will run")
    parser.add_argument(
        "--role", choices=[*ROLES, "all"], default="all", help="which role(s) run on this computer"
    )
    parser.add_argument("--user", default="climbd", help="user the daemon runs as")
    parser.add_argument("--workdir", default="/var/lib/climbd", help="state/recording directory")
    parser.add_argument("--unit-dir", default="/etc/systemd/system", help="where units go")
    parser.add_argument("--udev-dir", default="/etc/udev/rules.d", help="where udev rules go")
    parser.add_argument(
        "--climbd",
        default=shutil.which("climbd") or f"{sys.prefix}/bin/climbd",
        help="path of the climbd executable",
    )
    parser.add_argument(
        "--torque-bridge",
        action="store_true",
        help="torque legs: run the MIT driver as climbd-torque-bridge beside the control role",
    )
    parser.add_argument(
        "--python", default=sys.executable, help="Python of climbd's environment (the bridge's)"
    )


def render(template: str, **fields: object) -> str:
    """The text of ``systemd/TEMPLATE`` with ``fields`` (and the docs directory) filled in."""
    text = (ROOT / "systemd" / template).read_text()
    return text.format(docs=ROOT / "docs", **fields)


def bridge_refusal(path: Path, kind: str, role: str) -> str | None:
    """Why the torque bridge cannot go with this profile and role, or None."""
    if kind != "torque":
        return f"{path}: bus.kind is {kind!r}; the bridge serves torque legs (kind 'torque')"
    if role not in ("control", "all"):
        return f"the bridge runs beside the control role, not --role {role}"
    return None


def bridge_files(args: argparse.Namespace, profile_path: Path, robot: str) -> dict[str, str]:
    """The torque bridge's unit and the control role's drop-in, by path under the unit dir."""
    listen = f"{BRIDGE_ENDPOINT}/{CONTROL_ENDPOINT}"
    return {
        "climbd-torque-bridge.service": render(
            "climbd-torque-bridge.service.in",
            robot=robot,
            profile=profile_path,
            python=args.python,
            listen=listen,
            user=args.user,
            workdir=args.workdir,
        ),
        BRIDGE_DROP_IN: render(
            "climbd-control-torque-bridge.conf.in",
            climbd=args.climbd,
            profile=profile_path,
            port=f"{CONTROL_ENDPOINT}/{BRIDGE_ENDPOINT}",
        ),
    }


def main(args: argparse.Namespace) -> int:
    path = Path(args.profile).resolve()
    try:
        profile = profiles.load(path)
        check_network(profile)
    except (profiles.ProfileError, AccessError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    roles = ROLES if args.role == "all" else (args.role,)
    refusal = bridge_refusal(path, profile.bus.kind, args.role) if args.torque_bridge else None
    if refusal:
        print(f"error: --torque-bridge: {refusal}", file=sys.stderr)
        return 2
    files = {
        f"climbd-{role}.service": render(
            f"climbd-{role}.service.in",
            robot=profile.name,
            profile=path,
            climbd=args.climbd,
            user=args.user,
            workdir=args.workdir,
        )
        for role in roles
    }
    if args.torque_bridge:
        files |= bridge_files(args, path, profile.name)
    unit_dir, udev_dir = Path(args.unit_dir), Path(args.udev_dir)
    try:
        udev_dir.mkdir(parents=True, exist_ok=True)
        for name, text in files.items():
            unit = unit_dir / name
            unit.parent.mkdir(parents=True, exist_ok=True)
            unit.write_text(text)
            print(f"wrote {unit}")
        stale = unit_dir / BRIDGE_DROP_IN
        if "control" in roles and not args.torque_bridge and stale.exists():
            stale.unlink()
            print(f"removed {stale} (the control role drives its legs in-process)")
        rules = udev_dir / "99-climbd.rules"
        shutil.copyfile(ROOT / "systemd" / "99-climbd.rules", rules)
        print(f"wrote {rules}")
    except PermissionError as e:
        print(
            f"error: {e.filename}: permission denied (run as root, or pass --unit-dir/--udev-dir)",
            file=sys.stderr,
        )
        return 1
    units = " ".join(name.removesuffix(".service") for name in files if name.endswith(".service"))
    auth = profile.network.auth
    if auth is not None and auth.create_certificates:
        print(
            "certificates: the control role's first start creates them where the profile's "
            f"network.auth names them ({auth.tls_root_ca}, ~ being {args.workdir}, the home of "
            f"{args.user}); its journal says how operators get theirs (docs/access.md)"
        )
    print(
        "next:\n"
        f"  useradd --system --home {args.workdir} --create-home "
        f"--groups dialout,plugdev {args.user}\n"
        "  udevadm control --reload && udevadm trigger\n"
        f"  systemctl daemon-reload && systemctl enable --now {units}"
    )
    return 0
