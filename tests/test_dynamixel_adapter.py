"""The emulated USB serial adapter (FTDI latency timer, USB frames) and the driver's warning
about a slow latency timer.

Timing asserts are lower bounds the model guarantees (a reply is held for the timer after its
last byte), plus the one upper bound it also guarantees: at a 1 ms timer a read takes under
16 ms. The adapter's own schedule is checked on its clockless model, exactly.
"""

from __future__ import annotations

import logging
import os
import select
import subprocess
import sys
import time
from pathlib import Path

import dynamixel_sdk as sdk
import pytest

from climbd.daemon.contract.profile import load
from climbd.drivers.dynamixel import bus as dxl_bus
from climbd.drivers.dynamixel.bus import DynamixelBus, LatencyPort, check_latency_timer
from climbd.drivers.sim.dynamixel import DynamixelEmulator, EmulatedServo, ServoChain
from climbd.drivers.sim.dynamixel.adapter import FTDI_RX_PAYLOAD, USB_FRAME, UsbSerialAdapter
from climbd.drivers.sim.dynamixel.tables import AX_18A, XL430_W250
from climbd.drivers.sim.dynamixel.wire import crc16, packet2

ROOT = Path(__file__).resolve().parent.parent
BYTE = 10e-6  # one byte at 1 Mbps
AX_PRESENT_POSITION = 36
P2_READ = 0x02


def _chain(spec, ids=(1, 2)) -> ServoChain:
    chain = ServoChain([EmulatedServo(spec, i) for i in ids], spec.protocol)
    for s in chain.servos.values():
        s.set("return_delay_time", 0)
    return chain


def _timed_reads(port: str, latency_ms: float, count: int) -> list[float]:
    """Seconds each of ``count`` single READs of present position takes through LatencyPort."""
    lp = LatencyPort(port, latency_ms, margin_ms=20.0)
    assert lp.openPort() and lp.setBaudRate(1_000_000)
    ph = sdk.PacketHandler(1.0)
    took = []
    try:
        for _ in range(count):
            start = time.monotonic()
            _, result, _ = ph.readTxRx(lp, 1, AX_PRESENT_POSITION, 6)
            took.append(time.monotonic() - start)
            assert result == sdk.COMM_SUCCESS, ph.getTxRxResult(result)
    finally:
        lp.closePort()
    return took


# --- the adapter model, on its own clock -----------------------------------------------------


def test_host_bytes_leave_on_the_next_usb_frame():
    adapter = UsbSerialAdapter(0.016)
    assert adapter.to_bus(10.0002) == pytest.approx(10.001)
    assert adapter.to_bus(10.001) == pytest.approx(10.001)
    assert USB_FRAME == 1e-3


def test_short_reply_is_held_until_the_timer_runs_out_after_its_last_byte():
    adapter = UsbSerialAdapter(0.016)
    reply = bytes(range(8))
    adapter.from_bus(reply, end=1.0, byte_time=BYTE)
    assert adapter.due() == pytest.approx(1.016)
    assert adapter.release(1.0159) == b""
    assert adapter.release(1.016) == reply
    assert adapter.due() is None


def test_a_byte_before_the_timer_expires_restarts_it():
    adapter = UsbSerialAdapter(0.016)
    adapter.from_bus(b"\x01\x02", end=1.0, byte_time=BYTE)
    adapter.from_bus(b"\x03\x04", end=1.010, byte_time=BYTE)  # 10 ms later: timer still runs
    assert adapter.due() == pytest.approx(1.026)
    assert adapter.release(1.0255) == b""
    assert adapter.release(1.026) == b"\x01\x02\x03\x04"


def test_a_full_buffer_goes_at_once_the_rest_waits_for_the_timer():
    adapter = UsbSerialAdapter(0.016)
    reply = bytes(i % 256 for i in range(FTDI_RX_PAYLOAD + 40))
    end = 1.0
    adapter.from_bus(reply, end=end, byte_time=BYTE)
    full = end - 40 * BYTE  # the 62nd byte comes in 40 byte times before the last
    assert adapter.due() == pytest.approx(full)
    assert adapter.release(full) == reply[:FTDI_RX_PAYLOAD]
    assert adapter.due() == pytest.approx(end + 0.016)
    assert adapter.release(end + 0.016) == reply[FTDI_RX_PAYLOAD:]


# --- through the emulator's pty --------------------------------------------------------------


@pytest.mark.parametrize("latency_ms", [1, 16])
def test_a_read_round_trip_costs_the_latency_timer(latency_ms: int):
    with DynamixelEmulator(_chain(AX_18A), latency_ms=latency_ms) as emu:
        took = _timed_reads(emu.port, latency_ms, 5)
    assert min(took) >= latency_ms * 1e-3
    if latency_ms == 1:
        assert min(took) < 0.016


