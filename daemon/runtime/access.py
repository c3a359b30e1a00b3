"""Access control: who may command a robot over Zenoh, and read-only telemetry for everyone else.

The role's own Zenoh session admits only authenticated peers (mutual TLS with certificates from
``climbd certs``, or Zenoh user/password), and its access-control list lets every such peer
observe and publish state and features, but only ``commanders`` put on ``climbd/<robot>/cmd/**``.
Peers without credentials may reach a separate read-only ``TelemetryGate`` session: it mirrors
the role's telemetry and counts (and never forwards) every command put to it.
"""

from __future__ import annotations

import json
import logging
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from climbd.daemon.contract.messages import Message, encode
from climbd.daemon.contract.profile import AuthConfig, Profile

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


class AccessError(ValueError):
    """An auth setup that cannot work; the message names the profile field or the file."""


def _path(profile: Profile, value: str, role: str) -> str:
    base = Path(profile.source).parent if profile.source else Path.cwd()
    path = base / value.format(role=role)
    if not path.is_file():
        raise AccessError(f"{profile.source}: network.auth: file not found: {path}")
    return str(path)


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


def command_acl(robot: str, auth: AuthConfig) -> dict:
    """Zenoh ACL of a role: all peers observe and publish state, only commanders command."""
    commanders = list(auth.commanders)
    subjects: list[dict] = [{"id": "peers"}]
    command_subjects = []
    if commanders and auth.tls_certificate:
        subjects.append({"id": "commanders-tls", "cert_common_names": commanders})
        command_subjects.append("commanders-tls")
    if commanders and auth.user:
        subjects.append({"id": "commanders-user", "usernames": commanders})
        command_subjects.append("commanders-user")
    rules = [
        {
            "id": "observe",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": list(OBSERVE_MESSAGES),
            "key_exprs": ["climbd/**"],
        },
        {
            "id": "publish",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": ["put", "delete"],
            "key_exprs": ["climbd/*/state/**", "climbd/*/features/**"],
        },
        {
            "id": "command",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": ["put"],
            "key_exprs": [f"climbd/{robot}/cmd/**"],
        },
    ]
    policies = [{"rules": ["observe", "publish"], "subjects": ["peers"]}]
    if command_subjects:
        policies.append({"rules": ["command"], "subjects": command_subjects})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def apply_auth(
    cfg: zenoh.Config, profile: Profile, role: str, listen: list[str], connect: list[str]
) -> None:
    """Add the profile's TLS or user/password authentication and the command ACL to ``cfg``."""
    auth = profile.network.auth
    if auth is None:
        return
    tls = bool(auth.tls_certificate or auth.tls_private_key or auth.tls_root_ca)
    if not tls and not auth.user:
        raise AccessError(
            f"{profile.source}: network.auth: give tls_root_ca/tls_certificate/tls_private_key "
            "or user/password/credentials_file"
        )
    if tls:
        plain = [e for e in listen + connect if e.split("/", 1)[0] not in SECURE_PROTOCOLS]
        if plain:
            raise AccessError(
                f"{profile.source}: network.roles.{role}: endpoints {plain} are not tls/ or quic/ "
                "but network.auth asks for TLS (serve read-only peers with auth.telemetry_listen)"
            )
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
    """A read-only Zenoh session for peers without credentials.

    It is not linked to the role's authenticated session: the role mirrors telemetry to it
    with ``put``, and every command put to it is counted in ``attempts`` and dropped.
    """

    def __init__(self, robot: str, listen: list[str]) -> None:
        import zenoh

        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps("peer"))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        cfg.insert_json5("scouting/gossip/enabled", "false")
        cfg.insert_json5("listen/endpoints", json.dumps(listen))
        cfg.insert_json5("connect/endpoints", "[]")
        self.robot = robot
        self.session = zenoh.open(cfg)
        self.attempts = 0
        self._lock = threading.Lock()
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._subscriber = self.session.declare_subscriber(f"climbd/{robot}/cmd/**", self._refuse)
        self._token = self.session.liveliness().declare_token(f"climbd/{robot}/alive/telemetry")

    def _refuse(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.attempts += 1
            first = self.attempts == 1
        if first:
            log.warning(
                "refused %s from a peer without credentials (further ones only counted)",
                sample.key_expr,
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
