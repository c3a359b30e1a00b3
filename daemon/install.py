"""``climbd install``: write the systemd units and udev rules for this machine's paths.

Renders ``systemd/*.service.in`` with the robot's profile, the climbd executable, the user
and the working directory, and copies the udev rules. It validates the profile first, so a
unit never starts a daemon that would refuse its profile.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
ROLES = ("control", "perception")


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


def render(role: str, profile_path: Path, robot: str, climbd: str, user: str, workdir: str) -> str:
    """The unit file text for ``role``."""
    template = (ROOT / "systemd" / f"climbd-{role}.service.in").read_text()
    return template.format(
        robot=robot,
        profile=profile_path,
        climbd=climbd,
        user=user,
        workdir=workdir,
        docs=ROOT / "docs",
    )


def main(args: argparse.Namespace) -> int:
    from daemon import profile as profiles

    path = Path(args.profile).resolve()
    try:
        profile = profiles.load(path)
    except profiles.ProfileError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    roles = ROLES if args.role == "all" else (args.role,)
    unit_dir, udev_dir = Path(args.unit_dir), Path(args.udev_dir)
    try:
        unit_dir.mkdir(parents=True, exist_ok=True)
        udev_dir.mkdir(parents=True, exist_ok=True)
        for role in roles:
            unit = unit_dir / f"climbd-{role}.service"
            unit.write_text(render(role, path, profile.name, args.climbd, args.user, args.workdir))
            print(f"wrote {unit}")
        rules = udev_dir / "99-climbd.rules"
        shutil.copyfile(ROOT / "systemd" / "99-climbd.rules", rules)
        print(f"wrote {rules}")
    except PermissionError as e:
        print(
            f"error: {e.filename}: permission denied (run as root, or pass --unit-dir/--udev-dir)",
            file=sys.stderr,
        )
        return 1
    units = " ".join(f"climbd-{r}" for r in roles)
    print(
        "next:\n"
        f"  useradd --system --home {args.workdir} --create-home "
        f"--groups dialout,plugdev {args.user}\n"
        "  udevadm control --reload && udevadm trigger\n"
        f"  systemctl daemon-reload && systemctl enable --now {units}"
    )
    return 0
