"""Ray-cast depth cameras of the twin: one ray per pixel, rasterised or with ``mj_multiRay``.

Rays leave the camera's optical centre through each pixel of the model's nominal intrinsics
(drivers/realsense/models.py) from the profile's mount pose (``mount_extrinsics``). With
ray directions (x, y, 1) in the optical frame, MuJoCo's hit distance *is* the z-depth.
Where a headless OpenGL context exists (Mesa's llvmpipe needs no GPU) the same rays are
rasterised in one render pass (drivers/sim/gl_depth.py), several times faster; surface normals
then come from the depth image. Otherwise ``mj_multiRay`` casts them. Then
the sensor model: Gaussian noise whose σ grows with range, dropouts on grazing and dark
surfaces and at random, and zeros outside the stream's range — as the real camera reports.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import mujoco
import numpy as np

from climbd.daemon.contract.hardware import DepthFrame, Intrinsics, mount_extrinsics
from climbd.daemon.contract.profile import CameraConfig
from climbd.drivers.realsense.models import model as depth_model
from climbd.drivers.sim.gl_depth import GlDepthPass, gl_available


@dataclass(frozen=True)
class NoiseModel:
    """Depth error σ(z) = a + b·z + c·z² (m) and dropout probabilities.

    ``grazing_deg``: incidence angle beyond which returns fade (all gone at 90°);
    ``dark``: surface reflectance (mean RGB) under which ``dark_dropout`` applies.
    """

    a: float
    b: float
    c: float
    dropout: float = 0.002
    grazing_deg: float = 75.0
    dark: float = 0.15
    dark_dropout: float = 0.6

    def sigma(self, z: np.ndarray) -> np.ndarray:
        """Standard deviation (m) of depth at range ``z`` (m)."""
        return self.a + self.b * z + self.c * z * z


NOISE: dict[str, NoiseModel] = {
    # L515 (LiDAR): ≈ 2.5 mm 1σ at 1 m rising to ≈ 15.5 mm at 9 m; weak on dark surfaces.
    "L515": NoiseModel(a=0.001, b=0.0016, c=0.0, dark_dropout=0.6),
    # D435 (stereo): σ = z² · subpixel / (f · baseline) with subpixel 0.08, f = 384 px at
    # 640×480 and a 50 mm baseline: ≈ 4.2 mm at 1 m, 1.7 % at 2 m (datasheet: ≤ 2 %).
    "D435": NoiseModel(a=0.0, b=0.0, c=0.08 / (384.0 * 0.050), dark_dropout=0.2),
}

GEOM_GROUPS = np.array([1, 0, 1, 0, 0, 0], np.uint8)
"""The camera sees the world (group 0) and the legs (group 2), not the body it sits on."""

NEAR = 0.01
"""Near clipping plane of rasterised depth (m): closer than any camera's minimum range."""