def test_a_reply_longer_than_the_adapter_buffer_comes_in_two_usb_packets():
    """A 111-byte reply: its first 62 bytes reach the host as soon as the buffer is full, the
    remaining 49 a whole timer after the reply's last byte."""
    latency = 0.1  # long, so a late test thread cannot merge the two packets
    chain = _chain(XL430_W250, ids=(1,))
    length = 100
    with DynamixelEmulator(chain, latency_ms=latency * 1e3) as emu:
        fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, packet2(1, P2_READ, bytes([0, 0, length, 0])))  # from address 0
            chunks = []
            while sum(len(c) for _, c in chunks) < length + 11:
                assert select.select([fd], [], [], 1.0)[0], "reply incomplete"
                chunks.append((time.monotonic(), os.read(fd, 4096)))
        finally:
            os.close(fd)
    assert [len(c) for _, c in chunks] == [FTDI_RX_PAYLOAD, length + 11 - FTDI_RX_PAYLOAD]
    reply = chunks[0][1] + chunks[1][1]
    assert crc16(reply[:-2]) == int.from_bytes(reply[-2:], "little")
    assert reply[4] == 1 and reply[7] == 0x55 and reply[8] == 0  # servo 1's status, no error
    assert reply[9:-2] == chain.servo(1).read_bytes(0, length)
    assert chunks[1][0] - chunks[0][0] >= 0.9 * latency  # read times: the host may be late


def test_command_line_latency_option_holds_replies():
    proc = subprocess.Popen(
        [sys.executable, "-m", "climbd.drivers.sim.dynamixel", "--profile", "robots/widowx.toml"]
        + ["--latency-ms", "16", "--return-delay-us", "0"],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = proc.stdout.readline().strip()
        ident = load(ROOT / "robots/widowx.toml").joints[0].id
        lp = LatencyPort(port, 16, margin_ms=20.0)
        assert lp.openPort() and lp.setBaudRate(1_000_000)
        start = time.monotonic()
        _, result, _ = sdk.PacketHandler(1.0).readTxRx(lp, ident, AX_PRESENT_POSITION, 6)
        took = time.monotonic() - start
        lp.closePort()
    finally:
        proc.terminate()
        proc.wait(timeout=5)
    assert result == sdk.COMM_SUCCESS
    assert took >= 0.016


# --- the driver's warning -------------------------------------------------------------------


def _adapter_tree(tmp_path: Path, timer: int | None) -> tuple[str, Path]:
    """/dev/dynamixel → ttyUSB0 and the adapter's sysfs directory (its latency_timer file
    holding ``timer``, or none); returns the port and the sysfs root."""
    dev = tmp_path / "dev"
    dev.mkdir()
    (dev / "ttyUSB0").touch()
    (dev / "dynamixel").symlink_to(dev / "ttyUSB0")
    sysfs = tmp_path / "sys"
    (sysfs / "ttyUSB0").mkdir(parents=True)
    if timer is not None:
        (sysfs / "ttyUSB0" / "latency_timer").write_text(f"{timer}\n")
    return str(dev / "dynamixel"), sysfs


def test_latency_timer_above_1_ms_warns_with_cost_and_fix(tmp_path, caplog):
    port, sysfs = _adapter_tree(tmp_path, 16)
    with caplog.at_level(logging.WARNING, logger=dxl_bus.__name__):
        assert check_latency_timer(port, 18, lambda: 17.2, sysfs=sysfs) == 16
    [record] = caplog.records
    text = record.getMessage()
    assert port in text and "ttyUSB0" in text
    assert "latency timer is 16 ms" in text and "17.2 ms measured" in text
    assert "18 read(s) a cycle ≥ 310 ms" in text
    assert f"echo 1 | sudo tee {sysfs / 'ttyUSB0' / 'latency_timer'}" in text


@pytest.mark.parametrize("timer", [1, None])
def test_fast_or_absent_latency_timer_is_silent(tmp_path, caplog, timer):
    port, sysfs = _adapter_tree(tmp_path, timer)

    def measure() -> float:
        raise AssertionError("nothing to warn about: no read to time")

    with caplog.at_level(logging.DEBUG, logger=dxl_bus.__name__):
        assert check_latency_timer(port, 18, measure, sysfs=sysfs) == timer
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_open_warns_with_the_round_trip_measured_on_the_port(tmp_path, caplog, monkeypatch):
    """The kernel refuses the driver's write (no rights): the timer stays at 16 ms."""
    profile = load(ROOT / "robots/widowx.toml")
    with DynamixelEmulator(ServoChain.from_profile(profile), latency_ms=16) as emu:
        tty = Path(os.path.realpath(emu.port)).name
        (tmp_path / tty).mkdir()
        (tmp_path / tty / "latency_timer").write_text("16\n")
        monkeypatch.setattr(dxl_bus, "USB_SERIAL_SYSFS", tmp_path)
        monkeypatch.setattr(dxl_bus, "set_latency_timer", lambda port, ms: None)
        bus = DynamixelBus.from_profile(profile, port=emu.port, timeout_margin_ms=40.0)
        with caplog.at_level(logging.WARNING, logger=dxl_bus.__name__):
            bus.open()
        bus.close()
    [text] = [r.getMessage() for r in caplog.records if "latency timer" in r.getMessage()]
    measured = float(text.split("a read takes ")[1].split(" ms measured")[0])
    assert measured >= 16.0
    assert f"{len(profile.joints)} read(s) a cycle" in text
