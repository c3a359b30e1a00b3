"""The NUC and the Pi as two network namespaces joined by a veth pair, as on the WidowX.

The control role runs in the "pi" namespace, perception and the operator's tools in the "nuc"
namespace; they meet only through the veth link. Skipped, with the reason, where namespaces
cannot be created (not root, no ``ip``, a container without CAP_NET_ADMIN).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest
from support.zenoh_roles import Proc

from climbd.daemon.contract import profile as profiles

PORT = 7447
CERTS = Path(".config/climbd/certs")
"""Where the stock profiles keep certificates, under the home of the user climbd runs as."""


def ip(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=10)


@pytest.fixture()
def namespaces():
    """(pi namespace, pi address, nuc namespace): created here, deleted afterwards."""
    if shutil.which("ip") is None:
        pytest.skip("network namespaces: the `ip` command (iproute2) is not installed")
    tag = os.getpid() % 100000
    pi, nuc = f"climbd-pi-{tag}", f"climbd-nuc-{tag}"
    net = f"10.{200 + tag % 50}.{tag // 50 % 250}"
    steps = [
        ("netns", "add", pi),
        ("netns", "add", nuc),
        ("link", "add", f"cpi{tag}", "type", "veth", "peer", "name", f"cnuc{tag}"),
        ("link", "set", f"cpi{tag}", "netns", pi),
        ("link", "set", f"cnuc{tag}", "netns", nuc),
        ("-n", pi, "addr", "add", f"{net}.1/24", "dev", f"cpi{tag}"),
        ("-n", nuc, "addr", "add", f"{net}.2/24", "dev", f"cnuc{tag}"),
        ("-n", pi, "link", "set", f"cpi{tag}", "up"),
        ("-n", nuc, "link", "set", f"cnuc{tag}", "up"),
        ("-n", pi, "link", "set", "lo", "up"),
        ("-n", nuc, "link", "set", "lo", "up"),
    ]
    try:
        for step in steps:
            done = ip(*step)
            if done.returncode != 0:
                pytest.skip(f"cannot create network namespaces (ip {' '.join(step)}): "
                            f"{done.stderr.strip()}")  # fmt: skip
        yield pi, f"{net}.1", nuc
    finally:
        ip("netns", "del", pi)
        ip("netns", "del", nuc)


def status(nuc: str, endpoint: str, home: Path) -> dict:
    """`climbd status --json` run on the NUC side by the user whose home is ``home``."""
    p = Proc("status", "--robot", "widowx", "--connect", endpoint, "--json", "--timeout", "5",
             prefix=("ip", "netns", "exec", nuc), env={"HOME": str(home)})  # fmt: skip
    assert p.proc.wait(30) == 0, p.text
    p.stop()
    return json.loads(p.log[-1])


def test_roles_across_namespaces_features_estop_and_perception_loss(
    namespaces, robots, tmp_path
) -> None:
    """The stock profile as installed: the Pi's first run creates the certificates; the NUC
    gets the perception role's and the operator's by copy, and a peer without any is shut out."""
    max_age = profiles.load(robots / "widowx.toml").safety.feature_max_age
    pi, pi_addr, nuc = namespaces
    pi_home, nuc_home, stranger = tmp_path / "pi", tmp_path / "nuc", tmp_path / "stranger"
    endpoint = f"tls/{pi_addr}:{PORT}"
    control = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                   "--listen", endpoint, prefix=("ip", "netns", "exec", pi),
                   env={"HOME": str(pi_home)})  # fmt: skip
    perception = None
    try:
        control.wait_for("stand complete", 60)
        assert "first run: created control, perception, operator" in control.text
        made, copied = pi_home / CERTS, nuc_home / CERTS
        copied.mkdir(parents=True)
        for name in ("ca.pem", "perception.pem", "perception.key", "operator.pem", "operator.key"):
            shutil.copy(made / name, copied / name)
        perception = Proc("run", "--profile", "robots/widowx.toml", "--role", "perception",
                          "--source", "floor", "--plugin", "elevation", "--connect", endpoint,
                          prefix=("ip", "netns", "exec", nuc),
                          env={"HOME": str(nuc_home)})  # fmt: skip
        perception.wait_for("perception role", 60)
        end = time.monotonic() + 30
        health = status(nuc, endpoint, nuc_home)
        while "features/grid" not in health["features"] and time.monotonic() < end:
            health = status(nuc, endpoint, nuc_home)
        assert health["features"]["features/grid"] <= max_age, "NUC features reach the Pi"

        nobody = Proc("estop", "--robot", "widowx", "--connect", endpoint, "--timeout", "2",
                      prefix=("ip", "netns", "exec", nuc),
                      env={"HOME": str(stranger)})  # fmt: skip
        assert nobody.proc.wait(30) == 1 and "no robot widowx answered" in nobody.text
        assert status(nuc, endpoint, nuc_home)["mode"] == "HOLD"

        perception.kill()
        time.sleep(max_age + 0.5)
        health = status(nuc, endpoint, nuc_home)
        assert health["mode"] == "HOLD" and health["features"]["features/grid"] > max_age
        assert control.proc.poll() is None, "the control role outlives the perception link"

        stop = Proc("estop", "--robot", "widowx", "--connect", endpoint,
                    prefix=("ip", "netns", "exec", nuc), env={"HOME": str(nuc_home)})  # fmt: skip
        assert stop.proc.wait(30) == 0
        assert status(nuc, endpoint, nuc_home)["mode"] == "ESTOP"
        assert control.stop() == 0
    finally:
        if perception is not None:
            perception.kill()
        control.kill()
