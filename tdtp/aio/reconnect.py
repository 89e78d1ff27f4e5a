"""A master that reopens its session on its own: the policy (:class:`ReconnectPolicy`) and what the
endpoint records of it (:class:`ReconnectRecord`).

``tdtp.connect(..., reconnect=True)`` (or a :class:`ReconnectPolicy`) keeps the one
:class:`~tdtp.aio.endpoint.Endpoint` the application holds alive across sessions: when a session ends
because the slave restarted (a verified RESET, ``PEER_RESTARTED``), because nothing was heard for
``idle_timeout``, or because the slave has been silent for ``after_silence`` seconds, the endpoint opens
a new session on the same socket (new nonces, new keys, OPENs at the usual retry pacing) and the
application's ``async for`` loop, :meth:`~tdtp.aio.endpoint.Endpoint.send` and
:meth:`~tdtp.aio.endpoint.Endpoint.latest` go on. Samples offered while no session is established are
dropped as superseded (a newer one replaces them; nothing is queued for the next session).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from tdtp.errors import ArgumentTypeError, InvalidArgumentError
from tdtp.session.events import CloseCause

REOPEN_CAUSES = frozenset(
    {CloseCause.PEER_RESTARTED, CloseCause.IDLE_TIMEOUT, CloseCause.OPEN_TIMEOUT}
)
"""Why a session may end for a reconnecting master to open the next one. A CLOSE from the slave,
a REJECT (busy, unknown key, ...), a local close and an exhausted key end the endpoint as usual.
``OPEN_TIMEOUT`` counts only for a reopening (the slave is still down), never for the first open."""


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """How a master reopens its session (``tdtp.connect(reconnect=...)``)."""

    attempts: int | None = None
    """Reopenings in a row that may time out (the slave still down: ``open_timeout`` each) before
    the endpoint gives up and closes with the last cause; ``None``: never give up."""
    backoff: float = 0.0
    """Seconds to wait before reopening after a reopening that timed out; doubles each time up to
    :attr:`max_backoff`. The first reopening after a session ends starts at once."""
    max_backoff: float = 5.0
    after_silence: float | None = 3.0
    """Seconds of silence from the slave after which the master stops waiting for the session and
    opens a new one: the way back when no RESET can tell it the slave restarted (a keyed master
    sending datagrams too small to carry a RESET's tag, a RESET lost). ``None``: only a RESET or
    the idle timeout. A slave that was merely cut off takes the new OPEN as a restarted master's
    (PROTOCOL.md 5.1, rule 5), so a reopening costs a round trip, not the session's samples."""

    def __post_init__(self) -> None:
        attempts = self.attempts
        if attempts is not None and (
            isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 0
        ):
            raise InvalidArgumentError(
                f"attempts must be an integer >= 0 or None, got {attempts!r}"
            )
        for name in ("backoff", "max_backoff"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value) or value < 0:
                raise InvalidArgumentError(
                    f"{name} must be a number of seconds >= 0, got {value!r}"
                )
        silence = self.after_silence
        if silence is not None and (
            not isinstance(silence, int | float) or not math.isfinite(silence) or silence <= 0
        ):
            raise InvalidArgumentError(
                f"after_silence must be a positive number of seconds or None, got {silence!r}"
            )


def as_policy(reconnect: object) -> ReconnectPolicy | None:
    """``connect``'s ``reconnect=`` argument: False/None (no), True (the defaults) or a policy."""
    if reconnect is None or reconnect is False:
        return None
    if reconnect is True:
        return ReconnectPolicy()
    if isinstance(reconnect, ReconnectPolicy):
        return reconnect
    raise ArgumentTypeError(
        f"reconnect must be True, False or a tdtp.ReconnectPolicy, got {reconnect!r}"
    )


@dataclass(slots=True)
class ReconnectRecord:
    """What a reconnecting endpoint did (``ep.reconnects``)."""

    count: int = 0
    """Sessions opened again after the first one ended."""
    causes: dict[str, int] = field(default_factory=dict)
    """Why the sessions before them ended, by cause (``peer_restarted``, ``idle_timeout``,
    ``silence`` for :attr:`ReconnectPolicy.after_silence`)."""
    failed_attempts: int = 0
    """Reopenings that timed out (the slave was still down)."""
    last_at: float | None = None
    """``monotonic()`` when the last new session was established."""
    samples_received_before: int = 0
    """Samples delivered by the sessions before the current one (the current one's
    ``stats.samples_delivered`` counts the rest)."""
    samples_sent_before: int = 0
    """DATA packets sent by the sessions before the current one."""
    samples_dropped: int = 0
    """Samples the application offered while no session was established (superseded, never
    queued)."""
    reopening: bool = False
    """True while a new session is being opened (no session to send on)."""
