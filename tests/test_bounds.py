"""Bounds everywhere: oversized wire fields are refused at decode, profile values have physical
bounds named by field path, and ``climbd profile check`` reports every file and goes on."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import msgspec
import pytest

from climbd.daemon.contract import messages as m
from climbd.daemon.contract import profile as profiles

ROBOTS = Path(__file__).resolve().parent.parent / "robots"


def raw(message: type[m.Message], **fields: object) -> bytes:
    """A payload of ``message``'s topic with ``fields`` as given: what a hostile peer sends,
    past any clipping our own constructors do."""
    return msgspec.msgpack.encode({"schema": m.SCHEMA_VERSION, **fields})


def test_a_4mb_estop_reason_is_refused_at_decode() -> None:
    with pytest.raises(msgspec.ValidationError, match=r"\$\.reason"):
        m.decode(raw(m.EStop, reason="x" * 4_000_000), m.EStop)


def test_our_own_long_estop_reason_is_clipped_not_refused() -> None:
    sent = m.EStop(source="op", reason="x" * 4_000_000)
    assert len(m.decode(m.encode(sent), m.EStop).reason) == m.MAX_NAME


@pytest.mark.parametrize(
    "message,fields,path",
    [
        (m.JointState, {"position": [0.0] * (m.MAX_ENTRIES + 1)}, "$.position"),
        (m.FootTargets, {"stance": [True] * (m.MAX_LEGS + 1)}, "$.stance"),
        (m.GraspablePoints, {"points": [[0.0, 0.0, 0.0]] * (m.MAX_FEATURES + 1)}, "$.points"),
        (m.ModeState, {"estop_by": ["a"] * (m.MAX_ENTRIES + 1)}, "$.estop_by"),
        (m.BodyState, {"position": [0.0] * (m.MAX_VECTOR + 1)}, "$.position"),
        (m.DepthImage, {"depth": b"\0" * (m.MAX_DEPTH_BYTES + 1)}, "$.depth"),
        (m.TerrainMap, {"layers": {str(i): b"" for i in range(m.MAX_ENTRIES + 1)}}, "$.layers"),
        (m.SessionClaim, {"client": "c" * (m.MAX_NAME + 1)}, "$.client"),
        (m.Heartbeat, {"session": "s" * (m.MAX_NAME + 1)}, "$.session"),
        (m.Health, {"features": {str(i): 0.0 for i in range(m.MAX_ENTRIES + 1)}}, "$.features"),
        (m.Health, {"messages": ["x" * (m.MAX_TEXT + 1)]}, "$.messages[0]"),
    ],
    ids=lambda v: v.__name__ if isinstance(v, type) else "",
)
def test_an_oversized_field_is_refused_at_decode(message, fields, path) -> None:
    with pytest.raises(msgspec.ValidationError) as err:
        m.decode(raw(message, **fields), message)
    assert path in str(err.value)


def test_a_long_mode_reason_is_clipped_to_what_a_peer_decodes() -> None:
    state = m.ModeState(reason="control tick failed: " + "x" * 10_000)
    assert len(m.decode(m.encode(state), m.ModeState).reason) == m.MAX_TEXT


def test_a_health_with_long_error_texts_is_clipped_to_what_a_peer_decodes() -> None:
    """A plugin failing with a 10,000-character exception, and 100 messages: the robot's Health
    still decodes at the operator's tool, each text cut to MAX_TEXT, the newest messages kept."""
    failed = "failed: ValueError: " + "x" * 10_000
    health = m.Health(plugins={"graspable": failed}, messages=[f"m{i}" for i in range(100)])
    got = m.decode(m.encode(health), m.Health)
    assert len(got.plugins["graspable"]) == m.MAX_TEXT and got.plugins["graspable"][-1] == "…"
    assert got.messages == [f"m{i}" for i in range(100 - m.MAX_ENTRIES, 100)]


def widowx_with(tmp_path: Path, old: str, new: str) -> Path:
    text = (ROBOTS / "widowx.toml").read_text()
    assert old in text, old
    path = tmp_path / "bad.toml"
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize(
    "old,new,fragment",
    [
        ("rate_hz = 100.0", "rate_hz = 1e9", "$.rate_hz: expected 1..5000 Hz"),
        (
            "heartbeat_window = 0.3",
            "heartbeat_window = 1e9",
            "$.safety.heartbeat_window: expected 0.05..5 s",
        ),
        (
            "lower = -1.8000, upper = 1.8000",
            "lower = 1.8000, upper = -1.8000",
            "limits: expected finite lower < upper",
        ),
        ("lower = -1.8000", "lower = -inf", "limits: expected finite lower < upper"),
        ("fps = 30", "fps = 100000", "$.cameras[0].fps: expected 1..300 frames/s"),
        ("width = 640", "width = 100000", "$.cameras[0].width: expected 16..1280 pixels"),
        ("foot_radius = 0.01004", "foot_radius = 0.0", "$.foot_radius: expected 0.001..0.1 m"),
    ],
)
def test_a_profile_value_out_of_bounds_is_refused_with_its_path(tmp_path, old, new, fragment):
    path = widowx_with(tmp_path, old, new)
    with pytest.raises(profiles.ProfileError) as err:
        profiles.load(path)
    assert str(path) in str(err.value) and fragment in str(err.value), str(err.value)


def test_an_unreadable_profile_is_a_profile_error_naming_the_file(tmp_path, monkeypatch) -> None:
    path = tmp_path / "locked.toml"
    path.write_text("")

    def denied(self: Path, *args: object, **kwargs: object) -> str:
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(Path, "read_text", denied)
    with pytest.raises(profiles.ProfileError, match=f"{path}: cannot read: Permission denied"):
        profiles.load(path)


def test_profile_check_reports_every_file_and_goes_on(tmp_path: Path) -> None:
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b'name = "\xff\xfe"\n')
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    files = [ROBOTS / "widowx.toml", binary, folder, ROBOTS / "hubrobo.toml"]
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "profile", "check", *map(str, files)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert f"{files[0]}: ok" in res.stdout and f"{files[3]}: ok" in res.stdout
    assert f"{binary}: not UTF-8 text" in res.stderr
    assert f"{folder}: a directory" in res.stderr
    assert "2 of 4 profiles failed" in res.stderr


def test_stock_profiles_pass_the_bounds() -> None:
    stock = sorted(ROBOTS.glob("*.toml"))
    res = subprocess.run(
        [sys.executable, "-m", "climbd.daemon.cli", "profile", "check", *map(str, stock)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.count(": ok") == len(stock)
