"""Secure by default (#33): a profile that listens beyond this computer must authenticate;
``climbd certs --profile`` makes one safe; the stock profiles' first run creates certificates
the way an SSH server creates its host keys, and operator tools on that computer use them."""

from __future__ import annotations

import logging
import stat

import pytest
from conftest import free_port
from cryptography import x509
from support.auth_roles import unauthenticated_widowx
from support.zenoh_roles import Proc

from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime.access import AccessError, certificate_dir, check_network
from climbd.daemon.runtime.certificates import is_loopback, subject_names
from climbd.daemon.runtime.network import Endpoints, zenoh_config

CERTS = ".config/climbd/certs"
"""The stock profiles' certificate directory under the daemon user's home."""


@pytest.mark.parametrize(
    ("endpoint", "local"),
    [
        ("tcp/127.0.0.1:7447", True),
        ("tls/127.3.0.1:7447", True),
        ("tcp/[::1]:7447", True),
        ("tcp/localhost:7447", True),
        ("unixsock-stream/tmp/z.sock", True),
        ("tcp/0.0.0.0:7447", False),
        ("tcp/[::]:7447", False),
        ("tls/192.168.50.2:7447#iface=eth0", False),
        ("udp/robot.local:7447", False),
    ],
)
def test_only_loopback_endpoints_are_local(endpoint: str, local: bool) -> None:
    assert is_loopback(endpoint) is local


def test_certificates_name_every_host_peers_dial_but_no_wildcard() -> None:
    names = subject_names(["tls/0.0.0.0:7447", "tls/192.168.50.2:7447", "tcp/[::]:1"], ["pi"])
    assert names[:2] == ["localhost", "127.0.0.1"]
    assert "192.168.50.2" in names and "pi" in names
    assert "0.0.0.0" not in names and "::" not in names


def test_listening_beyond_loopback_without_auth_is_refused_naming_the_fix(tmp_path, robots):
    path = unauthenticated_widowx(tmp_path, robots)
    profile = profiles.load(path)
    fix = f"climbd certs --profile {path}"
    with pytest.raises(AccessError, match="network.roles.control.listen: .*tcp/0.0.0.0:7447"):
        check_network(profile)
    with pytest.raises(AccessError, match=r"--listen: \['tcp/10.1.2.3:1'\]"):
        zenoh_config(profile, "control", Endpoints(["tcp/10.1.2.3:1"], []))
    zenoh_config(profile, "control", Endpoints(["tcp/127.0.0.1:1"], []))  # this computer only

    check = Proc("profile", "check", str(path))
    assert check.proc.wait(30) == 1 and fix in check.text
    run = Proc("run", "--profile", str(path), "--driver", "fake", "--quiet")
    assert run.proc.wait(30) == 1 and fix in run.text
    every = Proc("run", "--profile", str(path), "--role", "all", "--driver", "fake")
    assert every.proc.wait(30) == 2 and fix in every.text and "started" not in every.text
    units = tmp_path / "units"
    install = Proc("install", "--profile", str(path), "--unit-dir", str(units),
                   "--udev-dir", str(tmp_path / "udev"))  # fmt: skip
    assert install.proc.wait(30) == 2 and fix in install.text and not units.exists()


def test_certs_profile_makes_a_profile_safe_and_its_operator_commands_it(tmp_path, robots):
    path = unauthenticated_widowx(tmp_path, robots)
    fixed = Proc("certs", "--profile", str(path))
    assert fixed.proc.wait(30) == 0, fixed.text
    profile = profiles.load(path)
    check_network(profile)
    assert profile.network.roles["control"].listen == ["tls/0.0.0.0:7447"]
    assert profile.network.auth is not None and profile.network.auth.commanders == ["operator"]
    certs = tmp_path / "certs"
    assert certificate_dir(profile) == certs
    assert sorted(p.name for p in certs.glob("*.pem")) == [
        "ca.pem", "control.pem", "operator.pem", "perception.pem"
    ]  # fmt: skip
    again = Proc("certs", "--profile", str(path))
    assert again.proc.wait(30) == 0 and "CA " not in again.text, "nothing reissued"

    listen = f"tls/127.0.0.1:{free_port()}"
    robot = Proc("run", "--profile", str(path), "--driver", "fake", "--quiet", "--listen", listen,
                 env={"HOME": str(tmp_path / "robot")})  # fmt: skip
    try:
        robot.wait_for("stand complete", 60)
        stranger = Proc("estop", "--robot", "widowx", "--connect", listen, "--timeout", "2",
                        env={"HOME": str(tmp_path / "stranger")})  # fmt: skip
        assert stranger.proc.wait(30) == 1 and "no robot widowx answered" in stranger.text
        tls = [str(certs / f) for f in ("ca.pem", "operator.pem", "operator.key")]
        operator = Proc("estop", "--robot", "widowx", "--connect", listen, "--tls", *tls)
        assert operator.proc.wait(30) == 0, operator.text
        assert robot.stop() == 0
    finally:
        robot.kill()


