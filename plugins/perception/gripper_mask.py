"""The 3-D gripper mask of paper 001 (§2.2, Fig. 3) from a spine gripper's geometry.

The mask is a voxel array at the terrain matrix's pitch: axis 0/1 span the gripper's reach
around the palm centre, axis 2 is depth below the palm (index 0 = the palm's level). A cell is
solid (True) where terrain may be when the gripper closes on the point under the palm centre,
void (False) where terrain would stop it. Its shape follows ClimbLab's passive spine gripper:
a cone opening from the palm at (90° − opening angle) to the fingers' span, free space beyond
the spines' reach, and a void disk where the closed spine tips meet, which the hold must fill
around rather than reach into.
"""

from __future__ import annotations

import math

import msgspec
import numpy as np


class GripperGeometry(msgspec.Struct, forbid_unknown_fields=True, kw_only=True):
    """Spine gripper geometry in metres and degrees; defaults are ClimbLab's HubRobo gripper.

    ``opening_spine_radius``, ``opening_spine_depth`` and ``closing_height`` are ClimbLab's
    CAD measurements (spine tip radius and depth when open, spine tip to palm when closed).
    """

    palm_diameter: float = 0.032
    palm_diameter_of_finger_joints: float = 0.028
    finger_length: float = 0.015
    spine_length: float = 0.015
    spine_depth: float = 0.005
    opening_angle: float = 75.0
    closing_angle: float = 30.0
    opening_spine_radius: float = 0.037
    opening_spine_depth: float = 0.005
    closing_height: float = 0.016
    margin_top_solid: float = 0.004
    margin_bottom_void: float = 0.002

    def check(self) -> None:
        """Raise ValueError naming the field when the geometry cannot make a mask."""
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"gripper.{name}: expected a finite value > 0, found {value}")
        if not 0 < self.opening_angle < 90:
            raise ValueError(
                f"gripper.opening_angle: expected 0..90 deg, found {self.opening_angle}"
            )
        if not 0 < self.closing_angle < 90:
            raise ValueError(
                f"gripper.closing_angle: expected 0..90 deg, found {self.closing_angle}"
            )


def _round(x: float) -> int:
    """Round half away from zero, as the gripper's CAD-to-voxel conversion does."""
    return int(math.floor(x + 0.5))


def _voxels(length: float, voxel: float) -> int:
    return _round(length / voxel)


def gripper_mask(geometry: GripperGeometry, voxel: float) -> np.ndarray:
    """Boolean mask (2h+1, 2h+1, depth) at pitch ``voxel`` (m); True = terrain allowed (§2.2)."""
    geometry.check()
    if not (math.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel: expected a finite size > 0 m, found {voxel}")
    g = geometry
    palm = _voxels(g.palm_diameter, voxel)
    half = (
        _voxels(g.palm_diameter_of_finger_joints, voxel) // 2
        + _voxels(g.finger_length, voxel)
        + _voxels(g.spine_length, voxel)
    )
    size = 2 * half + 1
    depth = max(_voxels(g.closing_height, voxel), 2)
    top_solid_r = _round((palm + _voxels(g.margin_top_solid, voxel)) / 2)
    clearance = max(_round((size - palm) / 2 * math.tan(math.radians(90.0 - g.opening_angle))), 2)
    bottom_void_r = _round(
        palm / 2
        + depth * math.tan(math.radians(g.closing_angle))
        - _voxels(g.margin_bottom_void, voxel)
    )
    spine_reach = _voxels(g.opening_spine_radius, voxel) + _voxels(g.spine_depth, voxel)
    spine_drop = max(_voxels(g.opening_spine_depth, voxel), 2)

    offsets = np.arange(size) - half
    r = np.hypot(offsets[:, None], offsets[None, :])
    mask = np.ones((size, size, depth), dtype=bool)
    for k in range(clearance):
        cone_r = top_solid_r + (half - top_solid_r) * k / (clearance - 1)
        reach_r = half - _round(half - spine_reach) * k / (spine_drop - 1)
        mask[:, :, k] = (r < cone_r) | (r > reach_r)
    mask[:, :, depth - 1] = r > bottom_void_r
    return mask
