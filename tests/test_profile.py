"""Robot profiles: stock ones validate; malformed ones name the field path, expected and found."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

import pytest

from climbd.daemon.algorithms.world import WorldConfig
from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import EstopPolicy
from climbd.daemon.runtime.loader import check_driver
from climbd.daemon.runtime.perception_role import PerceptionRole
from climbd.drivers.dynamixel.config import DynamixelConfig
from climbd.drivers.torque.config import TorqueConfig, can_frame_bits

ROBOTS = Path(__file__).resolve().parent.parent / "robots"


@pytest.mark.parametrize("name", ["widowx", "hubrobo", "qingzhui"])
def test_stock_profile_validates(name: str) -> None:
    p = profiles.load(ROBOTS / f"{name}.toml")
    assert p.name == name
    assert all(len(leg.joints) == 3 for leg in p.legs)


def test_stock_profiles_match_the_robots() -> None:
    widowx = check(ROBOTS / "widowx.toml")
    bus = DynamixelConfig.from_profile(widowx)
    assert len(widowx.legs) == 6 and sorted(j.id for j in widowx.joints) == list(range(1, 19))
    assert widowx.rate_hz == 100 and bus.protocol == 1 and bus.model == "AX-18A"
    assert widowx.legs[0].links == pytest.approx([0.052, 0.066, 0.133])
    hubrobo = check(ROBOTS / "hubrobo.toml")
    assert len(hubrobo.legs) == 4 and DynamixelConfig.from_profile(hubrobo).protocol == 2
    assert hubrobo.safety.estop_policy == EstopPolicy.HOLD_GRIP
    qingzhui = check(ROBOTS / "qingzhui.toml")
    assert qingzhui.rate_hz == 1000 and qingzhui.bus.kind == "torque"
    assert TorqueConfig.from_profile(qingzhui).actuator.torque == 48.0
    assert {leg.kind for leg in qingzhui.legs} == {"abduction_thigh_shank"}


def check(path: Path) -> profiles.Profile:
    """Load a profile and let its bus driver check its keys of ``[bus]``, as
    ``climbd profile check`` and ``climbd run`` do."""
    profile = profiles.load(path)
    check_driver(profile)
    return profile


def write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def base_text() -> str:
    return (ROBOTS / "widowx.toml").read_text()


def replace_once(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


def first_leg_gripper(text: str, servo: str) -> str:
    """``text`` with a ``gripper_servo = { servo }`` on its first leg."""
    return re.sub(r"(links = \[.*\]\n)", rf"\1gripper_servo = {{ {servo} }}\n", text, count=1)


MALFORMED = [
    # (description, transform of the WidowX profile text, expected fragments of the error)
    ("unknown top-level key", lambda t: "colour = 'red'\n" + t, ["colour", "$"]),
    (
        "rate as a string",
        lambda t: replace_once(t, "rate_hz = 100.0", 'rate_hz = "fast"'),
        ["$.rate_hz", "Expected `float`, got `str`"],
    ),
    (
        "negative rate",
        lambda t: replace_once(t, "rate_hz = 100.0", "rate_hz = -5.0"),
        ["$.rate_hz", "expected 1..5000 Hz", "-5.0"],
    ),
    (
        "zero stand tolerance",
        lambda t: replace_once(t, "[safety]\n", "[safety]\nstand_tolerance = 0.0\n"),
        ["$.safety.stand_tolerance", "expected 0.001..0.5 rad", "0.0"],
    ),
    (
        "negative servo stiffness",
        lambda t: replace_once(t, "stiffness = 11.0", "stiffness = -2.0"),
        ["$.bus.stiffness", "expected a finite value >= 0", "-2.0"],
    ),
    (
        "limit min > max",
        lambda t: re.sub(r"lower = -?[0-9.]+", "lower = 9.5", t, count=1),
        ["$.legs[0].joints[0].limits", "lower < upper", "lower=9.5"],
    ),
    (
        "duplicate servo id",
        lambda t: replace_once(t, "id = 3\n", "id = 1\n"),
        ["$.legs[0].joints[1].id", "duplicate id 1"],
    ),
    (
        "gripper servo on a joint's id",
        lambda t: first_leg_gripper(t, "id = 3, open = 0.0, closed = 1.0"),
        ["$.legs[0].gripper_servo.id", "duplicate id 3", "rf_femur"],
    ),
    (
        "gripper servo that does not move",
        lambda t: first_leg_gripper(t, "id = 40, open = 0.5, closed = 0.5"),
        ["$.legs[0].gripper_servo", "open != closed", "open=0.5"],
    ),
    (
        "leg with two joints",
        lambda t: re.sub(
            r'\[\[legs\.joints\]\]\nname = "rf_tibia"\n(?:(?!\[\[).*\n)*', "", t, count=1
        ),
        ["$.legs[0].joints", "expected 3 joints, found 2"],
    ),
    (
        "unknown e-stop policy",
        lambda t: replace_once(t, 'estop_policy = "torque_off"', 'estop_policy = "pray"'),
        ["$.safety.estop_policy", "pray"],
    ),
    (
        "tilt out of range",
        lambda t: replace_once(t, "tilt_deg = 30.0", "tilt_deg = 120.0"),
        ["$.cameras[0].mount.tilt_deg", "0..90", "120"],
    ),
    ("protocol 3", lambda t: replace_once(t, "protocol = 1", "protocol = 3"), ["$.bus.protocol"]),
    (
        "baud as a string",
        lambda t: replace_once(t, "baud = 1000000", 'baud = "fast"'),
        ["$.bus.baud", "Expected `int`, got `str`"],
    ),
    (
        "unknown bus key",
        lambda t: replace_once(t, "protocol = 1\n", "protocol = 1\nparity = 2\n"),
        ["$.bus", "unknown field `parity`"],
    ),
    (
        "bus key of another driver",
        lambda t: replace_once(t, "protocol = 1\n", 'protocol = 1\ncan_channel = "can1"\n'),
        ["$.bus", "unknown field `can_channel`"],
    ),
    (
        "health rate as a string",
        lambda t: replace_once(t, "[bus]\n", '[bus]\nhealth_rate_hz = "often"\n'),
        ["$.bus.health_rate_hz", "Expected `float`, got `str`"],
    ),
    (
        "missing stand",
        lambda t: re.sub(r"\[stand\]\n(?:(?!\[).*\n)*", "", t, count=1),
        ["$: Object missing required field `stand`"],
    ),
    (
        "unknown joint key",
        lambda t: replace_once(t, 'name = "rf_coxa"\n', 'name = "rf_coxa"\ngear = 2\n'),
        ["$.legs[0].joints[0]", "gear"],
    ),
    (
        "zero velocity limit",
        lambda t: replace_once(t, "velocity = 5.0", "velocity = 0.0"),
        ["$.legs[0].joints[0].limits.velocity", "> 0", "0.0"],
    ),
    (
        "direction 2",
        lambda t: replace_once(t, 'name = "rf_coxa"\n', 'name = "rf_coxa"\ndirection = 2\n'),
        ["$.legs[0].joints[0].direction"],
    ),
    ("bad TOML", lambda t: t + "\n[[legs\n", ["not valid TOML"]),
]


@pytest.mark.parametrize("desc,transform,fragments", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_profile_names_field(tmp_path: Path, desc, transform, fragments) -> None:
    path = write(tmp_path, transform(base_text()))
    with pytest.raises(profiles.ProfileError) as err:
        check(path)
    message = str(err.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, f"{desc}: {fragment!r} not in {message!r}"


def test_include_overrides_only_what_differs(tmp_path: Path) -> None:
    (tmp_path / "widowx.toml").write_text(base_text())
    path = write(
        tmp_path,
        'include = "widowx.toml"\nname = "attic-bot"\n[bus]\nport = "/dev/ttyACM3"\n'
        "[safety]\nheartbeat_window = 0.2\n",
        "mine.toml",
    )
    p = check(path)
    bus = DynamixelConfig.from_profile(p)
    assert p.name == "attic-bot"
    assert bus.port == "/dev/ttyACM3" and bus.model == "AX-18A" and bus.baud == 1_000_000
    assert p.safety.heartbeat_window == 0.2 and p.safety.estop_policy == EstopPolicy.TORQUE_OFF
    assert len(p.joints) == 18


@pytest.mark.parametrize(
    "bus,rate,fragments",
    [
        ('can_channels = ["can0"]', 1000.0, ["18 motors on can0", "4.50 ms", "6 channels"]),
        ('can_channels = ["can0", "can1", "can2"]', 1000.0, ["6 motors on can0", "1.50 ms"]),
        ('can_channels = ["can0", "can1", "can2"]', 500.0, []),
        ("baud = 125000", 1000.0, ["3 motors on can0", "6.00 ms", "lower rate_hz or raise baud"]),
    ],
)
def test_torque_profile_fits_its_can_traffic_in_a_tick(tmp_path: Path, bus, rate, fragments):
    """Every CAN channel carries its motors' MIT command (8 bytes) and reply (6 bytes) within
    one period, 250 bit times a motor at worst-case stuffing: Qingzhui's 18 motors at 1 kHz
    need six 1 Mbit/s buses."""
    (tmp_path / "qingzhui.toml").write_text((ROBOTS / "qingzhui.toml").read_text())
    path = write(tmp_path, f'include = "qingzhui.toml"\nrate_hz = {rate}\n[bus]\n{bus}\n')
    if not fragments:
        assert check(path).rate_hz == rate
        return
    profiles.load(path)  # the contract's schema holds; the torque driver finds the overload
    with pytest.raises(profiles.ProfileError) as err:
        check(path)
    message = str(err.value)
    assert str(path) in message and "$.bus.can_channels" in message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


def test_can_frame_bits_at_worst_case_stuffing() -> None:
    """A classic frame with 8 data bytes holds the bus for at most 135 bits, with 6 for 115."""
    assert can_frame_bits(8) == 135
    assert can_frame_bits(6) == 115
    assert can_frame_bits(0) == 55


def test_bus_options_round_trip_through_builtins() -> None:
    """The driver's keys of ``[bus]`` sit in ``bus.options``; a decoded profile turned back
    into builtins decodes to the same profile."""
    p = profiles.load(ROBOTS / "qingzhui.toml")
    assert "kp" in p.bus.options and "kind" not in p.bus.options
    again = profiles.from_dict(profiles.msgspec.to_builtins(p), p.source)
    assert again == p


def test_include_missing_and_cycle(tmp_path: Path) -> None:
    path = write(tmp_path, 'include = "nowhere.toml"\n', "a.toml")
    with pytest.raises(profiles.ProfileError, match="include: profile file not found"):
        profiles.load(path)
    write(tmp_path, 'include = "c.toml"\n', "b.toml")
    write(tmp_path, 'include = "b.toml"\n', "c.toml")
    with pytest.raises(profiles.ProfileError, match="include cycle"):
        profiles.load(tmp_path / "b.toml")


def test_profile_check_command(tmp_path: Path) -> None:
    bad = write(tmp_path, replace_once(base_text(), "id = 3\n", "id = 1\n"))
    ok = subprocess.run(
        [
            sys.executable,
            "-m",
            "climbd.daemon.cli",
            "profile",
            "check",
            str(ROBOTS / "widowx.toml"),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0 and "ok" in ok.stdout
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "profile", "check", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1
    assert "$.legs[0].joints[1].id" in res.stderr and "Traceback" not in res.stderr


def assert_check_refuses(tmp_path: Path, old: str, new: str, fragment: str) -> None:
    """``climbd profile check`` on the stock profile with ``old`` replaced by ``new`` exits 1
    naming the file and ``fragment``."""
    check_refuses(write(tmp_path, replace_once(base_text(), old, new)), fragment)


def check_refuses(bad: Path, fragment: str) -> None:
    """``climbd profile check`` on ``bad`` exits 1 naming the file and ``fragment``."""
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "profile", "check", str(bad)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1 and str(bad) in res.stderr and fragment in res.stderr, res.stderr


@pytest.mark.parametrize(
    "old,new,fragment",
    [
        ("protocol = 1", "protocol = 3", "$.bus.protocol: Invalid enum value 3"),
        ("protocol = 1", "protocol = 1\nkd = 2.0", "$.bus: Object contains unknown field `kd`"),
        ('kind = "dynamixel"', 'kind = "dynamo"', "$.bus.kind: climbd.drivers"),
    ],
)
def test_profile_check_validates_the_bus_driver(tmp_path: Path, old, new, fragment) -> None:
    assert_check_refuses(tmp_path, old, new, fragment)


@pytest.mark.parametrize(
    "old,new,fragment",
    [
        (
            'name = "joists" }',
            'name = "jiosts" }',
            "$.plugins.perception[0].name: climbd.perception",
        ),
        (
            'name = "joists" }',
            'name = "joists", config = { colour = 1 } }',
            "$.plugins.perception[0].config: Object contains unknown field `colour`",
        ),
    ],
)
def test_profile_check_validates_plugins(tmp_path: Path, old: str, new: str, fragment: str) -> None:
    assert_check_refuses(tmp_path, old, new, fragment)


@pytest.mark.parametrize(
    "world,fragment",
    [
        ("[world.elevation]\nlength = -1.0\n", "$.world.elevation: elevation config: length"),
        ("[world]\ndecimation = 0\n", "$.world: world config: decimation must be >= 1"),
        ("[world.joists]\ngates = 0.1\n", "$.world.joists: Object contains unknown field `gates`"),
    ],
)
def test_profile_check_validates_the_world_model(tmp_path: Path, world, fragment) -> None:
    check_refuses(write(tmp_path, base_text() + world), fragment)


def test_world_section_configures_the_perception_roles_world_model(tmp_path: Path) -> None:
    """The profile's ``[world]`` reaches the world model the perception role runs; what it does
    not set keeps the defaults."""
    (tmp_path / "widowx.toml").write_text(base_text())
    path = write(
        tmp_path,
        'include = "widowx.toml"\n[world]\npublish_period = 0.25\n'
        "[world.elevation]\nlength = 3.0\n[world.joists]\nmemory = 8.0\n",
        "far.toml",
    )
    role = PerceptionRole(check(path), argparse.Namespace())
    config = role.world.plugin.config
    assert config.publish_period == 0.25 and config.elevation.length == 3.0
    assert config.joists.memory == 8.0 and config.joists.gate == WorldConfig().joists.gate
    assert config.elevation.resolution == WorldConfig().elevation.resolution
    assert config.elevation.z_min == WorldConfig().elevation.z_min == -1.0  # not the grid's own
    assert role.world.plugin.joists.tracker.config.memory == 8.0
