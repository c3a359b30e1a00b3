"""The self filter (daemon/algorithms/self_filter.py): the depth pixels that see the robot's own
legs are dropped before perception, scored against the twin's ray cast, which knows which geom
each pixel hit; and the perception role refuses a frame with no joint reading near its stamp."""

from __future__ import annotations

import argparse

import msgspec
import mujoco
import numpy as np
import pytest
from conftest import ROOT

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.algorithms.self_filter import NO_JOINTS, JointHistory, SelfFilter
from climbd.daemon.algorithms.world import world_config
from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.hardware import DepthFrame
from climbd.daemon.contract.plugins import PerceptionPlugin
from climbd.daemon.runtime.loader import Isolated
from climbd.daemon.runtime.perception_role import PerceptionRole
from climbd.drivers.sim.twin import Twin
from climbd.drivers.sim.worlds import load

QINGZHUI = profiles.load(ROOT / "robots" / "qingzhui.toml")


@pytest.fixture(scope="module")
def twin() -> Twin:
    return Twin(QINGZHUI, load("stairs"), stepped=True)


def posed(twin: Twin, q: np.ndarray) -> tuple[DepthFrame, np.ndarray]:
    """The front camera's frame with the legs at ``q``, and the pixels that hit a leg by the
    twin's own ray cast (the truth)."""
    twin.data.qpos[twin.robot.qpos_adr] = twin.map.hinge(q)
    mujoco.mj_kinematics(twin.model, twin.data)
    frame = twin.depth_frame("front")
    data = mujoco.MjData(twin.model)
    data.qpos[:] = twin.data.qpos
    mujoco.mj_kinematics(twin.model, data)
    _, geom, _, _ = twin.cameras["front"].cast(data)
    legs = np.flatnonzero(twin.model.geom_bodyid != 0)
    return frame, np.isin(geom, legs).reshape(frame.depth.shape) & (frame.depth > 0)


def test_every_pixel_that_sees_a_leg_is_dropped_and_little_else(twin: Twin) -> None:
    """Standing and at random joint angles within the limits: every pixel the twin's ray cast
    puts on a leg is dropped, and what else is dropped (ground within the radius of a foot or a
    link that dips into it) stays under 2 % of the frame's returns."""
    kin = Kinematics(QINGZHUI)
    radius = world_config(QINGZHUI).self_filter.radius
    assert radius > 0, "the Qingzhui profile sets a self filter"
    self_filter = SelfFilter(kin, radius)
    rng = np.random.default_rng(1)
    poses = [kin.stand_joints()]
    span = kin.upper - kin.lower
    poses += [kin.lower + rng.uniform(size=kin.n_joints) * span for _ in range(5)]
    seen = 0
    for q in poses:
        frame, legs = posed(twin, q)
        cut, count = self_filter.apply(frame, twin.joint_positions())
        dropped = (cut.depth == 0) & (frame.depth > 0)
        assert count == dropped.sum()
        assert not (legs & ~dropped).any(), f"{(legs & ~dropped).sum()} leg pixels kept"
        assert (dropped & ~legs).sum() <= 0.02 * (frame.depth > 0).sum()
        seen += legs.sum()
    assert seen > 50_000, "the legs are in view: the check is not empty"


def test_a_leg_with_an_unknown_joint_is_left_in_and_the_others_still_dropped(twin: Twin) -> None:
    """A NaN joint (a reading the bus lost) leaves its leg's pixels in the frame, since where
    that leg is is not known; the other legs' are dropped as before. Only the middle-front leg
    is in the front camera's view."""
    kin = Kinematics(QINGZHUI)
    self_filter = SelfFilter(kin, 0.045)
    frame, legs = posed(twin, kin.stand_joints())
    q = twin.joint_positions()
    whole = self_filter.mask(frame, q)
    rear = q.copy()
    rear[9:12] = np.nan  # the middle-back leg, out of view
    np.testing.assert_array_equal(self_filter.mask(frame, rear), whole)
    front = q.copy()
    front[:3] = np.nan  # the middle-front leg
    assert legs.sum() > 0
    assert not self_filter.mask(frame, front).any()


def test_joint_history_answers_the_reading_nearest_a_stamp_within_its_age() -> None:
    history = JointHistory()
    for k in range(10):
        history.add(0.01 * k, np.full(3, float(k)))
    np.testing.assert_array_equal(history.at(0.031, 0.01), np.full(3, 3.0))
    np.testing.assert_array_equal(history.at(0.038, 0.01), np.full(3, 4.0))
    assert history.at(0.2, 0.05) is None  # newer than the last reading by more than the age
    assert history.at(-0.5, 0.05) is None
    history.add(0.05, np.zeros(3))  # a reordered reading: dropped
    np.testing.assert_array_equal(history.at(0.05, 0.001), np.full(3, 5.0))
    history.add(-10.0, np.ones(3))  # a restarted clock: the history begins anew
    assert history.at(0.05, 0.01) is None
    np.testing.assert_array_equal(history.at(-10.0, 0.01), np.ones(3))


class Seen(PerceptionPlugin):
    """Keeps the frames the role hands it, to see what a plugin is given."""

    publishes = (m.Joists,)

    def __init__(self) -> None:
        self.frames: list[DepthFrame] = []

    def process(self, frame: DepthFrame, body: m.BodyState) -> None:
        self.frames.append(frame)


def test_the_perception_role_gives_plugins_frames_without_the_legs(twin: Twin) -> None:
    """No joint reading near a frame's stamp: the frame is refused (``no_joints``, counted);
    with one, the plugin gets the frame with the leg pixels zeroed."""
    kin = Kinematics(QINGZHUI)
    frame, legs = posed(twin, kin.stand_joints())
    role = PerceptionRole(QINGZHUI, argparse.Namespace())
    plugin = Seen()
    plugins = [Isolated("seen", plugin)]
    t = frame.timestamp
    role.on_body(m.BodyState(stamp=t - 0.01, position=[0.0, 0.0, 0.3]))
    role.on_body(m.BodyState(stamp=t + 0.01, position=[0.0, 0.0, 0.3]))
    role.perceive(frame, plugins, lambda message: None)
    assert role.refused == {NO_JOINTS: 1}
    assert plugin.frames == []
    role.on_joints(m.JointState(stamp=t, position=twin.joint_positions().tolist()))
    role.perceive(frame, plugins, lambda message: None)
    (given,) = plugin.frames
    assert not (given.depth[legs]).any()
    assert role.self_pixels >= legs.sum()


def test_a_negative_radius_names_its_field() -> None:
    raw = msgspec.to_builtins(QINGZHUI)
    raw["world"] = {"self_filter": {"radius": -0.01}}
    bad = msgspec.convert(raw, profiles.Profile)
    with pytest.raises(profiles.ProfileError, match=r"\$\.world\.self_filter\.radius"):
        world_config(bad)
