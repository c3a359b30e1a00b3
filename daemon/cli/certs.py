"""``climbd certs``: a certificate authority and one certificate per role or operator, for mTLS.

``climbd certs NAME… -o DIR`` issues certificates whose CN names each role or operator (the
identities of ``network.auth.rights``). ``climbd certs --profile P`` makes a profile that
listens beyond this computer safe: certificates for its roles and operator beside it, and an
``[network.auth]`` table with its endpoints moved to ``tls/`` (docs/access.md).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime.access import (
    AccessError,
    certificate_dir,
    check_network,
    endpoint_hosts,
    identities,
)
from climbd.daemon.runtime.certificates import DEFAULT_SANS, OPERATOR, generate, missing

AUTH_TABLE = """
[network.auth]  # written by `climbd certs --profile`: mutual TLS, docs/access.md
tls_root_ca = "{out}/ca.pem"
tls_certificate = "{out}/{{role}}.pem"
tls_private_key = "{out}/{{role}}.key"
create_certificates = true
commanders = ["{operator}"]
"""
PLAIN_ENDPOINT = re.compile(r"""(["'])tcp/""")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="*", help="roles and operators, e.g. control perception alice"
    )
    parser.add_argument("-o", "--out", help="directory to write (default: certs, or the profile's)")
    parser.add_argument(
        "--profile",
        help="make this profile safe: certificates for its roles and operators, and its "
        "[network.auth] table if it has none",
    )
    parser.add_argument(
        "--san",
        action="append",
        help="host name or IP peers dial, repeatable (default: localhost, 127.0.0.1)",
    )
    parser.add_argument("--days", type=int, default=825, help="validity in days (default 825)")


def secured_text(text: str, out: str) -> str:
    """``text`` of a profile with its plain ``tcp/`` endpoints made ``tls/`` and an
    ``[network.auth]`` table for certificates in ``out`` (relative to the profile) appended."""
    text = PLAIN_ENDPOINT.sub(r"\1tls/", text)
    return text.rstrip("\n") + "\n" + AUTH_TABLE.format(out=out, operator=OPERATOR)


def secure_profile(path: Path, out: Path | None, sans: list[str], days: int) -> int:
    """Give the profile at ``path`` mutual TLS (see the module docstring); 0 when it is safe."""
    profile = profiles.load(path)
    auth = profile.network.auth
    if auth is not None and not auth.tls_root_ca:
        check_network(profile)
        print(f"{path}: authenticates by user and password already (network.auth.user)")
        return 0
    if auth is None:
        out = out or path.parent / "certs"
        relative = os.path.relpath(out.resolve(), path.parent.resolve())
        text = secured_text(path.read_text(), Path(relative).as_posix())
        trial = path.with_name(f".{path.name}.climbd-certs")
        trial.write_text(text)
        try:
            profile = profiles.load(trial)
            check_network(profile)
        except (profiles.ProfileError, AccessError) as e:
            trial.unlink()
            print(f"error: {e} (the profile was left as it was)", file=sys.stderr)
            return 1
        os.replace(trial, path)
        profile = profiles.load(path)
        print(f"{path}: network.auth added (mutual TLS, certificates in {out}), endpoints tls/")
    out = certificate_dir(profile)
    names = missing(out, dict.fromkeys([*identities(profile.network.auth), OPERATOR]))
    if names:
        ca, issued = generate(out, names, endpoint_hosts(profile, names=sans), days)
        report(ca, issued)
    print(f"{path}: ok; operators connect with --tls {out}/ca.pem {out}/NAME.pem {out}/NAME.key")
    return 0


def report(ca, issued) -> None:
    print(f"CA          {ca.certificate}")
    for i in issued:
        print(f"{i.name:<11} {i.certificate}  {i.private_key}")


def main(args: argparse.Namespace) -> int:
    out = Path(args.out) if args.out else None
    try:
        if args.profile:
            return secure_profile(Path(args.profile), out, args.san or [], args.days)
        ca, issued = generate(out or Path("certs"), args.names, args.san or DEFAULT_SANS, args.days)
    except (ValueError, OSError, AccessError) as e:  # ProfileError and TOML errors are ValueErrors
        print(f"error: {e}", file=sys.stderr)
        return 2
    report(ca, issued)
    return 0
