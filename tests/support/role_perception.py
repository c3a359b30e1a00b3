"""The perception role in a stepped twin run, on the path a robot's frames take.

Each frame the twin ray-casts goes through the pyrealsense2 software device (as the role reads
a USB camera), and ``PerceptionRole.perceive`` does with it what it does live: the pose at the
frame's stamp from the control role's body states, the legs' pixels dropped at the joints
nearest that stamp, the profile's perception plugins, the world model. The hold maps it
publishes cross a real Zenoh session (loopback) to the side that gives them to the controller.
Stepped: each frame is perceived and its map delivered before the run goes on, so runs stay
deterministic; the control role's body states and joints go to the role directly, tick by
tick (``sense``).
"""

from __future__ import annotations

import argparse
import queue

from climbd.daemon.contract.messages import BodyState, HoldMap, JointState, Message
from climbd.daemon.contract.profile import Profile
from climbd.daemon.runtime.network import Endpoints, Network, zenoh_config
from climbd.daemon.runtime.perception_role import PerceptionRole, make_plugins
from climbd.drivers.sim.twin import Twin
from support.ports import free_port

DELIVERY_WAIT = 1.0
"""s: how long a hold map is waited for at the subscriber before it is put again."""
DELIVERY_TRIES = 10
"""Puts of one hold map before the Zenoh link counts as down (the first may precede it)."""


class SteppedPerception:
    """``profile``'s perception role on ``twin``'s ``camera``, its hold maps over Zenoh."""

    def __init__(self, profile: Profile, twin: Twin, camera: str = "front") -> None:
        self.twin, self.name = twin, camera
        self.role = PerceptionRole(profile, argparse.Namespace())
        self.plugins = make_plugins(profile, None, self.role.plugin_failed)
        self.camera = twin.software_camera(camera, fed=False)
        self.camera.open()
        self.frames = self.camera.frames()
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.control = Network(
            profile.name, zenoh_config(None, "control", Endpoints([self.endpoint], []))
        )
        self.perception = Network(
            profile.name, zenoh_config(None, "perception", Endpoints([], [self.endpoint]))
        )
        self.received: queue.Queue[Message] = queue.Queue()
        self.control.subscribe(HoldMap, self.received.put)
        self.latest: HoldMap | None = None
        """The last hold map the control side received."""

    def sense(self, body: BodyState, joints: JointState) -> None:
        """A body state and the joints the control role publishes, into the role."""
        self.role.on_body(body)
        self.role.on_joints(joints)

    def look(self, stamp: float | None = None) -> HoldMap | None:
        """One frame of the twin as it is now, stamped ``stamp`` (None: the twin's time),
        through the software device and the role; the newest hold map the control side has
        received over Zenoh (None before the first)."""
        frame = self.twin.depth_frame(self.name)
        self.camera.push(frame.depth, frame.timestamp if stamp is None else stamp)
        published: list[Message] = []
        self.role.perceive(next(self.frames), self.plugins, published.append)
        for sent in published:
            if isinstance(sent, HoldMap):
                self.latest = self._deliver(sent)
        if self.role.failure:
            raise RuntimeError(f"perception role: {self.role.failure}")
        return self.latest

    def _deliver(self, sent: HoldMap) -> HoldMap:
        """Put ``sent`` over Zenoh and wait for it at the control side (put again while the
        link comes up); what arrived, decoded."""
        for _ in range(DELIVERY_TRIES):
            self.perception.put(sent)
            try:
                while True:
                    got = self.received.get(timeout=DELIVERY_WAIT)
                    if isinstance(got, HoldMap) and got.stamp == sent.stamp:
                        return got
            except queue.Empty:
                continue
        raise RuntimeError(f"hold map of {sent.stamp:.3f} s never crossed Zenoh {self.endpoint}")

    def close(self) -> None:
        """Close the camera and both Zenoh sessions."""
        self.camera.close()
        self.perception.close()
        self.control.close()
