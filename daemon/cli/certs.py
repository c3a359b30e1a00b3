"""``climbd certs``: a certificate authority and one certificate per role or operator, for mTLS.

Zenoh's mutual TLS checks every peer's certificate against the CA, and its access control
matches the certificate's common name (CN) against the profile's ``network.auth.rights``
(and ``commanders``).
So each role (``control``, ``perception``) and each operator laptop gets its own certificate
whose CN names it. Keys are ECDSA P-256 in PKCS#8 PEM; certificates serve as server and client.
"""

from __future__ import annotations

import argparse
import datetime
import ipaddress
import os
from dataclasses import dataclass
from pathlib import Path

DEFAULT_SANS = ("localhost", "127.0.0.1")


@dataclass(frozen=True)
class Issued:
    """Paths of one issued certificate and its private key."""

    name: str
    certificate: Path
    private_key: Path


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


def generate(
    out: Path, names: list[str], sans: list[str] | tuple[str, ...] = DEFAULT_SANS, days: int = 825
) -> tuple[Issued, list[Issued]]:
    """Write ``ca.pem``/``ca.key`` (reused when present) and ``<name>.pem``/``<name>.key`` per name.

    ``sans`` are the host names and IP addresses peers dial (TLS checks them on connect).
    """
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.serialization import load_pem_private_key
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    if not names:
        raise ValueError("climbd certs: give at least one role or operator name")
    bad = [n for n in names if not n or "/" in n or n == "ca"]
    if bad:
        raise ValueError(f"climbd certs: invalid certificate names {bad} (no '/', not 'ca')")
    out.mkdir(parents=True, exist_ok=True)
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_cert_path, ca_key_path = out / "ca.pem", out / "ca.key"
    if ca_cert_path.exists() and ca_key_path.exists():
        ca_key = load_pem_private_key(ca_key_path.read_bytes(), password=None)
        ca_cert = x509.load_pem_x509_certificate(ca_cert_path.read_bytes())
    else:
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "climbd CA")])
        ca_cert = (
            x509.CertificateBuilder()
            .subject_name(ca_name)
            .issuer_name(ca_name)
            .public_key(ca_key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(
                x509.KeyUsage(
                    digital_signature=True,
                    content_commitment=False,
                    key_encipherment=False,
                    data_encipherment=False,
                    key_agreement=False,
                    key_cert_sign=True,
                    crl_sign=True,
                    encipher_only=False,
                    decipher_only=False,
                ),
                critical=True,
            )
            .add_extension(
                x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False
            )
            .sign(ca_key, hashes.SHA256())
        )
        _write_key(ca_key_path, ca_key)
        _write_cert(ca_cert_path, ca_cert)
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
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
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
    return Issued("ca", ca_cert_path, ca_key_path), issued


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "names", nargs="+", help="roles and operators, e.g. control perception alice"
    )
    parser.add_argument("-o", "--out", default="certs", help="directory to write (default: certs)")
    parser.add_argument(
        "--san",
        action="append",
        help="host name or IP peers dial, repeatable (default: localhost, 127.0.0.1)",
    )
    parser.add_argument("--days", type=int, default=825, help="validity in days (default 825)")


def main(args: argparse.Namespace) -> int:
    try:
        ca, issued = generate(Path(args.out), args.names, args.san or DEFAULT_SANS, args.days)
    except ValueError as e:
        print(e)
        return 2
    print(f"CA          {ca.certificate}")
    for i in issued:
        print(f"{i.name:<11} {i.certificate}  {i.private_key}")
    return 0
