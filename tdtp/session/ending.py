"""How a session ends: the CLOSE reason it sends, and what it tells its application when the peer's
CLOSE arrives (docs/PROTOCOL.md 5.2, "Closing").

A CLOSE says more than "over": ``RESTARTING`` means the sender stops but expects to be back soon (a
service restart), so a master reopens at once; ``EVICTED`` means a full slave gave the session's
slot to another master after this one had been silent too long, so a master reopens after a
back-off; ``NORMAL`` means the session is over for good. Each becomes its own
:class:`~tdtp.session.events.CloseCause`, so that an application (and ``reconnect=``) acts on a cause,
never on the wording of a detail. Pure functions: the connection carries them out.
"""

from __future__ import annotations

from tdtp.session.events import CloseCause
from tdtp.wire.control import CloseReason

_PEER_CAUSES = {
    CloseReason.RESTARTING: (
        CloseCause.PEER_RESTARTING,
        "the peer is restarting and expects to be back soon; open a new connection "
        "(reconnect= does)",
    ),
    CloseReason.EVICTED: (
        CloseCause.EVICTED,
        "the slave gave this session's slot to another master: it had heard nothing from us "
        "for longer than it keeps a silent master's slot (or our key opened a newer session "
        "elsewhere); reopen later",
    ),
}


def close_reason_text(reason: int) -> str:
    """A CLOSE reason code as words (``idle_timeout``), or ``reason code N`` for one we do not know."""
    try:
        return CloseReason(reason).name.lower()
    except ValueError:
        return f"reason code {reason}"


def peer_ending(reason: int) -> tuple[CloseCause, str]:
    """The cause and detail of a session the peer's CLOSE with ``reason`` ended."""
    try:
        known = CloseReason(reason)
    except ValueError:
        return CloseCause.PEER_CLOSE, close_reason_text(reason)
    return _PEER_CAUSES.get(known, (CloseCause.PEER_CLOSE, close_reason_text(reason)))


def local_ending(*, taken_over: bool, restarting: bool) -> tuple[CloseReason, CloseCause, str]:
    """What ``close()`` sends (the CLOSE reason) and reports (cause, detail)."""
    if taken_over:
        return CloseReason.TAKEN_OVER, CloseCause.TAKEN_OVER, "another master took control"
    if restarting:
        return (
            CloseReason.RESTARTING,
            CloseCause.LOCAL_CLOSE,
            "closed by the application, restarting (the peer was told to reopen)",
        )
    return CloseReason.NORMAL, CloseCause.LOCAL_CLOSE, "closed by the application"


def control_abandoned_text(cause: CloseCause, count: int) -> str:
    """The detail of the ``ControlExpired`` a session reports when it ends with ``count`` control
    messages the peer never acknowledged (docs/PROTOCOL.md 5.10, sender rule 6)."""
    return (
        f"the session ended ({cause.value}) before the peer acknowledged {count} control "
        "message(s); they are not resent on any later session (the peer may or may not have "
        "them): send them again once a session is established, if they still apply"
    )


KEY_EXHAUSTED_TEXT = "the session protected as many packets as its keys may; open a new connection"
FORGERY_LIMIT_TEXT = (
    "too many datagrams failed authentication under this session's key; open a new connection"
)
REPLACED_TEXT = "the master opened a new connection from the same address"


def open_timeout_text(*, dials: bool, timeout: float) -> str:
    """Why an opening gave up: the OPEN of the side that dials never answered, or the side that
    dialed never confirmed the session (PROTOCOL.md 5.1)."""
    if dials:
        return f"no answer to OPEN within {timeout} s"
    return f"the peer never confirmed the session within {timeout} s after our OPEN_ACK"


def restarted_text(peer: tuple[object, ...]) -> str:
    """A verified RESET's detail (PROTOCOL.md 5.7)."""
    return (
        f"the slave at {peer[0]}:{peer[1]} holds no session for us (it restarted); open a new "
        "connection"
    )