def test_the_stock_profile_creates_its_certificates_on_the_first_run_only(tmp_path):
    home = tmp_path / "climbd"
    listen = f"tls/127.0.0.1:{free_port()}"

    def run() -> Proc:
        return Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                    "--listen", listen, env={"HOME": str(home)})  # fmt: skip

    first = run()
    try:
        first.wait_for("stand complete", 60)
        assert "first run: created control, perception, operator" in first.text
        assert first.stop() == 0
    finally:
        first.kill()
    certs = home / CERTS
    ca_pem = (certs / "ca.pem").read_bytes()
    ca = x509.load_pem_x509_certificate(ca_pem)
    control = x509.load_pem_x509_certificate((certs / "control.pem").read_bytes())
    control.verify_directly_issued_by(ca)
    sans = control.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    ips = [str(ip) for ip in sans.get_values_for_type(x509.IPAddress)]
    assert "127.0.0.1" in ips and "192.168.50.2" in ips, "where the NUC dials the Pi"
    for key in certs.glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key
    assert stat.S_IMODE(certs.stat().st_mode) == 0o700

    second = run()
    try:
        second.wait_for("stand complete", 60)
        assert (certs / "ca.pem").read_bytes() == ca_pem and "first run" not in second.text
        local = Proc("status", "--robot", "widowx", "--connect", listen, "--json",
                     "--timeout", "10", env={"HOME": str(home)})  # fmt: skip
        assert local.proc.wait(30) == 0, "an operator tool as the daemon's user needs no options"
        stranger = Proc("status", "--robot", "widowx", "--connect", listen, "--timeout", "2",
                        env={"HOME": str(tmp_path / "stranger")})  # fmt: skip
        assert stranger.proc.wait(30) != 0, "without the operator's certificate: nothing"
        assert second.stop() == 0
    finally:
        second.kill()


def test_a_perception_role_without_certificates_says_where_to_copy_them_from(tmp_path):
    p = Proc("run", "--profile", "robots/widowx.toml", "--role", "perception", "--source",
             "floor", env={"HOME": str(tmp_path)})  # fmt: skip
    assert p.proc.wait(30) == 1
    assert "copy ca.pem, perception.pem and perception.key from" in p.text


def test_plain_loopback_endpoints_given_instead_of_tls_run_without_it_and_say_so(
    robots, caplog, tmp_path, monkeypatch
) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))  # the TLS config's first run writes there
    profile = profiles.load(robots / "widowx.toml")
    with caplog.at_level(logging.WARNING, "climbd.bus"):
        cfg = zenoh_config(profile, "control", Endpoints(["tcp/127.0.0.1:1"], []))
    assert "network.auth (TLS) not applied" in caplog.text
    assert cfg.get_json("transport/link/tls/root_ca_certificate") == "null"
    secure = zenoh_config(profile, "control", Endpoints(["tls/127.0.0.1:1"], []))
    assert secure.get_json("access_control/enabled") == "true", "TLS endpoints get TLS"


def test_a_certificate_layout_first_run_cannot_fill_names_the_field(tmp_path, robots) -> None:
    path = tmp_path / "odd.toml"
    path.write_text(
        f'include = "{unauthenticated_widowx(tmp_path, robots)}"\n[network.auth]\n'
        'tls_root_ca = "c/ca.pem"\ntls_certificate = "c/{role}-cert.pem"\n'
        'tls_private_key = "c/{role}.key"\ncreate_certificates = true\n'
    )
    with pytest.raises(AccessError, match="network.auth.tls_certificate: climbd certs writes"):
        certificate_dir(profiles.load(path))
