"""Why a received datagram was not taken in: the verdicts of docs/PROTOCOL.md section 5.5.

Both the slave's front door (:mod:`tdtp.admission`, before any session exists) and the session
(:mod:`tdtp.session`) drop datagrams and count them by these reasons, and the conformance vectors
name them (``tests/vectors/``), so they live here, below both.
"""

from __future__ import annotations

import enum

__all__ = ["DropReason"]


class DropReason(enum.Enum):
    """Why a received datagram was not taken in. Every dropped datagram has exactly one reason."""

    TRUNCATED = "truncated"
    """Shorter than the 5-byte header."""
    UNKNOWN_TYPE = "unknown_type"
    """TYPE is the reserved value."""
    UNKNOWN_VERSION = "unknown_version"
    """An OPEN for a protocol version this implementation does not speak."""
    OVERSIZED = "oversized"
    """Longer than the header plus the maximum payload."""
    EMPTY_DATA = "empty_data"
    """A DATA packet without payload: senders never send one (a sample has at least one byte)."""
    WRONG_ADDRESS = "wrong_address"
    """Not from the connection's peer (off-path)."""
    OPTIMISTIC_ACK = "optimistic_ack"
    """Acknowledges a sequence number this side never sent."""
    DUPLICATE = "duplicate"
    """A second copy of a data packet (replayed or duplicated by the network)."""
    LATE = "late"
    """Arrived after a newer data packet and too late to be delivered in order: its gap was given up
    (the reorder wait ran out, or there is none). Still acknowledged."""
    STALE = "stale"
    """Older than the 64-packet reordering window: cannot be told apart from a replay."""
    NOT_ESTABLISHED = "not_established"
    """Data or acknowledgement before the connection is open."""
    CLOSED = "closed"
    """Arrived after the connection ended."""
    BAD_CONTROL = "bad_control"
    """A control packet with an unknown code or a body of the wrong size."""
    NONCE_MISMATCH = "nonce_mismatch"
    """A control packet of another (earlier) connection: a replay or a stale retransmission."""
    UNEXPECTED_CONTROL = "unexpected_control"
    """A well-formed control packet that makes no sense in this state or role."""
    UNVALIDATED = "unvalidated"
    """An OPEN without a valid cookie: answered with a COOKIE, nothing kept (address validation)."""
    REFUSED = "refused"
    """An OPEN from a validated address that was answered with REJECT (busy, unknown key, ...)."""
    RATE_LIMITED = "rate_limited"
    """An OPEN over its source's rate, or one the slave's reply budget could not answer."""
    UNAUTHENTICATED = "unauthenticated"
    """Keyed session: the authentication tag did not verify (forged, corrupted, or another key)."""
    REPLAYED = "replayed"
    """Keyed session: a packet number already accepted, or too old to check (replayed)."""
    CONTROL_WINDOW = "control_window"
    """A control MESSAGE numbered beyond the receive window (``control_window`` past the next
    message expected): more than a conforming peer may have outstanding."""
    CONTROL_BACKLOG = "control_backlog"
    """A control MESSAGE that found the receive bound full (messages held out of order plus those
    delivered but not read by the application): not acknowledged, so the peer sends it again."""
    UNMATCHED_RESET = "unmatched_reset"
    """A RESET that echoes none of our recent datagrams, or (keyed) whose tags do not verify:
    forged, replayed, or too late."""
    PEER_ALIVE = "peer_alive"
    """A RESET that matches, while the slave has been heard within our ``silence_timeout``: a
    slave that holds our session is talking, so the RESET answered a copy of one of our datagrams
    sent elsewhere (a replay to this slave from another address, or to another slave holding the
    key), not our session's datagram at a slave that lost it."""
    FAR_AHEAD = "far_ahead"
    """Unkeyed session: a DATA packet numbered further ahead of the highest received than the peer
    can have sent in the time since (a blind forgery; taking it would make us acknowledge numbers
    the peer never sent and drop the real packets as late)."""
    PATH_LIMIT = "path_limit"
    """Multipath: a new path refused: the session has ``max_paths`` already, or new paths came
    faster than ``new_paths_per_second`` (PROTOCOL.md 5.11)."""
    UNKNOWN_PATH = "unknown_path"
    """Multipath: a datagram from an address (or on a local socket) that is none of the session's
    paths, or a multipath packet naming a path that arrived on another one."""
    BAD_TOKEN = "bad_token"
    """Multipath: an MP_RESPONSE echoing a token no challenge of ours on that path carried."""
