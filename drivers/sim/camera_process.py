"""The real-time twin's depth cameras rendered in a child process.

Rendering a frame is tens of milliseconds of Python and numpy: in the control role's process
it holds the interpreter lock that the driver, the emulated bus and the control loop wait
for. A child process (spawned, so no Zenoh or pty state is inherited) holds its own copy of
the model; each frame it gets the joint state, renders with the same camera models and seeds
as the twin would in-process, and sends the image back. The parent waits for it in a pipe
read, which releases the lock.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
from collections.abc import Callable
from multiprocessing.connection import Connection

import numpy as np

from climbd.daemon.contract.hardware import DepthFrame
from climbd.daemon.contract.profile import Profile
from climbd.drivers.sim.worlds import World

Serve = Callable[[Connection, Profile, World, float, dict], None]
"""The child's loop (``climbd.drivers.sim.twin.serve_cameras``): renders each requested
(camera, qpos, time) and answers with the uint16 image; a module-level function, so a spawned
process can import it."""


class CameraProcess:
    """Renders ``profile``'s cameras for a real-time twin in a child process; ``options`` are
    the Twin's depth options (``seed``, ``depth_backend``, ``depth_threads``)."""

    def __init__(
        self, serve: Serve, profile: Profile, world: World, timestep: float, **options
    ) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(
            target=serve,
            args=(child, profile, world, timestep, options),
            name="twin-cameras",
            daemon=True,
        )
        self._process.start()
        child.close()
        if not self._conn.poll(60.0) or not self._conn.recv():
            self.close()
            raise RuntimeError(f"twin of {profile.name}: the camera process did not start")

    def render(self, camera, name: str, qpos: np.ndarray, t: float) -> DepthFrame:
        """One frame of ``camera`` (the twin's RayCastDepth named ``name``) at joint state
        ``qpos`` and simulated time ``t``; blocks until the child has rendered it."""
        try:
            self._conn.send((name, qpos, t))
            image = np.frombuffer(self._conn.recv_bytes(), np.uint16)
        except (EOFError, OSError) as e:
            raise RuntimeError(
                f"twin camera process (pid {self._process.pid}) ended while rendering {name!r}: "
                f"exit code {self._process.exitcode}"
            ) from e
        i = camera.intrinsics
        frame = DepthFrame(
            depth=image.reshape(i.height, i.width),
            depth_scale=camera.depth_scale,
            intrinsics=i,
            extrinsics=camera.extrinsics,
            timestamp=t,
            number=camera.number,
        )
        camera.number += 1
        return frame

    def close(self) -> None:
        """Ask the child to end, and end it if it does not (idempotent)."""
        if self._process.is_alive():
            with contextlib.suppress(OSError):
                self._conn.send(None)
            self._process.join(5.0)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(2.0)
        self._conn.close()
