"""A master that reopens its session on its own: the policy (:class:`ReconnectPolicy`) and what the
endpoint records of it (:class:`ReconnectRecord`).

``tdtp.connect(..., reconnect=True)`` (or a :class:`ReconnectPolicy`) keeps the one
:class:`~tdtp.aio.endpoint.Endpoint` the application holds alive across sessions: when a session ends
for a cause in :attr:`ReconnectPolicy.reopen_on` (by default: the slave said it is restarting, a
verified RESET said it restarted, it evicted us, or nothing was heard for ``idle_timeout``), or the
slave has been silent for ``after_silence`` seconds, the endpoint opens a new session on the same
socket (new nonces, new keys, OPENs at the usual retry pacing) and the application's ``async for``
loop, :meth:`~tdtp.aio.endpoint.Endpoint.send` and :meth:`~tdtp.aio.endpoint.Endpoint.latest` go on.

What happens to what the application sends while there is no session:

* samples are dropped as superseded (a newer one replaces them; nothing is queued for the next
  session), counted in :attr:`ReconnectRecord.samples_dropped`;
* control messages are refused at once with :class:`~tdtp.errors.ReconnectingError`, and those the
  ended session never had acknowledged are reported in one
  :class:`~tdtp.session.events.ControlExpired` (its ``payloads``); none is ever resent on the next
  session by itself. The peer may have received them (their acknowledgement may be what was lost),
  and the next session may reach a slave that restarted since: only the application knows whether a
  command still applies, so an emergency stop is never silently lost and never silently repeated.

The watchdog carries on across the gap: the application gets a
:class:`~tdtp.session.events.PeerSilent` when the session ends (if the slave was not silent already)
and a :class:`~tdtp.session.events.PeerResumed` once the next one is established, and
``ep.peer_silent`` is True in between.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from tdtp.errors import ArgumentTypeError, InvalidArgumentError
from tdtp.session.connection import Connection
from tdtp.session.events import Address, CloseCause, ConnectionClosed, PeerSilent
from tdtp.session.state import State
from tdtp.wire.control import CloseReason

REOPENABLE: frozenset[CloseCause] = frozenset(
    {
        CloseCause.PEER_RESTARTING,
        CloseCause.PEER_RESTARTED,
        CloseCause.EVICTED,
        CloseCause.IDLE_TIMEOUT,
        CloseCause.PEER_CLOSE,
        CloseCause.KEY_EXHAUSTED,
    }
)
"""The causes :attr:`ReconnectPolicy.reopen_on` may name: endings a new session can cure. A local
close, a REJECT and an open timeout never start a reconnection (a REJECT ``BUSY`` and an open timeout
are failed attempts of one under way, retried with back-off)."""
DEFAULT_REOPEN_ON: frozenset[CloseCause] = frozenset(
    {
        CloseCause.PEER_RESTARTING,
        CloseCause.PEER_RESTARTED,
        CloseCause.EVICTED,
        CloseCause.IDLE_TIMEOUT,
    }
)
"""By default a master reopens after the slave said it is restarting (CLOSE ``RESTARTING``), after a
verified RESET (it restarted without a word), after an eviction (after :attr:`busy_backoff`) and
after an idle timeout; not after a CLOSE ``NORMAL``: the slave ended the session on purpose."""


@dataclass(frozen=True, slots=True)
class ReconnectPolicy:
    """How a master reopens its session (``tdtp.connect(reconnect=...)``)."""

    attempts: int | None = None
    """Reopenings in a row that may fail (time out: the slave still down, ``open_timeout`` each;
    or be refused ``BUSY``) before the endpoint gives up and closes with the last cause; ``None``:
    never give up."""
    backoff: float = 0.0
    """Seconds to wait before reopening after a reopening that timed out; doubles each time up to
    :attr:`max_backoff`. (An attempt already takes ``open_timeout``, its OPENs paced.) The first
    reopening after a restart, a RESET, an idle timeout or a silence starts at once."""
    busy_backoff: float = 1.0
    """Seconds to wait before reopening when the slave has no slot for us: after an eviction, and
    after a reopening refused ``BUSY``; doubles with each refusal in a row, up to
    :attr:`max_backoff`. Never 0: a full slave answers at once, and a master must not hammer it."""
    max_backoff: float = 5.0
    after_silence: float | None = 3.0
    """Seconds of silence from the slave after which the master stops waiting for the session and
    opens a new one: the way back when no RESET can tell it the slave restarted (a keyed master
    sending datagrams too small to carry a RESET's tag, a RESET lost). ``None``: only a RESET or
    the idle timeout. A slave that was merely cut off takes the new OPEN as a restarted master's
    (PROTOCOL.md 5.1, rule 5), so a reopening costs a round trip, not the session's samples."""
    reopen_on: frozenset[CloseCause] = DEFAULT_REOPEN_ON
    """The causes that end a session into a reconnection (any iterable of
    :class:`~tdtp.session.events.CloseCause` from :data:`REOPENABLE`; kept as a frozenset). The
    default is :data:`DEFAULT_REOPEN_ON`; add ``CloseCause.PEER_CLOSE`` to reopen after any CLOSE
    from the slave, or leave out ``EVICTED`` to stop once a full slave gave our slot away."""

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
        busy = self.busy_backoff
        if (
            isinstance(busy, bool)
            or not isinstance(busy, int | float)
            or not math.isfinite(busy)
            or busy <= 0
        ):
            raise InvalidArgumentError(
                f"busy_backoff must be a positive number of seconds, got {busy!r}"
            )
        silence = self.after_silence
        if silence is not None and (
            not isinstance(silence, int | float) or not math.isfinite(silence) or silence <= 0
        ):
            raise InvalidArgumentError(
                f"after_silence must be a positive number of seconds or None, got {silence!r}"
            )
        object.__setattr__(self, "reopen_on", _causes(self.reopen_on))


def _causes(value: object) -> frozenset[CloseCause]:
    """``reopen_on`` as a frozenset of reopenable causes, or the error that says what is allowed."""
    allowed = ", ".join(sorted(f"CloseCause.{cause.name}" for cause in REOPENABLE))
    if isinstance(value, str | bytes) or not isinstance(value, Iterable):
        raise ArgumentTypeError(
            f"reopen_on must be a set of tdtp.CloseCause ({allowed}), got {value!r}"
        )
    causes = frozenset(value)
    for cause in causes:
        if not isinstance(cause, CloseCause):
            raise ArgumentTypeError(
                f"reopen_on must hold tdtp.CloseCause members ({allowed}), got {cause!r}"
            )
        if cause not in REOPENABLE:
            raise InvalidArgumentError(
                f"reopen_on cannot hold {cause}: a new session does not cure it; choose from "
                f"{allowed}"
            )
    return causes


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
    lost: tuple[str, str] | None = None
    """Why the last session ended into a reconnection: (cause, detail); ``None`` before any."""


class Reconnector:
    """A reconnecting master's policy at work: whether an ended session reopens, what it records,
    when the next OPEN goes. The :class:`~tdtp.aio.endpoint.Endpoint` swaps in the connection it
    makes and keeps the watchdog's events; this class decides."""

    def __init__(
        self,
        policy: ReconnectPolicy,
        new_connection: Callable[[], Connection],
        loop: asyncio.AbstractEventLoop,
        reopen_to: Callable[[], Address | None] | None = None,
    ) -> None:
        self.policy = policy
        self.record = ReconnectRecord()
        self._new_connection = new_connection
        self._loop = loop
        self._failures = 0
        """Reopenings in a row that failed (timed out, or refused BUSY)."""
        self.silence_reopen = False
        """The endpoint closed its session itself after ``after_silence``: reopen."""
        self._handle: asyncio.TimerHandle | None = None
        self._remote: Address | None = None
        self._reopen_to = reopen_to  # where the next session opens (default: the last peer)

    def may_reopen(self, event: ConnectionClosed, *, established: bool, closing: bool) -> bool:
        """Whether the session that ended with ``event`` leads to a reopening (counting a failed
        one): only once the endpoint was established, and never while it closes."""
        if closing or not established:
            return False
        cause = event.cause
        if cause is CloseCause.LOCAL_CLOSE:
            return self.silence_reopen
        if self.record.reopening:
            # A reopening failed: the slave is still down (timeout) or has no slot for us (BUSY).
            if cause is not CloseCause.OPEN_TIMEOUT and not is_busy(event):
                return False
            self._failures += 1
            self.record.failed_attempts += 1
            attempts = self.policy.attempts
            return attempts is None or self._failures <= attempts
        return cause in self.policy.reopen_on

    def reopen(
        self, old: Connection, event: ConnectionClosed, start: Callable[[], None]
    ) -> Connection:
        """The next session's connection (not opened yet: ``start`` runs after the back-off, then
        :meth:`open` connects it); records the loss the first time."""
        record = self.record
        if not record.reopening:
            why = "silence" if event.cause is CloseCause.LOCAL_CLOSE else event.cause.value
            record.causes[why] = record.causes.get(why, 0) + 1
            record.lost = (why, event.detail)
            stats = old.stats
            record.samples_received_before += stats.samples_delivered
            record.samples_sent_before += stats.sent.data_packets
            record.reopening = True
        self.silence_reopen = False
        self._remote = old.peer
        conn = self._new_connection()
        if old.sending_paused:
            conn.pause_sending()
        self._handle = self._loop.call_later(
            reopen_delay(self.policy, event, self._failures), start
        )
        return conn

    def open(self, conn: Connection, now: float) -> bool:
        """The back-off is over: connect ``conn`` (False: nothing to do, the endpoint closed)."""
        self._handle = None
        remote = self._remote if self._reopen_to is None else self._reopen_to()
        if remote is None or conn.state is not State.IDLE:
            return False
        conn.connect(remote, now=now)
        return True

    def reopened(self, now: float) -> None:
        """The new session is established."""
        record = self.record
        record.reopening = False
        record.count += 1
        record.last_at = now
        self._failures = 0

    def silence_wait(self, event: PeerSilent) -> float | None:
        """How long after ``event`` to check whether the slave is still silent (``after_silence``),
        or ``None`` (the policy does not reopen on silence)."""
        after = self.policy.after_silence
        return None if after is None else max(0.0, after - (event.detected_at - event.since))

    def cancel(self) -> None:
        """The endpoint closes: no reopening is pending any more."""
        if self._handle is not None:
            self._handle.cancel()
            self._handle = None


def is_busy(event: ConnectionClosed) -> bool:
    """A REJECT ``BUSY``: the slave has no slot for us now (it may later)."""
    return event.cause is CloseCause.REJECTED and event.reason == CloseReason.BUSY


def reopen_delay(policy: ReconnectPolicy, event: ConnectionClosed, failures: int) -> float:
    """How long to wait before the next reopening: ``busy_backoff``, doubling per failure, while the
    slave has no slot for us (evicted, or refused BUSY); ``backoff``, doubling, after attempts that
    timed out; at once after a restart, a RESET, a silence or an idle timeout."""
    if event.cause is CloseCause.EVICTED or is_busy(event):
        return min(policy.max_backoff, policy.busy_backoff * 2.0 ** max(0, failures - 1))
    if not failures:
        return 0.0
    return min(policy.max_backoff, policy.backoff * 2.0 ** (failures - 1))
