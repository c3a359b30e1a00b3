"""Byte-level Dynamixel servo emulator on a pseudo-terminal (Protocol 1.0 and 2.0).

In-process API (for tests and the physics twin)::

    chain = ServoChain.from_profile(profile)          # one EmulatedServo per joint, profile ids
    with DynamixelEmulator(chain) as emu:             # pty + background thread
        bus = DynamixelBus.from_profile(profile, port=emu.port)   # or any dynamixel_sdk client
        ...
        chain.joint_goals()          # goal positions: horn angles about the centre, profile order
        chain.set_joint_state(q, dq, tau)  # physics writes present state (joint frame, SI)
        chain.servo(3).set_present(temperature=80.0)   # → overheat bit / shutdown
        chain.servo(3).inject_overload()               # → overload bit / shutdown
        chain.silence(3); chain.silence(3, on=False)   # servo stops / resumes answering
        chain.boot_time = 0.1                          # REBOOT: silent this long (s), then
                                                       # RAM at power-on values, torque off
        chain.corrupt(3, count=2)                      # next 2 replies with bad checksum/CRC
        emu.vanish()                                   # the port disappears

``EmulatedServo``: raw control table (``get``/``set``/``memory``), SI view (``goal_angle``,
``torque_enabled``, ``speed_limit``, ``state``: angle, velocity, effort, temperature,
voltage), ``set_present(...)``, and a first-order motor model (speed and torque limited)
stepped by the server in wall-clock time. A physics twin sets ``servo.external = True`` on
each servo (or builds the server with ``realtime_motor=False``) and drives the present state
itself each step; ``chain.advance(dt)`` steps the built-in model in simulated time.

Wire timing: every reply reaches the pty when its last byte would arrive on a real bus,
bytes × 10 / baud for the instruction and the reply plus the servo's return delay
(2 µs × Return Delay Time; factory default 250 = 500 µs until the host sets it).

USB serial adapter: ``DynamixelEmulator(chain, latency_ms=16)`` (``--latency-ms 16``) puts an
FTDI-style adapter (U2D2) between the pty and the bus: instructions reach the bus on the next
1 ms USB frame, replies are held until the latency timer has run since their last byte or 62
bytes have gathered (adapter.py). Without it (the default) the pty is wired to the bus.

Command line: ``python -m climbd.drivers.sim.dynamixel --profile robots/widowx.toml`` prints the
port path and serves until interrupted.
"""

from climbd.drivers.sim.dynamixel.chain import ServoChain
from climbd.drivers.sim.dynamixel.server import DynamixelEmulator
from climbd.drivers.sim.dynamixel.servo import EmulatedServo
from climbd.drivers.sim.dynamixel.tables import SPECS, ServoSpec

__all__ = ["SPECS", "DynamixelEmulator", "EmulatedServo", "ServoChain", "ServoSpec"]
