"""The RealSense depth camera on pyrealsense2: one code path for live, recorded, software devices.

A *source* hands over an ``rs.device`` (a USB camera, a playback of a recording, or a software
device); from there on everything is the same: stream profile and options from the profile,
the depth sensor's callback, optional recording through ``rs.recorder``, post-processing
filters, conversion to DepthFrame, and reconnect with back-off when the device goes away.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Iterator
from importlib.metadata import version
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import pyrealsense2 as rs

from climbd.daemon.contract.hardware import (
    CameraHealth,
    DepthFrame,
    DriverError,
    Intrinsics,
    mount_extrinsics,
)
from climbd.daemon.contract.profile import CameraConfig
from climbd.drivers.realsense.models import L515, model

log = logging.getLogger("climbd.realsense")

FILTERS = ("decimation", "threshold", "spatial", "temporal", "hole_filling")
_LOST = object()


def host_time(stamp_ms: float, domain: rs.timestamp_domain) -> float:
    """A USB camera's frame stamp (s) on the host's monotonic clock, the control role's clock
    that body poses are stamped on: global and system time are the host's wall clock moved onto
    it; a device-clock stamp (firmware without global time) cannot be, so the frame's arrival
    stands in for it."""
    if domain in (rs.timestamp_domain.global_time, rs.timestamp_domain.system_time):
        return stamp_ms / 1000.0 - (time.time() - time.monotonic())
    return time.monotonic()


class Source(Protocol):
    """Where the device comes from: ``connect()`` returns an ``rs.device`` or raises DriverError.

    The camera sets ``on_lost``; a source that hears of a removal calls it with the reason.
    ``wall_clock``: its frames carry the host's wall clock (a USB camera's global time), which
    the camera moves onto the monotonic clock; other sources' stamps are kept as they are.
    """

    label: str
    real_time: bool
    finite: bool
    wall_clock: bool
    on_lost: Callable[[str], None] | None

    def connect(self) -> rs.device: ...


def librealsense_version() -> tuple[int, int, int]:
    """Installed pyrealsense2 version as (major, minor, patch)."""
    parts = version("pyrealsense2").split(".")
    return int(parts[0]), int(parts[1]), int(parts[2])


def _describe(device: rs.device) -> str:
    info = rs.camera_info
    name = device.get_info(info.name) if device.supports(info.name) else "?"
    serial = device.get_info(info.serial_number) if device.supports(info.serial_number) else "?"
    return f"{serial} ({' '.join(name.split())})"


class LiveSource:
    """A USB RealSense chosen by serial (if the profile gives one) or else by model."""

    real_time = True
    finite = False
    wall_clock = True

    def __init__(self, config: CameraConfig) -> None:
        self.config = config
        self.label = f"{config.model} {config.serial or '(any serial)'}"
        self.on_lost: Callable[[str], None] | None = None
        self._context: rs.context | None = None

    def connect(self) -> rs.device:
        if self.config.model == L515.name and librealsense_version() >= (2, 55, 0):
            found = ".".join(map(str, librealsense_version()))
            raise DriverError(f"the L515 needs librealsense <= 2.54, this is {found}")
        self._context = rs.context()
        devices = list(self._context.query_devices())
        serial = self.config.serial
        for device in devices:
            if serial:
                if device.get_info(rs.camera_info.serial_number) != serial:
                    continue
            elif self.config.model not in device.get_info(rs.camera_info.name):
                continue
            label = _describe(device)
            self._context.set_devices_changed_callback(
                lambda event, device=device, label=label: self._changed(event, device, label)
            )
            return device
        found = ", ".join(_describe(d) for d in devices) or "none"
        wanted = f"serial {serial}" if serial else f"model {self.config.model}"
        raise DriverError(f"no RealSense with {wanted}; found: {found}")

    def _changed(self, event: rs.event_information, device: rs.device, label: str) -> None:
        if event.was_removed(device) and self.on_lost is not None:
            self.on_lost(f"{label} unplugged")


class PlaybackSource:
    """A recording (.bag) played back at the recorded rate or as fast as frames are consumed."""

    finite = True
    wall_clock = False

    def __init__(self, path: str | Path, real_time: bool = True) -> None:
        self.path = Path(path)
        self.real_time = real_time
        self.label = f"recording {self.path}"
        self.on_lost: Callable[[str], None] | None = None
        self._context: rs.context | None = None

    def connect(self) -> rs.device:
        if not self.path.is_file():
            raise DriverError(f"{self.path}: recording not found")
        self._context = rs.context()
        try:
            device = self._context.load_device(str(self.path))
        except RuntimeError as e:
            raise DriverError(f"{self.path}: not a readable RealSense recording: {e}") from None
        playback = device.as_playback()
        playback.set_real_time(self.real_time)
        return device


class _Handoff:
    """Frames from the device callback to ``frames()``: newest wins, or block for playback."""

    def __init__(self, size: int, block: bool) -> None:
        self.queue: queue.Queue = queue.Queue(maxsize=size)
        self.block = block
        self.dropped = 0
        self.closed = threading.Event()

    def put(self, item: Any) -> None:
        while not self.closed.is_set():
            try:
                self.queue.put(item, timeout=0.05 if self.block else 0)
                return
            except queue.Full:
                if not self.block:
                    try:
                        self.queue.get_nowait()
                        self.dropped += 1
                    except queue.Empty:
                        pass

    def get(self, timeout: float) -> Any:
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def clear(self) -> None:
        while True:
            try:
                self.queue.get_nowait()
            except queue.Empty:
                return


def _set_option(sensor: rs.sensor, option: rs.option, value: float, where: str) -> None:
    if sensor.supports(option) and not sensor.is_option_read_only(option):
        try:
            sensor.set_option(option, value)
        except RuntimeError as e:
            raise DriverError(f"{where}: cannot set {option} to {value}: {e}") from None
    else:
        log.debug("%s: %s not settable on this device; left as is", where, option)


class RealSenseCamera:
    """A depth camera (the Camera protocol) on any RealSense source, configured by the profile.

    ``record_to`` writes every frame the device delivers to a .bag through librealsense's
    recorder (a reconnect continues in ``<stem>-1.bag``, ``<stem>-2.bag``...). ``timeout`` (s)
    without a frame means the device is lost; None waits forever (a stepped twin).
    """

    def __init__(
        self,
        config: CameraConfig,
        source: Source,
        *,
        extrinsics: np.ndarray | None = None,
        record_to: str | Path | None = None,
        timeout: float | None = 1.0,
        backoff: tuple[float, float] = (0.1, 2.0),
        queue_size: int = 2,
    ) -> None:
        self.config = config
        self.source = source
        self.model = model(config.model)
        self.extrinsics = mount_extrinsics(config) if extrinsics is None else extrinsics
        self.record_to = Path(record_to) if record_to is not None else None
        self.timeout = timeout
        self.backoff = backoff
        self.where = f"camera {config.name!r} ({source.label})"
        self.status = CameraHealth()
        self._check_config()
        source.on_lost = self.device_lost
        self._handoff = _Handoff(queue_size, block=not source.real_time)
        self._closed = threading.Event()
        self._device: rs.device | None = None
        self._recorder: rs.recorder | None = None
        self._sensor: rs.sensor | None = None
        self._filters: list[rs.filter] = []
        self._depth_scale = 0.0
        self._threshold: tuple[int, int] | None = None
        self._intrinsics: dict[tuple, Intrinsics] = {}
        self._segments = 0

    @classmethod
    def from_profile(cls, camera_config: CameraConfig, **options: Any) -> RealSenseCamera:
        """The camera of a profile: a live device, or ``playback=PATH`` (``real_time=`` flag)."""
        playback = options.pop("playback", None)
        real_time = options.pop("real_time", True)
        source = PlaybackSource(playback, real_time) if playback else LiveSource(camera_config)
        return cls(camera_config, source, **options)

    def _check_config(self) -> None:
        c, m = self.config, self.model
        units = c.depth_units
        if units is not None and m.depth_unit_fixed and abs(units - m.depth_unit) > 1e-9:
            raise DriverError(
                f"{self.where}: depth_units: the {m.name} has a fixed depth unit of "
                f"{m.depth_unit} m, the profile asks for {units}"
            )
        if c.visual_preset is not None and c.visual_preset not in m.presets:
            raise DriverError(
                f"{self.where}: visual_preset: {c.visual_preset!r} is not a {m.name} preset "
                f"(one of {', '.join(m.presets)})"
            )
        unknown = [f for f in c.filters if f not in FILTERS]
        if unknown:
            raise DriverError(
                f"{self.where}: filters: unknown {unknown} (known: {', '.join(FILTERS)})"
            )

    # --- lifecycle --------------------------------------------------------------------

    def open(self) -> None:
        """Connect and start streaming; a missing device raises DriverError at once."""
        self._closed.clear()
        self._handoff.closed.clear()
        self._start(self.source.connect())

    def _start(self, device: rs.device) -> None:
        if self.record_to is not None:
            path = self.record_to
            if self._segments:
                path = path.with_name(f"{path.stem}-{self._segments}{path.suffix}")
            self._segments += 1
            self._recorder = rs.recorder(str(path), device)
            device = self._recorder
        sensor = self._depth_sensor(device)
        recorded = device.is_playback()
        if not recorded:
            self._configure(sensor)
        profile = self._stream_profile(sensor, recorded)
        self._depth_scale = float(str(np.float32(sensor.get_option(rs.option.depth_units))))
        self._filters = self._make_filters()
        self._threshold = None
        if "threshold" in self.config.filters:
            lo = int(np.ceil(self.config.min_range / self._depth_scale))
            self._threshold = (lo, int(np.floor(self.config.max_range / self._depth_scale)))
        self._handoff.clear()
        sensor.open(profile)
        sensor.start(self._on_frame)
        self._device, self._sensor = device, sensor
        self.status.connected = True
        log.info("%s: streaming %s from %s", self.where, profile, _describe(device))

    def _depth_sensor(self, device: rs.device) -> rs.sensor:
        for sensor in device.query_sensors():
            streams = sensor.get_stream_profiles()
            if any(p.stream_type() == rs.stream.depth for p in streams):
                return sensor
        raise DriverError(f"{self.where}: {_describe(device)} has no depth sensor")

    def _configure(self, sensor: rs.sensor) -> None:
        c = self.config
        _set_option(sensor, rs.option.global_time_enabled, 1.0, self.where)
        if c.depth_units is not None:
            _set_option(sensor, rs.option.depth_units, c.depth_units, self.where)
        if c.visual_preset is not None:
            enum = rs.l500_visual_preset if self.model is L515 else rs.rs400_visual_preset
            preset = float(int(getattr(enum, c.visual_preset)))
            _set_option(sensor, rs.option.visual_preset, preset, self.where)
        if self.model is not L515:
            _set_option(sensor, rs.option.emitter_enabled, float(c.emitter), self.where)

    def _stream_profile(self, sensor: rs.sensor, recorded: bool) -> rs.video_stream_profile:
        """The profile's depth stream; a recording plays the depth stream it holds."""
        c = self.config
        found = []
        for p in sensor.get_stream_profiles():
            if p.stream_type() != rs.stream.depth or p.format() != rs.format.z16:
                continue
            v = p.as_video_stream_profile()
            if recorded or (v.width(), v.height(), v.fps()) == (c.width, c.height, c.fps):
                return v
            found.append(f"{v.width()}x{v.height()}@{v.fps()}")
        raise DriverError(
            f"{self.where}: no depth stream {c.width}x{c.height}@{c.fps} z16 "
            f"(device has {', '.join(sorted(set(found))) or 'none'})"
        )

    def _make_filters(self) -> list[rs.filter]:
        """librealsense filters in the profile's order; spatial/temporal run on disparity.

        ``threshold`` is not among them: it runs last, on the raw depth units, because
        software-device frames from pyrealsense2 2.54 carry no depth unit for it to read.
        """
        c = self.config
        filters: list[rs.filter] = []
        smoothing = [f for f in c.filters if f in ("spatial", "temporal")]
        for name in c.filters:
            if name in ("spatial", "temporal") and name == smoothing[0]:
                filters.append(rs.disparity_transform(True))
            if name == "decimation":
                filters.append(rs.decimation_filter())
            elif name == "spatial":
                filters.append(rs.spatial_filter())
            elif name == "temporal":
                filters.append(rs.temporal_filter())
            elif name == "hole_filling":
                filters.append(rs.hole_filling_filter())
            if name in ("spatial", "temporal") and name == smoothing[-1]:
                filters.append(rs.disparity_transform(False))
        return filters

    def _on_frame(self, frame: rs.frame) -> None:
        frame.keep()
        self._handoff.put(frame)

    def device_lost(self, reason: str) -> None:
        """Tell ``frames()`` the device is gone (a removal notice); it reconnects with back-off."""
        self.status.last_error = reason
        self._handoff.put(_LOST)

    def _stop(self) -> None:
        sensor, self._sensor = self._sensor, None
        self.status.connected = False
        if sensor is not None:
            for call in (sensor.stop, sensor.close):
                try:
                    call()
                except RuntimeError as e:
                    log.debug("%s: %s: %s", self.where, call.__name__, e)
        self._device = None
        self._recorder = None

    def close(self) -> None:
        """Stop streaming and release the device (and finish the recording file)."""
        self._closed.set()
        self._handoff.closed.set()
        self._handoff.clear()
        self._stop()

    # --- frames -----------------------------------------------------------------------

    def frames(self) -> Iterator[DepthFrame]:
        """Depth frames until ``close()`` (or the end of a recording), reconnecting if lost."""
        waited = 0.0
        step = 0.05
        while not self._closed.is_set():
            item = self._handoff.get(step)
            if item is None:
                waited += step
                if self.source.finite and self._playback_done():
                    return
                if self.timeout is not None and waited >= self.timeout and self._sensor:
                    self.device_lost(f"no frame for {waited:.2f} s")
                continue
            waited = 0.0
            if item is _LOST:
                log.warning(
                    "%s: device lost (%s); reconnecting", self.where, self.status.last_error
                )
                self._stop()
                self._reconnect()
                continue
            self.status.frames += 1
            self.status.dropped = self._handoff.dropped
            yield self._convert(item)

    def _playback_done(self) -> bool:
        device = self._device
        if device is None or not device.is_playback():
            return False
        done = device.as_playback().current_status() == rs.playback_status.stopped
        return done and self._handoff.queue.empty()

    def _reconnect(self) -> None:
        delay, longest = self.backoff
        while not self._closed.is_set():
            try:
                self._start(self.source.connect())
                self.status.reconnects += 1
                log.info("%s: reconnected", self.where)
                return
            except (DriverError, RuntimeError) as e:
                self.status.last_error = str(e)
                log.debug("%s: reconnect failed: %s; next try in %.2f s", self.where, e, delay)
            self._closed.wait(delay)
            delay = min(2 * delay, longest)

    def _stamp(self, depth: rs.depth_frame) -> float:
        """The frame's stamp on the control role's clock (see ``Source.wall_clock``)."""
        if self.source.wall_clock:
            return host_time(depth.get_timestamp(), depth.get_frame_timestamp_domain())
        return depth.get_timestamp() / 1000.0

    def _convert(self, frame: rs.frame) -> DepthFrame:
        for f in self._filters:
            frame = f.process(frame)
        depth = frame.as_depth_frame()
        profile = depth.get_profile().as_video_stream_profile()
        key = (profile.unique_id(), profile.width(), profile.height())
        intrinsics = self._intrinsics.get(key)
        if intrinsics is None:
            i = profile.get_intrinsics()
            intrinsics = Intrinsics(i.width, i.height, i.fx, i.fy, i.ppx, i.ppy)
            self._intrinsics[key] = intrinsics
        image = np.array(depth.get_data(), dtype=np.uint16, copy=True)
        if self._threshold is not None:
            lo, hi = self._threshold
            image[(image < lo) | (image > hi)] = 0
        return DepthFrame(
            depth=image.reshape(intrinsics.height, intrinsics.width),
            depth_scale=self._depth_scale,
            intrinsics=intrinsics,
            extrinsics=self.extrinsics,
            timestamp=self._stamp(depth),
            number=depth.get_frame_number(),
        )

    def health(self) -> CameraHealth:
        """Link state, frame and drop counts, reconnects, last error."""
        self.status.dropped = self._handoff.dropped
        return self.status
