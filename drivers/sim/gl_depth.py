"""Rasterised depth for the twin's cameras: MuJoCo's OpenGL renderer on a headless EGL context.

One render pass per frame samples the same rays ``mj_multiRay`` would (one through each pixel
centre of the camera's intrinsics) and reads back z-depth and the geom each pixel sees. On a
machine without a GPU, Mesa's llvmpipe rasterises a 640×480 frame several times faster than
ray casting it, which is what lets the twin keep real time beside the daemon on two cores.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from climbd.daemon.contract.hardware import Intrinsics


@functools.cache
def gl_available() -> bool:
    """Whether a headless EGL context (GPU or Mesa's software rasteriser) can be made here."""
    try:
        from mujoco.egl import GLContext

        GLContext(16, 16).free()
    except (ImportError, RuntimeError, AttributeError, OSError):
        return False
    return True


class GlDepthPass:
    """Z-depth (m) and geom id per pixel of one pinhole camera, rasterised with OpenGL.

    ``groups``: the geom groups the camera sees. Square pixels only (fx = fy): OpenGL's
    frustum keeps the viewport's aspect ratio.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        intrinsics: Intrinsics,
        groups: np.ndarray,
        near: float,
        far: float,
    ) -> None:
        from mujoco.egl import GLContext

        self._gl = None
        i = intrinsics
        if not np.isclose(i.fx, i.fy, rtol=1e-9):
            raise ValueError(
                f"OpenGL depth needs square pixels: fx {i.fx} ≠ fy {i.fy}; use ray casting"
            )
        self.model = model
        self.width, self.height = i.width, i.height
        self.near, self.far = float(near), float(far)
        vis = model.vis.global_
        vis.offwidth, vis.offheight = max(vis.offwidth, i.width), max(vis.offheight, i.height)
        self._gl = GLContext(i.width, i.height)
        with self._gl.as_current():  # and released after, for whichever thread renders
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_50.value)
            mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self._con.readDepthMap = mujoco.mjtDepthMap.mjDEPTH_ZEROFAR
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom))
        flags, off = self._scene.flags, mujoco.mjtRndFlag
        for flag in (off.mjRND_SHADOW, off.mjRND_REFLECTION, off.mjRND_SKYBOX, off.mjRND_FOG):
            flags[flag] = 0
        flags[off.mjRND_HAZE] = 0
        flags[off.mjRND_SEGMENT] = flags[off.mjRND_IDCOLOR] = 1
        self._option = mujoco.MjvOption()
        self._option.geomgroup[:] = groups
        self._option.sitegroup[:] = 0
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FREE
        self._rect = mujoco.MjrRect(0, 0, i.width, i.height)
        n = self.near / i.fx
        self._frustum = (
            ((i.width - 1) / 2 - i.ppx) * n,
            (i.ppy + 0.5 - i.height) * n,
            (i.ppy + 0.5) * n,
        )
        self._rgb = np.zeros((i.height, i.width, 3), np.uint8)
        self._zbuf = np.zeros((i.height, i.width), np.float32)
        f, z = np.float32(self.far), np.float32(self.near)
        self._c = np.float32(-0.5) * (-(f + z) / (f - z)) - np.float32(0.5)
        self._d = np.float32(-0.5) * (-(np.float32(2) * f * z) / (f - z))

    def render(
        self, data: mujoco.MjData, rot: np.ndarray, pos: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Z-depth (m, NaN where nothing is hit within ``far``) and geom id (-1 there), both
        row-major like the image, for the optical frame ``rot`` (x right, y down, z ahead)
        at ``pos`` in the world."""
        with self._gl.as_current():  # released after: the next frame may be another thread's
            mujoco.mjv_updateScene(
                self.model,
                data,
                self._option,
                None,
                self._camera,
                mujoco.mjtCatBit.mjCAT_STATIC | mujoco.mjtCatBit.mjCAT_DYNAMIC,
                self._scene,
            )
            centre, bottom, top = self._frustum
            for cam in self._scene.camera:
                cam.pos[:] = pos
                cam.forward[:] = rot[:, 2]
                cam.up[:] = -rot[:, 1]
                cam.frustum_center, cam.frustum_bottom, cam.frustum_top = centre, bottom, top
                cam.frustum_near, cam.frustum_far = self.near, self.far
                cam.orthographic = 0
            mujoco.mjr_render(self._rect, self._scene, self._con)
            mujoco.mjr_readPixels(self._rgb, self._zbuf, self._rect, self._con)
        rgb = self._rgb[::-1].astype(np.int32)
        segid = rgb[..., 0] + (rgb[..., 1] << 8) + (rgb[..., 2] << 16)
        lookup = np.full(self._scene.ngeom + 1, -1, np.int32)
        for g in self._scene.geoms[: self._scene.ngeom]:
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM and g.segid >= 0:
                lookup[g.segid + 1] = g.objid
        geom = lookup[np.minimum(segid, len(lookup) - 1)].ravel()
        depth = (self._d / (self._zbuf[::-1].astype(np.float64) + self._c)).ravel()
        depth[geom < 0] = np.nan
        return depth, geom

    def close(self) -> None:
        """Free the OpenGL resources (idempotent)."""
        if self._gl is not None:
            with self._gl.as_current():
                self._con.free()
            self._gl.free()
            self._gl = None

    def __del__(self) -> None:
        self.close()
