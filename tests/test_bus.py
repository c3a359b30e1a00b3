"""The Zenoh bus between two processes: typed round trip, garbage counted and ignored."""

from __future__ import annotations

import asyncio
import subprocess
import sys
import textwrap

from conftest import lossless

from climbd.daemon.contract.messages import Health, JointState, MotionCommand
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config

PUBLISHER = textwrap.dedent(
    """
    import sys, time
    import zenoh
    from climbd.daemon.runtime.network import Network, Endpoints, zenoh_config
    from climbd.daemon.contract.messages import JointState, MotionCommand, encode
    bus = Network("r2d2", zenoh_config(None, "test", Endpoints([], [sys.argv[1]])))
    pub = bus.publisher(JointState)
    time.sleep(1.0)
    raw = bus.session.declare_publisher("climbd/r2d2/state/joints")
    raw.put(b"\\x00garbage\\xff")
    raw.put(encode(MotionCommand(vx=1.0)))
    raw.put(encode(JointState(schema=99, position=[9.0])))
    for k in range(20):
        pub.put(JointState(stamp=k, names=["rf_coxa"], position=[0.01 * k], velocity=[0.0],
                           effort=[0.0]))
        time.sleep(0.01)
    time.sleep(0.5)
    bus.close()
    """
)


def test_round_trip_between_processes_and_garbage_is_counted(endpoint: str) -> None:
    async def scenario() -> tuple[list[JointState], int]:
        loop = asyncio.get_running_loop()
        bus = Network("r2d2", zenoh_config(None, "test", Endpoints([endpoint], [])), loop)
        got: list[JointState] = []
        bus.subscribe(JointState, got.append)
        proc = await asyncio.create_subprocess_exec(sys.executable, "-c", PUBLISHER, endpoint)
        try:
            await asyncio.wait_for(proc.wait(), 60)
        finally:
            if proc.returncode is None:
                proc.kill()
        await asyncio.sleep(0.2)
        errors = bus.decode_errors
        bus.close()
        return got, errors

    got, errors = asyncio.run(scenario())
    assert [m.stamp for m in got] == [float(k) for k in range(20)]
    assert got[5].position == [0.05] and got[5].names == ["rf_coxa"]
    assert errors == 3  # bytes, another topic's payload, another schema version


def test_latest_only_keeps_a_ring_buffer_of_one(endpoint: str) -> None:
    async def scenario() -> list[MotionCommand]:
        loop = asyncio.get_running_loop()
        rx = Network("r2d2", zenoh_config(None, "rx", Endpoints([endpoint], [])), loop)
        tx = Network("r2d2", zenoh_config(None, "tx", Endpoints([], [endpoint])))
        got: list[MotionCommand] = []
        rx.subscribe(MotionCommand, got.append, latest_only=True)
        await asyncio.sleep(0.5)
        pub = lossless(tx, MotionCommand)
        for k in range(200):  # the event loop is blocked: nothing is delivered meanwhile
            pub.put(MotionCommand(vx=float(k)))
        subprocess.run([sys.executable, "-c", "import time; time.sleep(0.5)"], check=True)
        await asyncio.sleep(0.2)
        tx.close()
        rx.close()
        return got

    got = asyncio.run(scenario())
    assert got and got[-1].vx == 199.0
    assert len(got) < 20, "stale commands queued behind the newest"


def test_robots_do_not_hear_each_other(endpoint: str) -> None:
    async def scenario() -> tuple[list, list]:
        loop = asyncio.get_running_loop()
        a = Network("alpha", zenoh_config(None, "a", Endpoints([endpoint], [])), loop)
        b = Network("beta", zenoh_config(None, "b", Endpoints([], [endpoint])), loop)
        heard_a: list = []
        heard_all: list = []
        a.subscribe(Health, heard_a.append)
        a.subscribe(Health, heard_all.append, robot="*")
        await asyncio.sleep(0.5)
        b.publisher(Health).put(Health(role="control"))
        await asyncio.sleep(0.5)
        a.close()
        b.close()
        return heard_a, heard_all

    heard_a, heard_all = asyncio.run(scenario())
    assert heard_a == [] and len(heard_all) == 1
