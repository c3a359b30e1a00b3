"""Certificates for mutual TLS: a certificate authority and one certificate per role or operator.

Zenoh's mutual TLS checks every peer's certificate against the CA, and its access control
matches the certificate's common name (CN) against the profile's ``network.auth.rights``
(and ``commanders``). Keys are ECDSA P-256 in PKCS#8 PEM, owner-only; certificates serve as
server and client. ``first_run`` creates what a profile with ``create_certificates`` lacks,
the way an SSH server creates its host keys on its first start.
"""

from __future__ import annotations

import datetime
import fcntl
import ipaddress
import logging
import os
import socket
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("climbd.access")

DEFAULT_SANS = ("localhost", "127.0.0.1")
DEFAULT_DIR = "~/.config/climbd/certs"
"""Where the stock profiles keep their certificates, and where operator tools look for theirs."""
OPERATOR = "operator"
"""The operator identity the stock profiles name, created with them on the first run."""
WILDCARD_HOSTS = ("0.0.0.0", "::", "")


@dataclass(frozen=True)
class Issued:
    """Paths of one issued certificate and its private key."""

    name: str
    certificate: Path
    private_key: Path


def endpoint_host(endpoint: str) -> str:
    """The host of a Zenoh locator, e.g. ``tls/192.168.50.2:7447`` or ``tcp/[::1]:7447#iface=x``."""
    address = endpoint.split("/", 1)[-1].split("#", 1)[0].split("?", 1)[0]
    host = address.rsplit(":", 1)[0] if ":" in address else address
    return host.strip("[]")


def is_loopback(endpoint: str) -> bool:
    """Whether only this computer can reach ``endpoint``: a loopback host or a Unix socket."""
    if endpoint.startswith(("unixsock-stream/", "unixpipe/")):
        return True
    host = endpoint_host(endpoint)
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def subject_names(endpoints: Iterable[str], extra: Iterable[str] = ()) -> list[str]:
    """Names peers may dial: localhost, this computer's name, each endpoint's host (not a
    wildcard) and ``extra``; TLS checks the one dialled against the certificate."""
    names = [*DEFAULT_SANS, socket.gethostname()]
    names += [endpoint_host(e) for e in endpoints] + list(extra)
    return list(dict.fromkeys(n for n in names if n not in WILDCARD_HOSTS))


def _write_key(path: Path, key) -> None:
    from cryptography.hazmat.primitives import serialization

    pem = key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)


def _write_cert(path: Path, cert) -> None:
    from cryptography.hazmat.primitives import serialization

    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def _san(names: list[str]):
    from cryptography import x509

    entries = []
    for n in names:
        try:
            entries.append(x509.IPAddress(ipaddress.ip_address(n)))
        except ValueError:
            entries.append(x509.DNSName(n))
    return x509.SubjectAlternativeName(entries)


def _authority(out: Path, now: datetime.datetime, days: int):
    """The CA's key and certificate in ``out``: read when present, else created and written."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.serialization import load_pem_private_key
    from cryptography.x509.oid import NameOID

    cert_path, key_path = out / "ca.pem", out / "ca.key"
    if cert_path.exists() and key_path.exists():
        key = load_pem_private_key(key_path.read_bytes(), password=None)
        return key, x509.load_pem_x509_certificate(cert_path.read_bytes())
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "climbd CA")])
    usage = x509.KeyUsage(
        digital_signature=True,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        key_cert_sign=True,
        crl_sign=True,
        encipher_only=False,
        decipher_only=False,
    )
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(usage, critical=True)
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_key(key_path, key)
    _write_cert(cert_path, cert)
    return key, cert


def generate(
    out: Path, names: list[str], sans: list[str] | tuple[str, ...] = DEFAULT_SANS, days: int = 825
) -> tuple[Issued, list[Issued]]:
    """Write ``ca.pem``/``ca.key`` (reused when present) and ``<name>.pem``/``<name>.key`` per name.

    ``sans`` are the host names and IP addresses peers dial (TLS checks them on connect).
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if not names:
        raise ValueError("climbd certs: give at least one role or operator name")
    bad = [n for n in names if not n or "/" in n or n == "ca"]
    if bad:
        raise ValueError(f"climbd certs: invalid certificate names {bad} (no '/', not 'ca')")
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key, ca_cert = _authority(out, now, days)
    both = x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH])
    issued = []
    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, name)]))
            .issuer_name(ca_cert.subject)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(_san(list(sans)), critical=False)
            .add_extension(both, critical=False)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        cert_path, key_path = out / f"{name}.pem", out / f"{name}.key"
        _write_key(key_path, key)
        _write_cert(cert_path, cert)
        issued.append(Issued(name, cert_path, key_path))
    return Issued("ca", out / "ca.pem", out / "ca.key"), issued


def missing(out: Path, names: Iterable[str]) -> list[str]:
    """Which of ``names`` have no certificate and key in ``out``."""
    return [n for n in names if not ((out / f"{n}.pem").is_file() and (out / f"{n}.key").is_file())]


def first_run(out: Path, names: list[str], sans: list[str]) -> list[Issued]:
    """Create in ``out`` the CA (when neither ``ca.pem`` nor ``ca.key`` exists) and each of
    ``names`` without a certificate, under a lock so two roles starting together make one CA;
    log where they are and how an operator gets credentials. [] when nothing was missing."""
    out.mkdir(parents=True, exist_ok=True, mode=0o700)
    with open(out / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        wanted = missing(out, names)
        if not wanted:
            return []
        if (out / "ca.pem").exists() != (out / "ca.key").exists():
            raise FileNotFoundError(
                f"{out}: no certificate for {', '.join(wanted)}, and only one of ca.pem and "
                "ca.key to issue one: issue them with `climbd certs` where both are and copy "
                "them here"
            )
        _, issued = generate(out, wanted, sans)
    log.warning(
        "first run: created %s in %s (certificate authority %s; hosts %s); an operator on "
        "this computer uses them as they are; another operator gets credentials with `climbd "
        "certs NAME -o %s` here, copies ca.pem, NAME.pem and NAME.key to the laptop and is "
        "named in the profile's network.auth commanders or rights",
        ", ".join(i.name for i in issued),
        out,
        out / "ca.pem",
        ", ".join(sans),
        out,
    )
    return issued


def default_credentials(name: str = OPERATOR) -> tuple[str, str, str] | None:
    """``(ca, certificate, key)`` of ``name`` in DEFAULT_DIR when all three exist (an operator
    tool on the robot's computer, as the user the daemon runs as), else None."""
    out = Path(DEFAULT_DIR).expanduser()
    files = (out / "ca.pem", out / f"{name}.pem", out / f"{name}.key")
    return tuple(str(f) for f in files) if all(f.is_file() for f in files) else None
