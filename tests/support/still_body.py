"""Body states and joint readings of a robot standing still (its stand pose), as its control role
publishes them: for tests that run the perception role's worker without a control role."""

from __future__ import annotations

import threading
import time

from climbd.daemon.algorithms.kinematics import Kinematics
from climbd.daemon.contract.messages import BodyState, JointState
from climbd.daemon.runtime.perception_role import PerceptionRole

RATE_HZ = 50.0


class StillBody:
    """Feeds ``role``'s pose history at 50 Hz on the monotonic clock until stopped (a context
    manager); the first state is in before ``__enter__`` returns."""

    def __init__(self, role: PerceptionRole) -> None:
        self.role = role
        self.joints = Kinematics(role.profile).stand_joints().tolist()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="still-body", daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(1.0 / RATE_HZ):
            self._publish()

    def _publish(self) -> None:
        stamp = time.monotonic()
        self.role.on_body(BodyState(stamp=stamp))
        self.role.on_joints(JointState(stamp=stamp, position=self.joints))

    def __enter__(self) -> StillBody:
        self._publish()
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(1.0)
