"""Synthetic attic scenes for joist tests and benchmarks: a floor, joists of known pose, ray-cast.

A pinhole depth camera (640×480, L515 field of view) on a tilted mount is ray-cast against the
floor and box-shaped joists, so point density falls with range and joists occlude what lies
behind them, as with a real camera; range noise grows with distance and a few returns drop out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from climbd.daemon.contract.messages import BodyState


@dataclass(frozen=True)
class JoistSpec:
    """A joist in the world frame: its near face crosses the x axis at ``distance``.

    ``yaw`` is the yaw of the face normal (0: square to the x axis); width and length in m.
    """

    distance: float
    yaw: float
    height: float
    width: float = 0.04
    length: float = 3.0

    def distance_from(self, x: float, y: float) -> float:
        """Ground-truth distance along +x from a robot at (x, y), heading along +x."""
        return self.distance - x - y * math.tan(self.yaw)


@dataclass(frozen=True)
class DepthCamera:
    """Camera on the body: mount height/forward offset (m), pitch down (rad), L515 FOV."""

    height: float = 0.30
    forward: float = 0.10
    pitch: float = math.radians(25.0)
    width: int = 640
    height_px: int = 480
    hfov: float = math.radians(70.0)
    vfov: float = math.radians(55.0)
    max_range: float = 4.0


def body_state(x: float = 0.0, y: float = 0.0, yaw: float = 0.0) -> BodyState:
    """BodyState at (x, y) on the floor, heading ``yaw``."""
    return BodyState(
        position=[x, y, 0.0], orientation=[math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    )


def _camera_rays(cam: DepthCamera) -> np.ndarray:
    """Unit ray directions in the body frame (x forward, y left, z up), one per pixel."""
    u = np.linspace(-math.tan(cam.hfov / 2), math.tan(cam.hfov / 2), cam.width)
    v = np.linspace(-math.tan(cam.vfov / 2), math.tan(cam.vfov / 2), cam.height_px)
    uu, vv = np.meshgrid(u, v)
    # Optical frame (x right, y down, z forward) to a level body-aligned frame.
    d = np.stack([np.ones_like(uu), -uu, -vv], axis=-1).reshape(-1, 3)
    c, s = math.cos(cam.pitch), math.sin(cam.pitch)
    pitch_down = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    d = d @ pitch_down.T
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _hit_box(origin: np.ndarray, dirs: np.ndarray, joist: JoistSpec) -> np.ndarray:
    """Ray parameter of the first hit on a joist box (inf where missed), slab method."""
    n = np.array([math.cos(joist.yaw), math.sin(joist.yaw), 0.0])
    u = np.array([-math.sin(joist.yaw), math.cos(joist.yaw), 0.0])
    corner = np.array([joist.distance, 0.0, 0.0])
    axes = np.stack([n, u, [0.0, 0.0, 1.0]])
    lo = np.array([0.0, -joist.length / 2, 0.0])
    hi = np.array([joist.width, joist.length / 2, joist.height])
    o = axes @ (origin - corner)
    d = dirs @ axes.T
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - o) / d
        t2 = (hi - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    hit = (tmax >= tmin) & (tmax > 0)
    return np.where(hit, np.maximum(tmin, 0.0), np.inf)


def render(
    joists: list[JoistSpec],
    x: float = 0.0,
    y: float = 0.0,
    yaw: float = 0.0,
    camera: DepthCamera | None = None,
    rng: np.random.Generator | None = None,
    noise: float = 1.0,
    dropout: float = 0.03,
) -> np.ndarray:
    """Body-frame points (N×3, float32) seen by the camera of a robot at (x, y, yaw).

    Range noise σ = (1.5 mm + 1.5 mm/m · range) × ``noise``; ``dropout`` of returns are lost.
    """
    cam = camera or DepthCamera()
    rng = rng or np.random.default_rng(0)
    c, s = math.cos(yaw), math.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    dirs = _camera_rays(cam) @ rot.T
    origin = np.array([x, y, 0.0]) + rot @ np.array([cam.forward, 0.0, cam.height])
    with np.errstate(divide="ignore"):
        t = np.where(dirs[:, 2] < 0, -origin[2] / dirs[:, 2], np.inf)
    for joist in joists:
        t = np.minimum(t, _hit_box(origin, dirs, joist))
    keep = (t < cam.max_range) & (rng.random(t.size) >= dropout)
    t, dirs = t[keep], dirs[keep]
    t = t + rng.normal(0.0, 1.0, t.size) * (0.0015 + 0.0015 * t) * noise
    world = origin + dirs * t[:, None]
    body = (world - np.array([x, y, 0.0])) @ rot
    return body.astype(np.float32)
