"""Conformance of the Dynamixel emulator, checked from the outside.

Raw packets are the byte strings printed in the ROBOTIS e-Manual (Protocol 1.0 / 2.0
instruction and status examples) or built here by hand with the SDK's own CRC; everything
else goes through plain dynamixel_sdk calls, so the emulator cannot share a bug with our driver.
"""

from __future__ import annotations

import math
import termios
import time

import dynamixel_sdk as sdk
import pytest
import serial

from climbd.drivers.sim.dynamixel import DynamixelEmulator, EmulatedServo, ServoChain
from climbd.drivers.sim.dynamixel.tables import AX_18A, XL430_W250
from climbd.drivers.sim.dynamixel.wire import Framer, crc16, packet1, packet2, stuff, unstuff

P2_CRC = sdk.Protocol2PacketHandler().updateCRC
PATIENCE_MS = 200.0


class PatientPort(sdk.PortHandler):
    """The SDK's own port, waiting ``PATIENCE_MS`` longer for a reply than its 34 ms default:
    the SDK busy-polls, so on a loaded machine the in-process emulator's thread can wait that
    long for the GIL, and a reply the wire model delivers in time would count as a timeout."""

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 - SDK override
        super().setPacketTimeout(packet_length)
        self.packet_timeout += PATIENCE_MS

    def setPacketTimeoutMillis(self, msec: float) -> None:  # noqa: N802 - SDK override
        super().setPacketTimeoutMillis(msec + PATIENCE_MS)


def _chain(spec, ids=(1, 2, 3), baud=1_000_000) -> ServoChain:
    chain = ServoChain([EmulatedServo(spec, i) for i in ids], spec.protocol, baud)
    for s in chain.servos.values():
        s.set("return_delay_time", 0)
    return chain


@pytest.fixture
def ax():
    chain = _chain(AX_18A)
    with DynamixelEmulator(chain) as emu:
        port = PatientPort(emu.port)
        assert port.openPort()
        yield chain, emu, port, sdk.PacketHandler(1.0)
        port.closePort()


@pytest.fixture
def xl():
    chain = _chain(XL430_W250)
    with DynamixelEmulator(chain) as emu:
        port = PatientPort(emu.port)
        assert port.openPort()
        yield chain, emu, port, sdk.PacketHandler(2.0)
        port.closePort()


def _settle(port, ph) -> None:
    """A round trip after a broadcast: the emulator handles packets in order, so it is done."""
    assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS


def _raw(port: str, packet: bytes, expect: int, timeout: float = 0.5) -> bytes:
    """Write raw bytes to the emulator's port and read ``expect`` bytes back."""
    with serial.Serial(port, 1_000_000, timeout=timeout) as s:
        s.write(packet)
        return s.read(expect)


# --- wire format against the published examples --------------------------------------------


def test_protocol2_crc_matches_emanual_examples():
    ping = bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
    status = bytes.fromhex("ff ff fd 00 01 07 00 55 00 06 04 26 65 5d")
    read = bytes.fromhex("ff ff fd 00 01 07 00 02 84 00 04 00 1d 15")
    write = bytes.fromhex("ff ff fd 00 01 09 00 03 74 00 00 02 00 00 ca 89")
    assert packet2(1, 0x01) == ping
    assert packet2(1, 0x55, bytes([0, 0x06, 0x04, 0x26])) == status
    assert packet2(1, 0x02, bytes([0x84, 0, 4, 0])) == read
    assert packet2(1, 0x03, bytes([0x74, 0, 0, 2, 0, 0])) == write
    for p in (ping, status, read, write):
        assert crc16(p[:-2]) == P2_CRC(0, list(p), len(p) - 2) == p[-2] | p[-1] << 8


def test_protocol1_checksum_matches_emanual_examples():
    assert packet1(1, 0x01) == bytes.fromhex("ff ff 01 02 01 fb")
    assert packet1(1, 0x02, bytes([0x2B, 1])) == bytes.fromhex("ff ff 01 04 02 2b 01 cc")
    assert packet1(1, 0x00, bytes([0x20])) == bytes.fromhex("ff ff 01 03 00 20 db")


