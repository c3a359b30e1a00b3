"""Actuator physics of the twin: servo datasheet figures, the motor law and a thermal model.

A Dynamixel is a P-controller driving a DC motor's duty cycle, so its torque follows the
motor's torque–speed line (stall torque at rest, zero at the no-load speed). Torque-controlled
legs run the MIT-mode law τ = kp·e + kd·ė + τ_ff under the same line. Winding heat grows
as (τ/τ_stall)² against one thermal resistance to ambient.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from climbd.drivers.sim.dynamixel.tables import SPECS


@dataclass(frozen=True)
class ServoModel:
    """Datasheet figures of one actuator at 12 V (SI units).

    ``kp`` is the firmware's default position gain as torque per radian of error; ``armature``
    the rotor inertia reflected through the gearbox; ``stall_power`` the electrical power at
    stall (W), which heats the winding; ``thermal_resistance`` (K/W) and ``heat_capacity``
    (J/K) to ambient.
    """

    name: str
    stall_torque: float
    no_load_speed: float
    mass: float
    kp: float
    armature: float
    friction: float
    stall_power: float
    thermal_resistance: float = 3.0
    heat_capacity: float = 100.0


# Physical extras of the Dynamixel models the emulator knows (stall torque and no-load speed
# come from its tables): mass (kg), error at which the firmware's default gain saturates the
# drive (AX compliance slope 32 ≈ 9.4°; X series position P gain 800 ≈ 12.4°), reflected
# rotor inertia (kg·m²), gearbox friction (N·m) and electrical power at stall (W).
_EXTRAS: dict[str, tuple[float, float, float, float, float]] = {
    "AX-18A": (0.0545, 9.4, 0.004, 0.02, 26.4),
    "XL430-W250": (0.0572, 12.4, 0.005, 0.02, 16.8),
    "XM430-W350": (0.082, 12.4, 0.01, 0.03, 27.6),
    "XM430-W210": (0.082, 12.4, 0.008, 0.03, 27.6),
}


def torque_motor(effort: float, velocity: float) -> ServoModel:
    """A torque-controlled joint motor (MIT mode) sized from the profile's effort and speed."""
    return ServoModel(
        "mit", effort, 2.0 * velocity, 0.5, 0.0, 0.02, 0.05, 12.0 * effort, 1.0, 400.0
    )


def servo_model(name: str, source: str = "profile") -> ServoModel:
    """The physics of a Dynamixel model: the emulator's datasheet figures plus our extras."""

    if name not in SPECS or name not in _EXTRAS:
        known = sorted(set(SPECS) & set(_EXTRAS))
        raise ValueError(f"{source}: $.bus.model: the twin has no model {name!r}; known: {known}")
    spec = SPECS[name]
    mass, saturate_deg, armature, friction, stall_power = _EXTRAS[name]
    return ServoModel(
        name,
        spec.stall_torque,
        spec.no_load_speed,
        mass,
        spec.stall_torque / math.radians(saturate_deg),
        armature,
        friction,
        stall_power,
    )


def servo_torque(
    error: np.ndarray,
    velocity: np.ndarray,
    kp: np.ndarray,
    stall: np.ndarray,
    no_load: np.ndarray,
    limit: np.ndarray,
) -> np.ndarray:
    """Torque of a position servo: duty u = clip(kp·e/τ_stall, ±1), τ = τ_stall·(u − ω/ω_0).

    The DC motor's back-EMF gives the torque–speed line; ``limit`` (≤ τ_stall) is the torque
    limit register's current cap.
    """
    duty = np.clip(kp * error / stall, -1.0, 1.0)
    return np.clip(stall * (duty - velocity / no_load), -limit, limit)


def mit_torque(
    error: np.ndarray,
    rate_error: np.ndarray,
    kp: np.ndarray,
    kd: np.ndarray,
    feed_forward: np.ndarray,
    velocity: np.ndarray,
    stall: np.ndarray,
    no_load: np.ndarray,
) -> np.ndarray:
    """MIT-mode torque τ = kp·e + kd·ė + τ_ff, bounded by the torque–speed line at ω."""
    tau = kp * error + kd * rate_error + feed_forward
    slope = stall / no_load
    upper = np.clip(stall - slope * velocity, 0.0, stall)
    lower = np.clip(-stall - slope * velocity, -stall, 0.0)
    return np.clip(tau, lower, upper)


@dataclass
class ThermalState:
    """Winding temperatures (°C) of a bank of motors, heated by load and cooled to ambient."""

    temperature: np.ndarray
    ambient: float = 25.0

    def advance(
        self,
        load: np.ndarray,
        stall_power: np.ndarray,
        r_th: np.ndarray,
        c_th: np.ndarray,
        dt: float,
    ) -> None:
        """Integrate C·dT/dt = P_stall·(τ/τ_stall)² − (T − T_amb)/R over ``dt`` (exactly)."""
        steady = self.ambient + stall_power * np.square(load) * r_th
        alpha = 1.0 - np.exp(-dt / (r_th * c_th))
        self.temperature += alpha * (steady - self.temperature)
