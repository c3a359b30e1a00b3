"""Access control: what each identity may do to a robot over Zenoh, and read-only telemetry.

The role's own Zenoh session admits only authenticated peers (mutual TLS with certificates from
``climbd certs``, or Zenoh user/password), and its access-control list gives each identity the
rights the profile names (``network.auth.rights``, or ``commanders``): which keys it may put is
decided by Zenoh before climbd sees the sample, so resets and override claims ride on keys of
their own (``cmd/reset``, ``cmd/override``). Peers without credentials may reach a separate
read-only ``TelemetryGate`` session: it serves only what the role mirrors to it, and refuses
(counting those it can see) every put from its peers.
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, get_args

from climbd.daemon.contract.messages import Message, encode
from climbd.daemon.contract.profile import AuthConfig, Profile, Right
from climbd.daemon.runtime.certificates import first_run, is_loopback, subject_names

if TYPE_CHECKING:  # the CLI parser imports this module: zenoh loads only when used
    import zenoh

log = logging.getLogger("climbd.access")

OBSERVE_MESSAGES = (
    "declare_subscriber",
    "declare_queryable",
    "query",
    "reply",
    "liveliness_token",
    "liveliness_query",
    "declare_liveliness_subscriber",
)
SECURE_PROTOCOLS = ("tls", "quic")

RIGHTS: tuple[Right, ...] = get_args(Right)

COMMANDER_RIGHTS: frozenset[Right] = frozenset(RIGHTS) - {"features"}
"""What a name in ``network.auth.commanders`` may do: everything on ``cmd/**``, as before."""

ROLES = ("control", "perception")
"""climbd's roles: their identities (CN or user name, ``{role}`` expanded) publish state."""

ROLE_KEYS = ("climbd/*/state/**", "climbd/*/features/**", "climbd/*/sim/**")
"""What the roles themselves publish to each other."""

COMMAND_TOPICS: dict[Right, tuple[str, ...]] = {
    "teleop": ("cmd/motion", "cmd/mode", "cmd/session", "cmd/heartbeat"),
    "estop": ("cmd/estop",),
    "reset": ("cmd/reset",),
    "override": ("cmd/override",),
}
"""The command keys (under ``climbd/<robot>/``) each right may put."""

REFUSAL_LOG_PERIOD = 5.0
"""Seconds between log lines about refused puts on the telemetry gate (the rest only counted)."""


class AccessError(ValueError):
    """An auth setup that cannot work; the message names the profile field or the file."""


def _resolve(profile: Profile, value: str, role: str) -> Path:
    """A ``network.auth`` path: ``{role}`` expanded, ``~`` the user's home, else relative to
    the profile file."""
    base = Path(profile.source).parent if profile.source else Path.cwd()
    return base / Path(value.format(role=role)).expanduser()


def _path(profile: Profile, value: str, role: str) -> str:
    path = _resolve(profile, value, role)
    if not path.is_file():
        hint = ""
        if profile.network.auth is not None and profile.network.auth.create_certificates:
            hint = (
                f"; the control role creates it on its first run: copy ca.pem, {role}.pem and "
                f"{role}.key from {path.parent} on the control computer"
            )
        raise AccessError(f"{profile.source}: network.auth: file not found: {path}{hint}")
    return str(path)


def certificate_dir(profile: Profile) -> Path:
    """Where ``create_certificates`` writes: the one directory of ``ca.pem``, ``{role}.pem``
    and ``{role}.key``, as ``climbd certs`` names them (AccessError naming the field if not)."""
    auth = profile.network.auth
    assert auth is not None
    out = _resolve(profile, auth.tls_root_ca, "control").parent
    expected = {
        "tls_root_ca": (auth.tls_root_ca, "ca.pem"),
        "tls_certificate": (auth.tls_certificate, "{role}.pem"),
        "tls_private_key": (auth.tls_private_key, "{role}.key"),
    }
    for field, (value, name) in expected.items():
        if _resolve(profile, value, "{role}") != out / name:
            raise AccessError(
                f"{profile.source}: network.auth.{field}: climbd certs writes {out / name} "
                "(in the directory of tls_root_ca); name that file"
            )
    return out


def identities(auth: AuthConfig) -> list[str]:
    """Every identity the profile names: its roles and the names with rights."""
    return list(dict.fromkeys([*ROLES, *identity_rights(auth)]))


def endpoint_hosts(
    profile: Profile, endpoints: Iterable[str] = (), names: Iterable[str] = ()
) -> list[str]:
    """The names a certificate must carry: the hosts of the profile's roles' endpoints and of
    ``endpoints``, and ``names``."""
    found = [e for ep in profile.network.roles.values() for e in (*ep.listen, *ep.connect)]
    return subject_names([*found, *endpoints], names)


def check_exposure(profile: Profile, where: str, listen: list[str]) -> None:
    """Refuse listening beyond this computer without ``network.auth``: anyone on the network
    could command the robot. The error names ``where`` and the command that fixes it."""
    if profile.network.auth is not None:
        return
    beyond = [e for e in listen if not is_loopback(e)]
    if beyond:
        raise AccessError(
            f"{profile.source}: {where}: {beyond} can be reached beyond this computer and the "
            "profile has no network.auth, so anyone on the network could command the robot; "
            f"fix: climbd certs --profile {profile.source} (or listen on loopback only)"
        )


def plain_loopback(listen: list[str], connect: list[str]) -> bool:
    """Endpoints that are all loopback and none TLS: only this computer reaches them."""
    endpoints = listen + connect
    return bool(endpoints) and all(not _secure(e) and is_loopback(e) for e in endpoints)


def check_network(profile: Profile) -> None:
    """What ``profile check`` and ``climbd install`` refuse before a role starts: a role
    listening beyond this computer without auth, and plain endpoints under TLS."""
    auth = profile.network.auth
    for role, ep in profile.network.roles.items():
        check_exposure(profile, f"network.roles.{role}.listen", list(ep.listen))
        if auth is not None and _uses_tls(auth):
            _check_secure(profile, role, [*ep.listen, *ep.connect])
    if auth is not None and auth.create_certificates:
        certificate_dir(profile)


def _secure(endpoint: str) -> bool:
    """Whether ``endpoint``'s protocol encrypts and authenticates (TLS)."""
    return endpoint.split("/", 1)[0] in SECURE_PROTOCOLS


def _uses_tls(auth: AuthConfig) -> bool:
    return bool(auth.tls_certificate or auth.tls_private_key or auth.tls_root_ca)


def _check_secure(profile: Profile, role: str, endpoints: list[str]) -> None:
    plain = [e for e in endpoints if not _secure(e)]
    if plain:
        raise AccessError(
            f"{profile.source}: network.roles.{role}: endpoints {plain} are not tls/ or quic/ "
            "but network.auth asks for TLS (serve read-only peers with auth.telemetry_listen)"
        )


def tls_settings(ca: str, certificate: str, private_key: str) -> dict:
    """Zenoh ``transport/link/tls`` for mutual TLS: one certificate to listen and to connect."""
    return {
        "root_ca_certificate": ca,
        "listen_certificate": certificate,
        "listen_private_key": private_key,
        "connect_certificate": certificate,
        "connect_private_key": private_key,
        "enable_mtls": True,
    }


def identity_rights(auth: AuthConfig) -> dict[str, frozenset[Right]]:
    """Each named identity's rights: its ``rights`` entry and, for a name in ``commanders``,
    every right but ``features``; any right implies ``telemetry`` (a commander must see the
    mode that confirms its e-stop)."""
    rights: dict[str, set[Right]] = {name: set(granted) for name, granted in auth.rights.items()}
    for name in auth.commanders:
        rights.setdefault(name, set()).update(COMMANDER_RIGHTS)
    return {name: frozenset({"telemetry", *granted}) for name, granted in rights.items()}


def role_identities(auth: AuthConfig) -> list[str]:
    """The identities climbd's own roles authenticate as: the role names (the CNs ``climbd
    certs`` writes) and ``user`` with ``{role}`` expanded."""
    names = list(ROLES) if auth.tls_certificate else []
    if auth.user:
        names += [auth.user.format(role=role) for role in ROLES]
    return sorted(set(names))


def _subjects(group: str, names: Iterable[str], auth: AuthConfig) -> list[dict]:
    """ACL subjects matching ``names`` by certificate CN and/or user name, per auth kind."""
    names = sorted(set(names))
    if not names:
        return []
    subjects = []
    if auth.tls_certificate:
        subjects.append({"id": f"{group}-tls", "cert_common_names": names})
    if auth.user:
        subjects.append({"id": f"{group}-user", "usernames": names})
    return subjects


def _rule(rule_id: str, flows: list[str], messages: list[str], keys: list[str]) -> dict:
    """One ``allow`` rule of a Zenoh ACL."""
    return {
        "id": rule_id,
        "permission": "allow",
        "flows": flows,
        "messages": messages,
        "key_exprs": keys,
    }


def command_acl(robot: str, auth: AuthConfig) -> dict:
    """Zenoh ACL of a role from the identities' rights: holders of any right (every
    authenticated peer when the profile has no ``rights`` table) observe and receive; the roles
    publish state and features; ``features`` holders publish features; each command key is put
    only by holders of its right (COMMAND_TOPICS)."""
    rights = identity_rights(auth)
    rules = [
        _rule("observe", ["ingress", "egress"], list(OBSERVE_MESSAGES), ["climbd/**"]),
        _rule("receive", ["egress"], ["put", "delete"], ["climbd/**"]),
        _rule("role", ["ingress"], ["put", "delete"], list(ROLE_KEYS)),
        _rule("features", ["ingress"], ["put", "delete"], ["climbd/*/features/**"]),
    ]
    for right, topics in COMMAND_TOPICS.items():
        rules.append(_rule(right, ["ingress"], ["put"], [f"climbd/{robot}/{t}" for t in topics]))
    roles = role_identities(auth)
    groups: dict[str, tuple[list[str], list[str]]] = {
        "role": (roles, ["observe", "receive", "role"]),
        "telemetry": (list(rights), ["observe", "receive"]),
    }
    for right in ("features", *COMMAND_TOPICS):
        groups[right] = ([n for n, r in rights.items() if right in r], [right])
    subjects: list[dict] = []
    policies: list[dict] = []
    if not auth.rights:
        subjects.append({"id": "peers"})
        policies.append({"rules": ["observe", "receive"], "subjects": ["peers"]})
    for group, (names, group_rules) in groups.items():
        found = _subjects(group, names, auth)
        subjects += found
        if found:
            policies.append({"rules": group_rules, "subjects": [s["id"] for s in found]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def gate_acl(robot: str) -> dict:
    """Zenoh ACL of the telemetry gate, whatever the peer's session mode: it observes, and
    receives only the role's state; a put on a command, feature or sim key reaches the gate
    alone (counted there, never forwarded), and any other put is refused by Zenoh."""
    observe = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"]
    counted = [f"climbd/{robot}/{k}/**" for k in ("cmd", "features", "sim")]
    rules = [
        _rule("ask", ["ingress"], observe, ["climbd/**"]),
        _rule("attempt", ["ingress"], ["put", "delete"], counted),
        _rule("answer", ["egress"], list(OBSERVE_MESSAGES), ["climbd/**"]),
        _rule("serve", ["egress"], ["put"], [f"climbd/{robot}/state/**"]),
    ]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": "anyone"}],
        "policies": [{"rules": [r["id"] for r in rules], "subjects": ["anyone"]}],
    }


def apply_auth(
    cfg: zenoh.Config, profile: Profile, role: str, listen: list[str], connect: list[str]
) -> None:
    """Add the profile's TLS or user/password authentication and the command ACL to ``cfg``."""
    auth = profile.network.auth
    if auth is None:
        return
    tls = _uses_tls(auth)
    if not tls and not auth.user:
        raise AccessError(
            f"{profile.source}: network.auth: give tls_root_ca/tls_certificate/tls_private_key "
            "or user/password/credentials_file"
        )
    if tls:
        _check_secure(profile, role, listen + connect)
        if auth.create_certificates and listen:
            out = certificate_dir(profile)
            try:
                first_run(out, identities(auth), endpoint_hosts(profile, listen + connect))
            except OSError as e:
                where = f"{profile.source}: network.auth.create_certificates"
                raise AccessError(f"{where}: {e}") from None
        settings = tls_settings(
            _path(profile, auth.tls_root_ca, role),
            _path(profile, auth.tls_certificate, role),
            _path(profile, auth.tls_private_key, role),
        )
        cfg.insert_json5("transport/link/tls", json.dumps(settings))
    if auth.user:
        usrpwd = {"user": auth.user.format(role=role), "password": auth.password}
        if auth.credentials_file:
            usrpwd["dictionary_file"] = _path(profile, auth.credentials_file, role)
        cfg.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    cfg.insert_json5("access_control", json.dumps(command_acl(profile.name, auth)))


def client_credentials(
    cfg: zenoh.Config,
    tls: tuple[str, str, str] | None = None,
    user: tuple[str, str] | None = None,
) -> None:
    """Credentials of an operator tool: ``tls=(ca, cert, key)`` and/or ``user=(name, password)``."""
    if tls is not None:
        missing = [p for p in tls if not Path(p).is_file()]
        if missing:
            raise AccessError(f"TLS file not found: {', '.join(missing)}")
        cfg.insert_json5("transport/link/tls", json.dumps(tls_settings(*tls)))
    if user is not None:
        cfg.insert_json5(
            "transport/auth/usrpwd", json.dumps({"user": user[0], "password": user[1]})
        )


class TelemetryGate:
    """A read-only Zenoh session for peers without credentials, client or peer mode alike.

    It is not linked to the role's authenticated session: the role mirrors telemetry to it with
    ``put``, and its ACL (``gate_acl``) forwards no peer's put to another, so its subscribers see
    only the role's own telemetry. Puts on command, feature and sim keys reach the gate, which
    counts them in ``attempts`` and logs them (rate-limited); other puts Zenoh refuses unseen.
    """

    def __init__(self, robot: str, listen: list[str]) -> None:
        import zenoh

        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps("peer"))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("scouting/gossip/enabled", "false")
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
        cfg.insert_json5("connect/endpoints", "[]")
        cfg.insert_json5("access_control", json.dumps(gate_acl(robot)))
        self.robot = robot
        self.session = zenoh.open(cfg)
        self.attempts = 0
        self._logged = -1e9
        self._lock = threading.Lock()
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._subscriber = self.session.declare_subscriber(
            f"climbd/{robot}/**", self._refuse, allowed_origin=zenoh.Locality.REMOTE
        )
        self._token = self.session.liveliness().declare_token(f"climbd/{robot}/alive/telemetry")

    def _refuse(self, sample: zenoh.Sample) -> None:
        """Count a peer's put (never acted on, never forwarded); log it every few seconds."""
        with self._lock:
            self.attempts += 1
            now = time.monotonic()
            due = now - self._logged >= REFUSAL_LOG_PERIOD
            if due:
                self._logged = now
        if due:
            log.warning(
                "refused %s from a peer without credentials on the read-only telemetry endpoint "
                "(%d so far; more only counted for %.0f s)",
                sample.key_expr,
                self.attempts,
                REFUSAL_LOG_PERIOD,
            )

    def put(self, message: Message) -> None:
        """Mirror one telemetry message to read-only peers."""
        k = f"climbd/{self.robot}/{message.TOPIC}"
        pub = self._publishers.get(k)
        if pub is None:
            import zenoh

            pub = self._publishers[k] = self.session.declare_publisher(
                k, congestion_control=zenoh.CongestionControl.DROP
            )
        pub.put(encode(message))

    def close(self) -> None:
        for d in (*self._publishers.values(), self._subscriber, self._token):
            d.undeclare()
        self._publishers.clear()
        self.session.close()
