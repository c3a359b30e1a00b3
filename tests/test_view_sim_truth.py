"""The twin's truth without a flag: a ``--sim`` run publishes its world's true maps on
``sim/truth`` about once a second, and ``climbd view`` and ``climbd record --scene`` draw them
on /truth/… when they arrive (``--truth WORLD`` stays for a robot not in the twin)."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from support.foxglove_ws import Proc, check_payloads, first_on, foxglove_client
from support.scene_decode import decoded, proto_dict, tree

from climbd.daemon.cli.record import McapSink, Sample
from climbd.daemon.cli.sim_host import TruthPublisher
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.runtime import scene
from climbd.drivers.sim.truth import truth, truth_message
from climbd.drivers.sim.worlds import load

ROOT = Path(__file__).resolve().parent.parent


def widowx() -> scene.RobotScene:
    return scene.RobotScene(profiles.load(ROOT / "robots/widowx.toml"))


def test_the_truth_message_carries_the_worlds_maps_and_survives_the_wire() -> None:
    world = load("attic_paper")
    msg = truth_message(world)
    assert msg.world == "attic_paper" and msg.stairs is msg.holds is msg.truss is None
    assert msg.joists == truth(world)[0]
    assert m.decode(m.encode(msg), m.SimTruth) == msg
    assert scene.truth_maps(truth_message(load("truss"))) == truth(load("truss"))


def test_the_publisher_sends_the_truth_once_a_period_and_nothing_for_an_empty_world() -> None:
    sent: list[m.Message] = []
    publisher = TruthPublisher(truth_message(load("stairs")), sent.append, period=1.0)
    for t in (0.0, 0.4, 0.99, 1.0, 1.5, 2.25):
        publisher.due(t)
    assert [s.stamp for s in sent] == [0.0, 1.0, 2.25]
    assert all(isinstance(s, m.SimTruth) and s.stairs is not None for s in sent)
    assert publisher.message.stamp == 0.0, "each copy is stamped, the message kept as built"

    empty = TruthPublisher(truth_message(load("slope")), sent.append)
    empty.due(0.0)
    assert empty.empty and len(sent) == 3


def test_the_scene_draws_the_truth_when_it_arrives_and_it_takes_over_a_given_one() -> None:
    attic, stairs = truth_message(load("attic_paper")), truth_message(load("stairs"))
    stream = scene.SceneStream(widowx(), truth=[stairs.stairs])
    assert "/truth/stairs" in dict(stream.update([], 0, 0.0)), "given: with the geometry"
    out = dict(stream.update([attic], 1, 0.1))
    joists = decoded(out["/truth/joists"])
    assert len(joists["entities"]) == len(attic.joists.joists)
    (box,) = joists["entities"][0]["cubes"]
    assert [box["color"][c] for c in "rgba"] == pytest.approx(scene.TRUTH_COLOR)
    later = dict(stream.update([], 2, 1.5))
    assert "/robot" in later and not any(t.startswith("/truth/") for t in later), (
        "once heard, the truth goes out as it comes, not with the geometry"
    )


def test_a_scene_recording_declares_the_truth_when_it_comes(tmp_path: Path) -> None:
    path = tmp_path / "truth.mcap"
    stream = scene.SceneStream(widowx())
    sink = McapSink(path, [m.SimTruth, m.ModeState], "widowx", stream)
    t0 = 1_700_000_000_000_000_000
    sink.write(Sample(m.key("widowx", m.ModeState), m.ModeState(mode=m.Mode.STAND), t0))
    assert "/truth/joists" not in sink.scene_channels
    truth_msg = truth_message(load("attic_paper"))
    sink.write(Sample(m.key("widowx", m.SimTruth), truth_msg, t0 + 10**9))
    sink.close()
    with open(path, "rb") as f:
        reader = make_reader(f)
        drawn = [
            proto_dict(schema.name, schema.data, msg.data)
            for schema, channel, msg in reader.iter_messages(topics=["/truth/joists"])
        ]
        f.seek(0)
        raw = [
            msg
            for _, channel, msg in make_reader(f).iter_messages()
            if channel.topic == m.key("widowx", m.SimTruth)
        ]
    assert len(drawn) == 1 and len(drawn[0]["entities"]) == len(truth_msg.joists.joists)
    assert len(raw) == 1, "the raw sim/truth is recorded beside it"


def test_a_stepped_sim_runs_view_gets_the_true_joists(tmp_path: Path, endpoint: str) -> None:
    """``climbd run --sim attic_paper --stepped`` and ``climbd view`` of it, no ``--truth``:
    a Foxglove client gets the twin's joists on /truth/joists, every message it gets decodes
    against its channel's schema, and the transforms form one tree rooted at odom."""
    robot = Proc(  # stopped below; a loaded machine steps the twin at a tenth of real time
        "run", "--profile", "robots/widowx.toml", "--sim", "attic_paper", "--stepped",
        "--duration", "600", "--listen", endpoint, "--quiet", "--snapshot", str(tmp_path / "t.png"),
    )  # fmt: skip
    view = Proc(
        "view", "--robot", "widowx", "--connect", endpoint, "--port", "0", "--cloud-rate", "0"
    )
    try:
        port = int(view.wait_for("to Foxglove on ws://").split("ws://127.0.0.1:")[1].split()[0])
        view.wait_for("robot 'widowx' heard", timeout=60)
        # the twin's truth comes once a simulated second: beside another twin test on a
        # loaded CI machine, 30 s of wall time once passed without one
        try:
            _, joists = asyncio.run(first_on(port, "/truth/joists", time.monotonic() + 90))
        except AssertionError as e:  # what the twin and the view said: the flake's evidence
            said = "".join(robot.lines[-40:]) + "--- view ---\n" + "".join(view.lines[-20:])
            raise AssertionError(f"{e}\n--- robot ---\n{said}") from e
        # the robot's state comes at the twin's pace, a tenth of real time when loaded
        wanted = frozenset({"/tf", "/robot", "/mode", "/health", "/loop", "/estop"})
        channels, data = asyncio.run(foxglove_client(port, time.monotonic() + 60, wanted))
    finally:
        robot.stop()
        code = view.stop()
    # every message of every channel decodes against its advertised schema; the twin's robot,
    # standing, sends its frames, links, mode, health, loop and e-stop (no perception role
    # runs: its maps stay silent)
    topics = check_payloads(channels, data, every=False)
    assert wanted <= set(topics)
    frames = tree([t for msg in topics["/tf"] for t in msg["transforms"]])
    joints = {j.name for j in profiles.load(ROOT / "robots" / "widowx.toml").joints}
    assert joints <= set(frames) and "body" in frames
    for child in frames:  # one tree: every frame reaches odom
        seen = child
        for _ in range(len(frames) + 1):
            if seen == "odom":
                break
            seen = frames[seen][0]
        assert seen == "odom", f"{child} does not reach odom"
    boxes = [e for e in joists["entities"] if e["cubes"]]
    assert len(boxes) == len(truth(load("attic_paper"))[0].joists)
    (box,) = boxes[0]["cubes"]
    assert [box["color"][c] for c in "rgba"] == pytest.approx(scene.TRUTH_COLOR)
    assert code == 0 and "Traceback" not in "".join(view.lines + robot.lines)