def test_byte_stuffing_rule():
    assert stuff(bytes.fromhex("03 ff ff fd 00")) == bytes.fromhex("03 ff ff fd fd 00")
    assert stuff(bytes.fromhex("ff ff fd ff ff fd")) == bytes.fromhex("ff ff fd fd ff ff fd fd")
    for raw in (b"\xff\xff\xfd", b"\xff\xff\xfd\xfd", b"\x01\xff\xff\xfd\xff\xff\xfd\x02"):
        assert unstuff(stuff(raw)) == raw


def test_framer_resynchronises_after_garbage():
    framer = Framer(2)
    ping = bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
    got = framer.feed(b"\x00\xff\x12" + ping[:5])
    assert got == []
    got = framer.feed(ping[5:] + ping)
    assert [(p.ident, p.inst, p.valid) for p in got] == [(1, 1, True), (1, 1, True)]


# --- raw packets on the pty ------------------------------------------------------------------


def test_raw_emanual_ping_gets_documented_status(xl):
    chain, emu, _, _ = xl
    chain.servo(1).set("firmware_version", 0x26)
    chain.servo(1).set("model_number", 0x0406)
    reply = _raw(emu.port, bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e"), 14)
    assert reply == bytes.fromhex("ff ff fd 00 01 07 00 55 00 06 04 26 65 5d")


def test_raw_stuffed_write_is_unstuffed_by_the_servo(xl):
    """Goal velocity 0x00FDFFFF puts FF FF FD in the parameters: the host must stuff a FD."""
    chain, emu, _, _ = xl
    body = [0xFF, 0xFF, 0xFD, 0x00, 0x01, 0x0A, 0x00, 0x03, 104, 0x00, 0xFF, 0xFF, 0xFD, 0xFD, 0x00]
    crc = P2_CRC(0, body, len(body))
    reply = _raw(emu.port, bytes([*body, crc & 0xFF, crc >> 8]), 11)
    assert reply[7:9] == bytes([0x55, 0x00])
    assert chain.servo(1).get("goal_velocity") == 0x00FDFFFF


def test_raw_protocol1_read_temperature_and_bad_checksum(ax):
    chain, emu, _, _ = ax
    chain.servo(1).set_present(temperature=32.0)
    reply = _raw(emu.port, bytes.fromhex("ff ff 01 04 02 2b 01 cc"), 7)
    assert reply == bytes.fromhex("ff ff 01 03 00 20 db")
    reply = _raw(emu.port, bytes.fromhex("ff ff 01 04 02 2b 01 cd"), 6)
    assert reply[4] & 0x10  # checksum error bit


# --- Protocol 1.0 through dynamixel_sdk --------------------------------------------------------


def test_p1_ping_read_write_sizes(ax):
    chain, _, port, ph = ax
    assert ph.ping(port, 2)[:2] == (18, sdk.COMM_SUCCESS)
    assert ph.write1ByteTxRx(port, 2, 25, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 2, 25) == (1, sdk.COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 2, 30, 700) == (sdk.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 2, 30) == (700, sdk.COMM_SUCCESS, 0)
    assert chain.servo(2).goal_angle == pytest.approx((700 - 512) * math.radians(300) / 1023)
    # AX has no 4-byte items; a 4-byte read spans goal position and moving speed.
    assert ph.write2ByteTxRx(port, 2, 32, 100)[0] == sdk.COMM_SUCCESS
    assert ph.read4ByteTxRx(port, 2, 30)[0] == 700 | 100 << 16


def test_p1_sync_write_reg_write_action(ax):
    chain, _, port, ph = ax
    group = sdk.GroupSyncWrite(port, ph, 30, 2)
    for i, goal in ((1, 100), (2, 200), (3, 300)):
        group.addParam(i, [goal & 0xFF, goal >> 8])
    assert group.txPacket() == sdk.COMM_SUCCESS
    _settle(port, ph)
    assert [chain.servo(i).get("goal_position") for i in (1, 2, 3)] == [100, 200, 300]
    assert ph.regWriteTxRx(port, 1, 30, 2, [0x00, 0x02]) == (sdk.COMM_SUCCESS, 0)
    assert chain.servo(1).get("goal_position") == 100
    assert ph.read1ByteTxRx(port, 1, 44)[0] == 1  # registered
    assert ph.action(port, sdk.BROADCAST_ID) == sdk.COMM_SUCCESS
    assert ph.read2ByteTxRx(port, 1, 30)[0] == 512


def test_p1_error_bits_angle_overheat_instruction(ax):
    chain, _, port, ph = ax
    assert ph.write2ByteTxRx(port, 3, 8, 800) == (sdk.COMM_SUCCESS, 0)  # CCW limit
    assert ph.write2ByteTxRx(port, 3, 30, 900) == (sdk.COMM_SUCCESS, 2)  # angle limit error
    assert chain.servo(3).get("goal_position") == 512
    assert ph.write1ByteTxRx(port, 3, 24, 1) == (sdk.COMM_SUCCESS, 0)
    assert chain.servo(3).torque_enabled
    chain.servo(3).set_present(temperature=80.0)
    _, result, error = ph.read1ByteTxRx(port, 3, 43)
    assert (result, error) == (sdk.COMM_SUCCESS, 4)
    assert not chain.servo(3).torque_enabled  # shutdown mask 36 includes overheat
    result, error = ph.factoryReset(port, 3)  # not emulated: instruction error
    assert result == sdk.COMM_SUCCESS and error == 0x40 | 4


def test_p1_status_return_level_and_return_delay(ax):
    chain, _, port, ph = ax
    assert ph.write1ByteTxRx(port, 1, 16, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 1, 25, 1)[0] == sdk.COMM_RX_TIMEOUT  # writes unanswered
    assert ph.read1ByteTxRx(port, 1, 25) == (1, sdk.COMM_SUCCESS, 0)  # but it was applied
    ph.write1ByteTxOnly(port, 1, 16, 0)
    deadline = time.monotonic() + 2.0
    while chain.servo(1).get("status_return_level") != 0:  # applied (the emulator's thread)
        assert time.monotonic() < deadline, "status return level 0 never applied"
        time.sleep(0.001)
    assert ph.read1ByteTxRx(port, 1, 25)[1] == sdk.COMM_RX_TIMEOUT


def test_wire_time_is_never_shorter_than_the_bus_allows():
    """At 57600 baud with the factory 500 µs return delay, 20 reads cannot beat the wire."""
    chain = ServoChain([EmulatedServo(AX_18A, 1)], 1, 57_600)
    with DynamixelEmulator(chain) as emu:
        port = PatientPort(emu.port)
        port.openPort()
        port.setBaudRate(57_600)
        ph = sdk.PacketHandler(1.0)
        t0 = time.perf_counter()
        for _ in range(20):
            assert ph.read2ByteTxRx(port, 1, 36)[1] == sdk.COMM_SUCCESS
        elapsed = time.perf_counter() - t0
        port.closePort()
    per_read = (8 + 8) * 10 / 57_600 + 500e-6
    assert elapsed >= 20 * per_read


# --- Protocol 2.0 through dynamixel_sdk ------------------------------------------------------


def test_p2_ping_read_write_sizes(xl):
    chain, _, port, ph = xl
    assert ph.ping(port, 3) == (1060, sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 3, 65, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 3, 65) == (1, sdk.COMM_SUCCESS, 0)
    assert ph.write2ByteTxRx(port, 3, 84, 900) == (sdk.COMM_SUCCESS, 0)
    assert ph.read2ByteTxRx(port, 3, 84) == (900, sdk.COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 3, 116, 3000) == (sdk.COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, 3, 116) == (3000, sdk.COMM_SUCCESS, 0)
    assert chain.servo(3).goal_angle == pytest.approx((3000 - 2048) * 2 * math.pi / 4096)
    found, result = ph.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS and sorted(found) == [1, 2, 3]


def test_p2_sync_and_fast_sync_read(xl):
    chain, _, port, ph = xl
    for i in (1, 2, 3):
        chain.servo(i).set_present(angle=0.1 * i, temperature=30 + i)
    for fast in (False, True):
        group = sdk.GroupSyncRead(port, ph, 132, 15)
        for i in (1, 2, 3):
            group.addParam(i)
        result = group.fastSyncRead() if fast else group.txRxPacket()
        assert result == sdk.COMM_SUCCESS
        for i in (1, 2, 3):
            assert group.getData(i, 132, 4) == chain.servo(i).tick(0.1 * i)
            assert group.getData(i, 146, 1) == 30 + i


def test_p2_bulk_read_fast_bulk_read_bulk_write(xl):
    chain, _, port, ph = xl
    writer = sdk.GroupBulkWrite(port, ph)
    writer.addParam(1, 116, 4, [0x00, 0x09, 0, 0])
    writer.addParam(2, 65, 1, [1])
    assert writer.txPacket() == sdk.COMM_SUCCESS
    _settle(port, ph)
    assert chain.servo(1).get("goal_position") == 0x900 and chain.servo(2).get("led") == 1
    for fast in (False, True):
        reader = sdk.GroupBulkRead(port, ph)
        reader.addParam(1, 116, 4)
        reader.addParam(2, 65, 1)
        assert (reader.fastBulkRead() if fast else reader.txRxPacket()) == sdk.COMM_SUCCESS
        assert reader.getData(1, 116, 4) == 0x900 and reader.getData(2, 65, 1) == 1


def test_p2_sync_write_reg_write_action_and_access_errors(xl):
    chain, _, port, ph = xl
    group = sdk.GroupSyncWrite(port, ph, 116, 4)
    for i in (1, 2, 3):
        group.addParam(i, list((1000 * i).to_bytes(4, "little")))
    assert group.txPacket() == sdk.COMM_SUCCESS
    _settle(port, ph)
    assert [chain.servo(i).get("goal_position") for i in (1, 2, 3)] == [1000, 2000, 3000]
    assert ph.regWriteTxRx(port, 2, 116, 4, [0, 8, 0, 0]) == (sdk.COMM_SUCCESS, 0)
    assert ph.action(port, 2) == sdk.COMM_SUCCESS
    _settle(port, ph)
    assert ph.read4ByteTxRx(port, 2, 116)[0] == 2048
    assert ph.write1ByteTxRx(port, 2, 132, 0)[1] == 7  # read-only: access error
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (sdk.COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, 9, 0)[1] == 7  # EEPROM with torque on: access error
    assert ph.write4ByteTxRx(port, 2, 116, 5000)[1] == 6  # beyond max position: data limit


def test_p2_hardware_alert_and_reboot(xl):
    chain, _, port, ph = xl
    chain.servo(2).set_present(temperature=90.0)
    _, result, error = ph.read1ByteTxRx(port, 2, 146)
    assert result == sdk.COMM_SUCCESS and error & 0x80
    assert ph.read1ByteTxRx(port, 2, 70)[0] == 0x04  # overheating bit
    chain.servo(2).set_present(temperature=40.0)
    assert ph.read1ByteTxRx(port, 2, 70)[0] == 0x04  # latched until reboot
    assert ph.reboot(port, 2) == (sdk.COMM_SUCCESS, 0x80)
    _booted(port, ph, 2)
    assert ph.read1ByteTxRx(port, 2, 70) == (0, sdk.COMM_SUCCESS, 0)


def _booted(port, ph, ident: int) -> float:
    """Seconds until a rebooted servo answers a ping again."""
    start = time.monotonic()
    while ph.ping(port, ident)[1] != sdk.COMM_SUCCESS:
        assert time.monotonic() - start < 2.0, f"id {ident} never came back from its reboot"
    return time.monotonic() - start


def test_p2_reboot_is_silent_for_the_boot_time_then_ram_is_at_power_on_values(xl):
    chain, _, port, ph = xl
    servo = chain.servo(3)
    assert ph.write1ByteTxRx(port, 3, 65, 1) == (sdk.COMM_SUCCESS, 0)  # LED on (RAM)
    assert ph.write1ByteTxRx(port, 3, 64, 1) == (sdk.COMM_SUCCESS, 0)  # torque on
    assert ph.write4ByteTxRx(port, 3, 116, 3000) == (sdk.COMM_SUCCESS, 0)  # goal
    servo.set_present(angle=0.5)
    servo.inject_overload()
    assert not servo.torque_enabled  # shutdown on overload (default Shutdown 52 has bit 5)
    servo.inject_overload(False)
    assert ph.read1ByteTxRx(port, 3, 70)[0] == 0x20  # latched
    assert ph.reboot(port, 3) == (sdk.COMM_SUCCESS, 0x80)  # answered before it restarts
    took = _booted(port, ph, 3)
    assert took >= chain.boot_time - 0.01
    assert ph.read1ByteTxRx(port, 3, 70)[:2] == (0, sdk.COMM_SUCCESS)
    assert ph.read1ByteTxRx(port, 3, 64)[0] == 0  # torque off
    assert ph.read1ByteTxRx(port, 3, 65)[0] == 0  # LED back to its default
    assert ph.read4ByteTxRx(port, 3, 116)[0] == 2048 + round(0.5 / (2 * math.pi / 4096))
    assert ph.ping(port, 1)[1] == sdk.COMM_SUCCESS, "the other servos answered throughout"
    servo.inject_overload()  # a stall still present latches again after the reboot
    assert ph.reboot(port, 3)[0] == sdk.COMM_SUCCESS
    _booted(port, ph, 3)
    assert ph.read1ByteTxRx(port, 3, 70)[0] == 0x20


# --- faults ----------------------------------------------------------------------------------


def test_silenced_servo_times_out_and_comes_back(xl):
    chain, _, port, ph = xl
    chain.silence(2)
    assert ph.ping(port, 2)[1] == sdk.COMM_RX_TIMEOUT
    group = sdk.GroupSyncRead(port, ph, 132, 4)
    for i in (1, 2, 3):
        group.addParam(i)
    assert group.fastSyncRead() != sdk.COMM_SUCCESS
    chain.silence(2, on=False)
    assert ph.ping(port, 2)[1] == sdk.COMM_SUCCESS
    assert group.fastSyncRead() == sdk.COMM_SUCCESS


def test_corrupt_replies_are_rejected_by_the_sdk(ax, xl):
    for chain, _, port, ph in (ax, xl):
        chain.corrupt(1, count=2)
        assert ph.read1ByteTxRx(port, 1, 3)[1] == sdk.COMM_RX_CORRUPT
        assert ph.read1ByteTxRx(port, 1, 3)[1] == sdk.COMM_RX_CORRUPT
        assert ph.read1ByteTxRx(port, 1, 3)[1] == sdk.COMM_SUCCESS


def test_vanished_port_raises_in_the_sdk(xl):
    """An unplugged adapter surfaces as termios.error (EIO) or SerialException, not a timeout."""
    _, emu, port, ph = xl
    emu.vanish()
    with pytest.raises((serial.SerialException, termios.error, OSError)):
        for _ in range(3):
            ph.ping(port, 1)


# --- motor model -------------------------------------------------------------------------------


@pytest.mark.parametrize("spec", [AX_18A, XL430_W250])
def test_motor_model_first_order_and_speed_limited(spec):
    servo = EmulatedServo(spec, 1)
    servo.set("torque_enable", 1)
    servo.set("goal_position", servo.tick(1.0))
    speed_field = "moving_speed" if spec.protocol == 1 else "profile_velocity"
    servo.set(speed_field, 20)  # 20 × unit rpm
    vmax = 20 * spec.velocity_unit
    servo.step(0.1)
    assert servo.state.angle == pytest.approx(min(vmax * 0.1, 1.0), rel=1e-6)
    servo.set(speed_field, 0)
    for _ in range(100):
        servo.step(0.01)
    assert abs(servo.state.angle - servo.goal_angle) < 1e-3
    servo.set("torque_enable", 0)
    before = servo.state.angle
    servo.set("goal_position", servo.tick(-1.0))
    servo.step(0.5)
    assert servo.state.angle == before
