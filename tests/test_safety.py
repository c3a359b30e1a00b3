"""The safety state machine: allowed transitions, e-stop latching, sessions, heartbeats, health."""

from __future__ import annotations

import msgspec
import pytest

from climbd.daemon.contract import profile as profiles
from climbd.daemon.contract.messages import EstopPolicy, JointHealth, JointState, Mode
from climbd.daemon.runtime.safety import DERATE_SCALE, MAX_ESTOP_SOURCES, Safety


@pytest.fixture()
def safety(robots) -> Safety:
    return Safety(profiles.load(robots / "widowx.toml"))


def test_normal_sequence_and_refused_jumps(safety: Safety) -> None:
    assert safety.mode == Mode.OFF
    assert not safety.request(Mode.ACTIVE, 0.0), "OFF → ACTIVE skips the stand"
    assert safety.request(Mode.STAND, 0.1)
    assert safety.request(Mode.ACTIVE, 0.2)
    assert not safety.request(Mode.OFF, 0.3), "torque off while walking would drop the robot"
    assert safety.request(Mode.HOLD, 0.4)
    assert safety.request(Mode.ACTIVE, 0.5)
    assert [t.mode for t in safety.history] == [Mode.STAND, Mode.ACTIVE, Mode.HOLD, Mode.ACTIVE]


def test_estop_latches_until_explicit_reset(safety: Safety) -> None:
    safety.request(Mode.STAND, 0.0)
    safety.torque_on = True
    safety.estop(1.0, "laptop", "operator")
    assert safety.mode == Mode.ESTOP and "laptop" in safety.reason
    for mode in Mode:
        assert not safety.request(mode, 1.1) or mode == Mode.ESTOP
    assert safety.mode == Mode.ESTOP
    assert safety.reset(2.0)
    assert safety.mode == Mode.HOLD, "a powered robot resets into HOLD, never straight into motion"


def test_fault_needs_reset_and_estop_wins(safety: Safety) -> None:
    safety.request(Mode.STAND, 0.0)
    safety.fault(1.0, "port gone")
    assert safety.mode == Mode.FAULT
    safety.estop(1.5, "pendant")
    assert safety.mode == Mode.ESTOP
    safety.fault(1.6, "another fault")
    assert safety.mode == Mode.ESTOP, "a fault never clears a latched e-stop"
    assert safety.reset(2.0) and safety.mode == Mode.OFF


def test_one_session_at_a_time_and_override(safety: Safety) -> None:
    assert safety.claim("s1", "alice", 0.0) == (True, "claimed")
    ok, why = safety.claim("s2", "bob", 0.1)
    assert not ok and "alice" in why
    assert safety.accepts("s1") and not safety.accepts("s2")
    refused = safety.refused
    assert not safety.request(Mode.STAND, 0.2, session="s2")
    assert safety.refused == refused + 1
    assert safety.request(Mode.STAND, 0.2, session="s1")
    assert safety.claim("s3", "carol", 0.3, override=True)[0]
    assert safety.accepts("s3") and not safety.accepts("s1")


def test_lost_heartbeat_holds_within_the_window(safety: Safety) -> None:
    window = safety.profile.safety.heartbeat_window
    safety.claim("s1", "alice", 0.0)
    safety.request(Mode.STAND, 0.0, session="s1")
    safety.request(Mode.ACTIVE, 0.0, session="s1")
    for k in range(1, 10):
        assert safety.heartbeat("s1", 0.1 * k, seq=k, stamp=0.1 * k)
        safety.check_heartbeat(0.1 * k + 0.05)
    assert safety.mode == Mode.ACTIVE
    last = 0.9
    safety.check_heartbeat(last + window * 0.99)
    assert safety.mode == Mode.ACTIVE
    safety.check_heartbeat(last + window + 0.01)
    assert safety.mode == Mode.HOLD and "heartbeat" in safety.reason
    assert safety.history[-1].at - last <= window + 0.011
    assert safety.session is None, "an expired session must be claimed again"


def test_foreign_heartbeats_keep_nothing_alive_and_are_not_refused_commands(
    safety: Safety,
) -> None:
    window = safety.profile.safety.heartbeat_window
    safety.claim("s1", "alice", 0.0)
    safety.request(Mode.STAND, 0.0, session="s1")
    safety.request(Mode.ACTIVE, 0.0, session="s1")
    for k in range(1, 10):
        assert not safety.heartbeat("intruder", 0.1 * k, seq=k, stamp=0.1 * k)
    safety.check_heartbeat(window + 0.01)
    assert safety.mode == Mode.HOLD, "another session's heartbeats must not keep s1 alive"
    assert not safety.heartbeat("s1", window + 0.02, seq=1, stamp=1.0), "a late beat, expired"
    assert safety.refused == 0, "heartbeats overtake claims and releases; they command nothing"


def test_expired_session_can_be_claimed_by_another(safety: Safety) -> None:
    safety.claim("s1", "alice", 0.0)
    assert safety.claim("s2", "bob", 1.0)[0]


def active(safety: Safety, session: str = "s1", client: str = "alice") -> None:
    """Claim ``session`` for ``client`` and walk: OFF → STAND → ACTIVE."""
    assert safety.claim(session, client, 0.0)[0]
    assert safety.request(Mode.STAND, 0.0, session=session)
    assert safety.request(Mode.ACTIVE, 0.1, session=session)