def rotate(points: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``points @ rot.T`` for N×3 ``points``, without BLAS: a BLAS product of a tall, thin
    matrix wakes its thread pool, which on a loaded two-core machine costs several times more."""
    return np.einsum("ij,kj->ik", points, rot)


def surface_normals(z: np.ndarray, rays: np.ndarray, fx: float, fy: float) -> np.ndarray:
    """Unit normals (H×W×3, optical frame) of a z-depth image (H×W, NaN = no return) whose
    pixel (u, v) looks along ``rays`` (H×W×3, (x̃, ỹ, 1)). For P = z·(x̃, ỹ, 1) the normal
    ∂P/∂u × ∂P/∂v is ∝ (−fx·z_u, −fy·z_v, fx·x̃·z_u + fy·ỹ·z_v + z); each image gradient is
    the one-sided step to the neighbour nearer in range, so an edge pixel keeps its surface."""

    def gradient(axis: int) -> np.ndarray:
        step = np.diff(z, axis=axis)
        gap = np.full_like(np.take(z, [0], axis=axis), np.nan)
        back = np.concatenate([gap, step], axis=axis)
        ahead = np.concatenate([step, gap], axis=axis)
        return np.where(np.isnan(ahead) | (np.abs(back) <= np.abs(ahead)), back, ahead)

    zu, zv = fx * gradient(1), fy * gradient(0)
    normal = np.stack([-zu, -zv, rays[..., 0] * zu + rays[..., 1] * zv + z], axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return normal / np.sqrt(np.einsum("...i,...i->...", normal, normal))[..., None]


class RayCastDepth:
    """One depth camera of ``camera``'s model, resolution and mount on body ``body``."""

    def __init__(
        self,
        model: mujoco.MjModel,
        camera: CameraConfig,
        body: int,
        seed: int = 0,
        noise: NoiseModel | None = None,
        intrinsics: Intrinsics | None = None,
        threads: int = 1,
        backend: str = "auto",
    ) -> None:
        spec = depth_model(camera.model)
        self.name = camera.name
        self.model = model
        self.body = body
        self.intrinsics = intrinsics or spec.intrinsics(camera.width, camera.height)
        self.depth_scale = camera.depth_units or spec.depth_unit
        self.min_range = max(camera.min_range, spec.min_range)
        self.max_range = min(camera.max_range, spec.max_range)
        self.period = 1.0 / camera.fps
        self.noise = noise or NOISE[spec.name]
        self.extrinsics = mount_extrinsics(camera)
        self.rng = np.random.default_rng(seed)
        i = self.intrinsics
        u, v = np.meshgrid(np.arange(i.width, dtype=float), np.arange(i.height, dtype=float))
        self.rays = np.stack(
            [(u.ravel() - i.ppx) / i.fx, (v.ravel() - i.ppy) / i.fy, np.ones(u.size)], axis=1
        )
        self.ray_norm = np.linalg.norm(self.rays, axis=1)
        n = len(self.rays)
        self._geomid = np.zeros(n, np.int32)
        self._dist = np.zeros(n)
        self._normal = np.zeros(3 * n)
        self.reflectance = model.geom_rgba[:, :3].mean(axis=1)
        self.number = 0
        bounds = np.linspace(0, n, max(1, threads) + 1).astype(int)
        self._chunks = list(zip(bounds[:-1], bounds[1:], strict=True))
        self._pool = ThreadPoolExecutor(threads) if threads > 1 else None
        square = math.isclose(self.intrinsics.fx, self.intrinsics.fy, rel_tol=1e-9)
        if backend not in ("auto", "gl", "rays"):
            raise ValueError(f"camera {camera.name}: depth backend {backend!r} is not auto/gl/rays")
        if backend == "auto":
            backend = "gl" if square and gl_available() else "rays"
        self.backend = backend
        self._gl: GlDepthPass | None = None

    def pose(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """Camera optical frame in the world: rotation (3×3) and position (m)."""
        r_wb = data.xmat[self.body].reshape(3, 3)
        p_wb = data.xpos[self.body]
        return r_wb @ self.extrinsics[:3, :3], p_wb + r_wb @ self.extrinsics[:3, 3]

    def cast(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Noise-free z-depth (m, NaN for no hit), hit geom ids, unit normals and the world ray
        directions, per pixel. Rasterised with the ``gl`` backend; with ``rays`` and
        ``threads`` > 1 cast in parallel chunks (MuJoCo releases the GIL while it casts)."""
        rot, pos = self.pose(data)
        vec = rotate(self.rays, rot)
        if self.backend == "gl":
            if self._gl is None:
                far = self.max_range * 1.05
                self._gl = GlDepthPass(self.model, self.intrinsics, GEOM_GROUPS, NEAR, far)
            depth, geom = self._gl.render(data, rot, pos)
            i = self.intrinsics
            shape = (i.height, i.width)
            rays = self.rays.reshape(*shape, 3)
            normal = surface_normals(depth.reshape(shape), rays, i.fx, i.fy)
            normal = rotate(normal.reshape(-1, 3), rot)
            return depth, geom, normal, vec
        cutoff = self.max_range * float(self.ray_norm.max())

        def chunk(bounds: tuple[int, int]) -> None:
            lo, hi = bounds
            mujoco.mj_multiRay(
                self.model,
                data,
                pos,
                vec[lo:hi].ravel(),
                GEOM_GROUPS,
                1,
                self.body,
                self._geomid[lo:hi],
                self._dist[lo:hi],
                self._normal[3 * lo : 3 * hi],
                hi - lo,
                cutoff,
            )

        if self._pool is None:
            chunk(self._chunks[0])
        else:
            list(self._pool.map(chunk, self._chunks))
        depth = np.where(self._geomid >= 0, self._dist, np.nan)
        return depth, self._geomid, self._normal.reshape(-1, 3), vec

    def render(self, data: mujoco.MjData, timestamp: float) -> DepthFrame:
        """One frame as the camera would deliver it (uint16 depth, 0 = no return)."""
        depth, geom, normal, vec = self.cast(data)
        hit = np.isfinite(depth)
        z = np.where(hit, depth, 0.0)
        nz = self.noise
        z = z + nz.sigma(z) * self.rng.standard_normal(z.size)
        cos_inc = np.abs(np.einsum("ij,ij->i", normal, vec)) / self.ray_norm
        cos_inc = np.nan_to_num(cos_inc, nan=1.0)
        fade = math.cos(math.radians(nz.grazing_deg))
        p_drop = np.full(z.size, nz.dropout)
        p_drop += np.clip((fade - cos_inc) / fade, 0.0, 1.0)
        p_drop += np.where(self.reflectance[np.maximum(geom, 0)] < nz.dark, nz.dark_dropout, 0.0)
        keep = hit & (self.rng.random(z.size) >= p_drop)
        keep &= (z >= self.min_range) & (z <= self.max_range)
        units = np.where(keep, np.rint(z / self.depth_scale), 0.0)
        image = (
            np.clip(units, 0, 65535)
            .astype(np.uint16)
            .reshape(self.intrinsics.height, self.intrinsics.width)
        )
        frame = DepthFrame(
            depth=image,
            depth_scale=self.depth_scale,
            intrinsics=self.intrinsics,
            extrinsics=self.extrinsics,
            timestamp=timestamp,
            number=self.number,
        )
        self.number += 1
        return frame

    def close(self) -> None:
        """Free the OpenGL context of the ``gl`` backend, if one was made (a later frame makes
        a new one)."""
        if self._gl is not None:
            self._gl.close()
            self._gl = None
