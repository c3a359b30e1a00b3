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

import pytest
from support.zenoh_roles import Proc

from climbd.daemon.contract import profile as profiles

PORT = 7447


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


def status(nuc: str, endpoint: str) -> dict:
    """`climbd status --json` run on the NUC side."""
    p = Proc("status", "--robot", "widowx", "--connect", endpoint, "--json", "--timeout", "5",
             prefix=("ip", "netns", "exec", nuc))  # fmt: skip
    assert p.proc.wait(30) == 0, p.text
    p.stop()
    return json.loads(p.log[-1])


def test_roles_across_namespaces_features_estop_and_perception_loss(namespaces, robots) -> None:
    max_age = profiles.load(robots / "widowx.toml").safety.feature_max_age
    pi, pi_addr, nuc = namespaces
    endpoint = f"tcp/{pi_addr}:{PORT}"
    control = Proc("run", "--profile", "robots/widowx.toml", "--driver", "fake", "--quiet",
                   "--listen", endpoint, prefix=("ip", "netns", "exec", pi))  # fmt: skip
    perception = Proc("run", "--profile", "robots/widowx.toml", "--role", "perception",
                      "--source", "floor", "--plugin", "elevation", "--connect", endpoint,
                      prefix=("ip", "netns", "exec", nuc))  # fmt: skip
    try:
        control.wait_for("stand complete", 60)
        perception.wait_for("perception role", 60)
        end = time.monotonic() + 30
        health = status(nuc, endpoint)
        while "features/grid" not in health["features"] and time.monotonic() < end:
            health = status(nuc, endpoint)
        assert health["features"]["features/grid"] <= max_age, "NUC features reach the Pi"

        perception.kill()
        time.sleep(max_age + 0.5)
        health = status(nuc, endpoint)
        assert health["mode"] == "HOLD" and health["features"]["features/grid"] > max_age
        assert control.proc.poll() is None, "the control role outlives the perception link"

        stop = Proc("estop", "--robot", "widowx", "--connect", endpoint,
                    prefix=("ip", "netns", "exec", nuc))  # fmt: skip
        assert stop.proc.wait(30) == 0
        assert status(nuc, endpoint)["mode"] == "ESTOP"
        assert control.stop() == 0
    finally:
        perception.kill()
        control.kill()