def test_release_means_hold(safety: Safety) -> None:
    active(safety)
    assert safety.release("s1", 0.2)
    assert safety.mode == Mode.HOLD and safety.reason == "session of alice released"
    assert safety.session is None, "nobody holds the session after its release"


def test_release_with_handoff_leaves_the_robot_to_autonomy_and_says_so(
    safety: Safety, caplog: pytest.LogCaptureFixture
) -> None:
    active(safety)
    with caplog.at_level("WARNING", logger="climbd.safety"):
        assert safety.release("s1", 0.2, handoff=True)
    assert safety.mode == Mode.ACTIVE and safety.session is None
    assert safety.reason == "handed to autonomy by alice", "status shows who handed it over"
    assert safety.mode_state(0.3).reason == "handed to autonomy by alice"
    assert "session of alice released: robot handed to autonomy in ACTIVE" in caplog.text


def test_release_of_a_session_not_held_changes_nothing(safety: Safety) -> None:
    active(safety)
    assert not safety.release("intruder", 0.2)
    assert not safety.release("intruder", 0.2, handoff=True)
    assert safety.mode == Mode.ACTIVE and safety.session is not None
    assert safety.session.client == "alice"


def test_mode_state_names_who_engaged_and_who_reset_the_latch(safety: Safety) -> None:
    safety.request(Mode.STAND, 0.0)
    assert safety.mode_state(0.0).estop_by == []
    safety.estop(1.0, "laptop", "operator")
    safety.estop(1.1, "pendant")
    safety.estop(1.2, "laptop", "again")
    state = safety.mode_state(1.3)
    assert state.mode == Mode.ESTOP and state.estop_by == ["laptop", "pendant"]
    assert "laptop" in state.reason and state.reset_by == ""
    safety.claim("s1", "alice", 2.0)
    assert safety.reset(2.0, "s1")
    state = safety.mode_state(2.1)
    assert state.mode == Mode.OFF and state.estop_by == [] and state.reset_by == "s1"
    safety.fault(3.0, "port gone")
    assert safety.mode_state(3.1).reset_by == "", "a new latch is not yet reset"


def test_estop_sources_are_bounded(safety: Safety) -> None:
    for k in range(3 * MAX_ESTOP_SOURCES):
        safety.estop(0.1 * k, f"peer{k}")
    kept = safety.mode_state(5.0).estop_by
    assert kept == [f"peer{k}" for k in range(2 * MAX_ESTOP_SOURCES, 3 * MAX_ESTOP_SOURCES)]


def joints(n: int = 18, **over) -> list[JointHealth]:
    out = [JointHealth(name=f"j{i}", temperature=40.0, voltage=12.0) for i in range(n)]
    for i, fields in over.items():
        k = int(i[1:])
        out[k] = msgspec.structs.replace(out[k], **fields)
    return out


def test_health_policy(safety: Safety) -> None:
    safety.request(Mode.STAND, 0.0)
    safety.request(Mode.ACTIVE, 0.0)
    safety.judge(joints(j3={"temperature": 68.0}), 1.0)
    assert safety.mode == Mode.ACTIVE and safety.speed_scale == DERATE_SCALE
    safety.judge(joints(), 1.1)
    assert safety.speed_scale == 1.0
    safety.judge(joints(j5={"lost": True}), 1.2)
    assert safety.mode == Mode.HOLD and "j5" in safety.reason
    safety.request(Mode.ACTIVE, 1.3)
    safety.judge(joints(j2={"voltage": 7.0}), 1.4)
    assert safety.mode == Mode.HOLD and "voltage" in safety.reason
    safety.judge(joints(j7={"temperature": 80.0}), 1.5)
    assert safety.mode == Mode.FAULT and "overheat" in safety.reason


@pytest.mark.parametrize(
    "name,policy",
    [
        ("widowx", EstopPolicy.TORQUE_OFF),
        ("hubrobo", EstopPolicy.HOLD_GRIP),
        ("qingzhui", EstopPolicy.HOLD),
    ],
)
def test_policy_comes_from_the_profile(robots, name: str, policy: EstopPolicy) -> None:
    assert Safety(profiles.load(robots / f"{name}.toml")).policy == policy


def test_a_joint_state_older_than_the_bound_is_a_fault_naming_the_joint(safety: Safety) -> None:
    bound = safety.profile.bus.max_state_age
    names = [j.name for j in safety.profile.joints[:3]]
    stale = JointState(names=names, position=[0.0] * 3, age=[0.01, bound * 1.5, float("nan")])
    safety.check_state_age(stale, 0.0)
    assert safety.mode == Mode.OFF, "a robot not on its legs has nothing to fault"
    safety.request(Mode.STAND, 0.1)
    fresh = JointState(names=names, position=[0.0] * 3, age=[0.01, bound, float("nan")])
    safety.check_state_age(fresh, 0.2)
    assert safety.mode == Mode.STAND, "at the bound, and a lost joint (NaN), are no fault"
    safety.check_state_age(stale, 0.3)
    assert safety.mode == Mode.FAULT
    assert names[1] in safety.reason and names[0] not in safety.reason
