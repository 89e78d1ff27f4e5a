"""What a rendezvous client and a relay can be told: :class:`Rendezvous` (where to meet, under which
name, how long to try direct paths) and :class:`RelayConfig` (a relay's tables and budgets).

Both validate in ``__post_init__`` (:class:`~tdtp.errors.InvalidArgumentError`, a ``ValueError``).
The names a pair meets under are derived here too (:func:`meeting`): the relay learns only an id,
the probes between the pair are MACed with a key the relay never sees.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from typing import Final, NamedTuple

from tdtp.errors import InvalidArgumentError
from tdtp.protection.derivation import derive_rendezvous_secret, expand_rendezvous
from tdtp.protection.keys import PresharedKey
from tdtp.wire.rendezvous import ID_SIZE

PROBE_KEY_SIZE: Final = 32


def _positive(name: str, value: object) -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or value <= 0
    ):
        raise InvalidArgumentError(f"{name} must be a positive number, got {value!r}")


def _count(name: str, value: object) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise InvalidArgumentError(f"{name} must be an integer >= 1, got {value!r}")


@dataclass(frozen=True, slots=True)
class Rendezvous:
    """Meet the peer through the relay at ``host``:``port`` (``tdtp relay``), then talk directly
    when a direct path works, else through the relay (docs/NAT.md).

    ``name``: what the pair meets under. A keyed pair may leave it out (it is derived from the key,
    so only key holders can meet there and the relay learns nothing of it); an unkeyed pair must
    give one, and anyone who knows it can meet the peer there: choose it as a password.
    """

    host: str
    port: int
    name: str | None = None
    direct_wait: float = 0.3
    """Seconds the dialer tries direct paths after learning the peer's addresses before it opens
    the session through the relay (a direct path found later is moved to mid-session)."""
    punch_interval: float = 0.02
    """Seconds between PROBEs to each candidate while hole punching."""
    punch_for: float = 2.0
    """Seconds of fast hole punching after the peer's addresses arrive; then :attr:`retry_interval`."""
    retry_interval: float = 0.5
    """Seconds between PROBEs to the candidates while no direct path works (a path that starts
    working is found this late at most)."""
    check_interval: float = 0.05
    """Seconds between PROBEs on the direct path in use."""
    path_timeout: float = 0.25
    """A direct path in use that answers no PROBE for this long is given up for the relay."""
    refresh_interval: float = 10.0
    """Seconds between REGISTERs that keep the registration (and the NAT's mapping to the relay)."""
    wait_for_peer: float = 30.0
    """Seconds a dialer waits at the relay for its peer to register before it gives up."""

    def __post_init__(self) -> None:
        if not isinstance(self.host, str) or not self.host:
            raise InvalidArgumentError(
                f"host must be the relay's host name or address, got {self.host!r}"
            )
        if (
            isinstance(self.port, bool)
            or not isinstance(self.port, int)
            or not 1 <= self.port <= 65535
        ):
            raise InvalidArgumentError(f"port must be an integer in 1..65535, got {self.port!r}")
        if self.name is not None and (not isinstance(self.name, str) or not self.name):
            raise InvalidArgumentError(
                f"name must be a non-empty string or None, got {self.name!r}"
            )
        for field in (
            "direct_wait",
            "punch_interval",
            "punch_for",
            "retry_interval",
            "check_interval",
            "path_timeout",
            "refresh_interval",
            "wait_for_peer",
        ):
            _positive(field, getattr(self, field))
        if self.path_timeout <= self.check_interval:
            raise InvalidArgumentError(
                f"path_timeout ({self.path_timeout}) must be longer than check_interval "
                f"({self.check_interval}): a path is given up after several unanswered checks"
            )


@dataclass(frozen=True, slots=True)
class RelayConfig:
    """A relay's tables and budgets (``tdtp relay``, ``tdtp.relay``): every one a peer can grow is
    bounded."""

    max_registrations: int = 4096
    """Registrations held at once (two per rendezvous); a new one beyond it is refused."""
    lifetime: float = 30.0
    """Seconds a registration lives without a REGISTER refreshing it."""
    registers_per_source: float = 10.0
    """REGISTERs per second one source address (host and port) may send."""
    register_burst: int = 20
    max_sources: int = 16384
    """Source addresses whose REGISTER rate is tracked (least recently seen forgotten first)."""
    replies_per_second: float = 20_000.0
    """Answers to unvalidated sources (cookies, "unknown source") per second, all together."""
    forward_rate: int = 20_000
    """Datagrams per second the relay forwards for one registration (a 1 kHz session needs ~1,000
    plus its acknowledgements and keep-alives); the rest are dropped and counted."""
    cookie_lifetime: float = 5.0

    def __post_init__(self) -> None:
        for field in ("lifetime", "registers_per_source", "replies_per_second", "cookie_lifetime"):
            _positive(field, getattr(self, field))
        for field in ("max_registrations", "register_burst", "max_sources", "forward_rate"):
            _count(field, getattr(self, field))


class Meeting(NamedTuple):
    """What a pair meets under: the id the relay sees, the key its probes are MACed with."""

    rendezvous_id: bytes
    probe_key: bytes


def meeting(key: PresharedKey | None, name: str | None) -> Meeting:
    """The id and probe key for a keyed pair (from the key; ``name`` may add to it) or an unkeyed
    one (from ``name``, required)."""
    if key is None and name is None:
        raise InvalidArgumentError(
            "an unkeyed rendezvous needs a name both sides give (Rendezvous(..., name=...), "
            "--rendezvous-name); a keyed pair meets under a name derived from its key"
        )
    secret = b""
    if key is not None:
        secret = derive_rendezvous_secret(key.secret)
    if name is not None:
        secret = hashlib.sha256(b"tdtp4 rendezvous name|" + secret + name.encode()).digest()
    return Meeting(
        expand_rendezvous(secret, b"rendezvous id", ID_SIZE),
        expand_rendezvous(secret, b"probe", PROBE_KEY_SIZE),
    )
