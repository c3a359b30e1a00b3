"""Access control over real Zenoh: mutual TLS and user/password from the profile, command ACL,
read-only telemetry for peers without credentials, and their command attempts counted."""

from __future__ import annotations

import time

import pytest
from conftest import free_port
from support.auth_roles import auth_profile, control_health
from support.zenoh_roles import Observer, Proc

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import EStop, Mode, ModeState
from climbd.daemon.runtime.access import AccessError
from climbd.daemon.runtime.certificates import generate
from climbd.daemon.runtime.network import Endpoints, zenoh_config

GRID = "features/grid"


def test_mutual_tls_only_commanders_command_and_anonymous_peers_only_read(tmp_path, robots) -> None:
    certs = tmp_path / "certs"
    generate(certs, ["control", "perception", "operator", "intruder"])
    secure, telemetry = f"tls/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    profile = auth_profile(
        tmp_path,
        robots,
        'tls_root_ca = "certs/ca.pem"\ntls_certificate = "certs/{role}.pem"\n'
        'tls_private_key = "certs/{role}.key"',
        telemetry,
    )

    def tls(name: str) -> tuple[str, ...]:
        return ("--tls", *(str(certs / f) for f in ("ca.pem", f"{name}.pem", f"{name}.key")))

    robot = Proc("run", "--profile", profile, "--driver", "fake", "--quiet", "--listen", secure)
    perception = Proc("run", "--profile", profile, "--role", "perception", "--source", "floor",
                      "--plugin", "elevation", "--connect", secure)  # fmt: skip
    anonymous = Observer("widowx", [telemetry])
    try:
        control_health(anonymous, lambda h: h.mode == Mode.HOLD, 60)
        control_health(anonymous, lambda h: GRID in h.features, 60)  # perception over mTLS

        script = tmp_path / "off.txt"
        script.write_text("0 claim\n0.3 mode OFF\n1 release\n")
        op = Proc("teleop", "--robot", "widowx", "--connect", secure, "--script", str(script),
                  *tls("operator"))  # fmt: skip
        assert op.proc.wait(30) == 0
        anonymous.wait(ModeState, lambda m: m.mode == Mode.OFF)

        intruder = Proc("estop", "--robot", "widowx", "--connect", secure, *tls("intruder"),
                        "--timeout", "1")  # fmt: skip
        assert intruder.proc.wait(30) == 1, "the robot dropped the intruder's e-stop"
        intruder.stop()
        assert "refused: e-stop: widowx stays in OFF" in intruder.text
        bare = Proc("status", "--robot", "widowx", "--connect", secure, "--timeout", "2")
        assert bare.proc.wait(30) == 1, "no TLS credentials: cannot even connect"
        attempted = time.monotonic()  # the daemon stamps Health on this machine's monotonic clock
        anonymous.bus.publisher(EStop).put(EStop(engage=True, source="anonymous"))
        after = control_health(anonymous, lambda h: h.stamp > attempted + 0.6)
        assert after.mode == Mode.OFF, "neither the intruder's nor the anonymous e-stop acted"
        assert after.unauthorised_commands >= 1, "the anonymous attempt is counted"
        assert after.refused_commands == 0

        op_stop = Proc("estop", "--robot", "widowx", "--connect", secure, *tls("operator"))
        assert op_stop.proc.wait(30) == 0
        anonymous.wait(ModeState, lambda m: m.mode == Mode.ESTOP)
        assert robot.stop() == 0
        assert "refused climbd/widowx/cmd/estop from a peer without credentials" in robot.text
    finally:
        anonymous.close()
        perception.kill()
        robot.kill()


def test_user_password_only_commanders_command(tmp_path, robots) -> None:
    (tmp_path / "users.txt").write_text("control:rolepw\noperator:oppw\nviewer:viewpw\n")
    listen, telemetry = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    profile = auth_profile(
        tmp_path,
        robots,
        'user = "{role}"\npassword = "rolepw"\ncredentials_file = "users.txt"',
        telemetry,
    )
    robot = Proc("run", "--profile", profile, "--driver", "fake", "--quiet", "--listen", listen)
    anonymous = Observer("widowx", [telemetry])
    try:
        anonymous.wait(ModeState, lambda m: m.mode == Mode.HOLD, 60)
        for user, password, why in (
            ("operator", "wrong", "no robot widowx answered"),  # cannot even connect
            ("viewer", "viewpw", "refused: e-stop: widowx stays in HOLD"),
        ):
            p = Proc("estop", "--robot", "widowx", "--connect", listen, "--user", user,
                     "--timeout", "1", env={"CLIMBD_PASSWORD": password})  # fmt: skip
            assert p.proc.wait(30) == 1, f"{user}'s e-stop was dropped"
            p.stop()
            assert why in p.text
        sent = time.monotonic()
        after = control_health(anonymous, lambda h: h.stamp > sent + 0.6)
        assert after.mode == Mode.HOLD, "a wrong password or a non-commander cannot e-stop"

        p = Proc("estop", "--robot", "widowx", "--connect", listen, "--user", "operator",
                 env={"CLIMBD_PASSWORD": "oppw"})  # fmt: skip
        assert p.proc.wait(30) == 0
        anonymous.wait(ModeState, lambda m: m.mode == Mode.ESTOP)
        assert robot.stop() == 0
    finally:
        anonymous.close()
        robot.kill()


def test_auth_setups_that_cannot_work_name_the_field(tmp_path, robots) -> None:
    tls = auth_profile(
        tmp_path, robots, 'tls_root_ca = "ca.pem"\ntls_certificate = "c.pem"', "tcp/127.0.0.1:1"
    )
    profile = profiles.load(tls)
    with pytest.raises(AccessError, match=r"network.roles.control: endpoints \['tcp/"):
        zenoh_config(profile, "control", Endpoints(["tcp/0.0.0.0:7447"], []))
    with pytest.raises(AccessError, match=r"network.auth: file not found: .*ca.pem"):
        zenoh_config(profile, "control", Endpoints(["tls/127.0.0.1:7447"], []))
    empty = auth_profile(tmp_path, robots, "", "tcp/127.0.0.1:1")
    with pytest.raises(AccessError, match="network.auth: give tls_root_ca"):
        zenoh_config(profiles.load(empty), "control", Endpoints([], []))


def test_certs_command_writes_a_ca_and_one_pair_per_name(tmp_path) -> None:
    from cryptography import x509

    out = tmp_path / "c"
    p = Proc("certs", "control", "alice", "-o", str(out), "--san", "10.0.0.2")
    assert p.proc.wait(30) == 0
    ca = x509.load_pem_x509_certificate((out / "ca.pem").read_bytes())
    alice = x509.load_pem_x509_certificate((out / "alice.pem").read_bytes())
    alice.verify_directly_issued_by(ca)
    assert alice.subject.rfc4514_string() == "CN=alice"
    sans = alice.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(ip) for ip in sans.get_values_for_type(x509.IPAddress)] == ["10.0.0.2"]
    assert (out / "alice.key").stat().st_mode & 0o077 == 0, "private keys are owner-only"
    bad = Proc("certs", "ca", "-o", str(out))
    assert bad.proc.wait(30) == 2
    bad.stop()
    assert "invalid certificate names ['ca']" in bad.text
