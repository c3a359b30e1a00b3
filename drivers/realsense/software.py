"""A software RealSense: frames from any producer (twin, test) enter through rs.software_device.

Everything after the device is the code a USB camera runs: RealSenseCamera's options, stream
profile, recorder, filters and conversion. ``unplug()``/``replug()`` simulate a cable pull.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyrealsense2 as rs

from climbd.daemon.contract.hardware import DriverError, Intrinsics
from climbd.daemon.contract.profile import CameraConfig
from climbd.drivers.realsense.camera import RealSenseCamera
from climbd.drivers.realsense.models import model


def rs_intrinsics(intrinsics: Intrinsics) -> rs.intrinsics:
    """Our pinhole Intrinsics as pyrealsense2's (no distortion), e.g. for rs2_deproject_pixel."""
    i = rs.intrinsics()
    i.width, i.height = intrinsics.width, intrinsics.height
    i.fx, i.fy, i.ppx, i.ppy = intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy
    i.model = rs.distortion.none
    i.coeffs = [0.0] * 5
    return i


class SoftwareSource:
    """Makes a fresh ``rs.software_device`` with one Z16 depth stream on every (re)connect."""

    finite = False
    wall_clock = False

    def __init__(
        self, intrinsics: Intrinsics, depth_scale: float, fps: int, model_name: str, serial: str
    ) -> None:
        self.intrinsics = intrinsics
        self.depth_scale = depth_scale
        self.fps = fps
        self.model = model(model_name)
        self.serial = serial
        self.label = f"software {model_name} {serial}"
        self.real_time = True
        self.plugged = True
        self.on_lost: Callable[[str], None] | None = None
        self._lock = threading.Lock()
        self._sensor: rs.software_sensor | None = None
        self._profile: rs.video_stream_profile | None = None
        self._device: rs.software_device | None = None

    def connect(self) -> rs.device:
        with self._lock:
            if not self.plugged:
                raise DriverError(f"no RealSense with serial {self.serial}; found: none")
            device = rs.software_device()
            sensor = device.add_sensor("Depth")
            i = self.intrinsics
            stream = rs.video_stream()
            stream.type, stream.index, stream.uid = rs.stream.depth, 0, 0
            stream.width, stream.height, stream.fps = i.width, i.height, self.fps
            stream.bpp, stream.fmt, stream.intrinsics = 2, rs.format.z16, rs_intrinsics(i)
            profile = sensor.add_video_stream(stream).as_video_stream_profile()
            sensor.add_read_only_option(rs.option.depth_units, self.depth_scale)
            device.register_info(rs.camera_info.name, f"Intel RealSense {self.model.name}")
            device.register_info(rs.camera_info.serial_number, self.serial)
            device.register_info(rs.camera_info.product_line, self.model.product_line)
            self._device, self._sensor, self._profile = device, sensor, profile
            return device

    def push(self, depth: np.ndarray, timestamp: float, number: int) -> None:
        """Hand one uint16 depth image (timestamp in s) to the device, as its USB link would."""
        i = self.intrinsics
        if depth.dtype != np.uint16 or depth.shape != (i.height, i.width):
            raise DriverError(
                f"{self.label}: push: expected uint16 depth of shape ({i.height}, {i.width}), "
                f"found {depth.dtype} {depth.shape}"
            )
        with self._lock:
            if self._sensor is None:
                raise DriverError(f"{self.label}: push while unplugged or before open()")
            frame = rs.software_video_frame()
            frame.pixels = np.ascontiguousarray(depth)
            frame.bpp = 2
            frame.stride = 2 * i.width
            frame.timestamp = timestamp * 1000.0
            frame.domain = rs.timestamp_domain.global_time
            frame.frame_number = number
            frame.profile = self._profile
            self._sensor.on_video_frame(frame)

    def unplug(self) -> None:
        """The device disappears: pushes fail, enumeration no longer finds it."""
        with self._lock:
            self.plugged = False
            self._device = self._sensor = self._profile = None
        if self.on_lost is not None:
            self.on_lost(f"{self.label} unplugged")

    def replug(self) -> None:
        """The device is back: the camera's next reconnect attempt finds it."""
        with self._lock:
            self.plugged = True


class SoftwareDepthCamera(RealSenseCamera):
    """A RealSense camera fed by ``push(depth_u16, timestamp)``: the twin's and tests' camera.

    ``timeout`` defaults to None (a stepped-clock producer may pause); ``record_to`` records
    the pushed frames through librealsense's recorder exactly as for a USB camera.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        depth_scale: float,
        extrinsics: np.ndarray,
        *,
        fps: int = 30,
        model: str = "D435",
        serial: str = "SW-DEPTH-0",
        config: CameraConfig | None = None,
        record_to: str | Path | None = None,
        timeout: float | None = None,
        backoff: tuple[float, float] = (0.05, 0.5),
        queue_size: int = 2,
    ) -> None:
        source = SoftwareSource(intrinsics, depth_scale, fps, model, serial)
        if config is None:
            config = CameraConfig(
                name="software",
                model=model,
                serial=serial,
                width=intrinsics.width,
                height=intrinsics.height,
                fps=fps,
            )
        super().__init__(
            config,
            source,
            extrinsics=extrinsics,
            record_to=record_to,
            timeout=timeout,
            backoff=backoff,
            queue_size=queue_size,
        )
        self.software = source
        self._pushed = 0

    def push(self, depth: np.ndarray, timestamp: float) -> None:
        """Deliver one uint16 depth image taken at ``timestamp`` (s, the control role's clock:
        monotonic, or simulated time in lock-step)."""
        self.software.push(depth, timestamp, self._pushed)
        self._pushed += 1

    def unplug(self) -> None:
        """Simulate a cable pull: the stream stops and the device vanishes until ``replug()``."""
        self.software.unplug()

    def replug(self) -> None:
        """Simulate plugging the cable back in."""
        self.software.replug()
