"""The two memories of copies: which samples arrived already (receiver), and where and when each of
ours left (sender).

A multipath session sends one sample as several identical datagrams, one per path (keyed: the same
sealed datagram, one packet number). The receiver takes the first and drops the others as
``duplicate``, before anything else looks at them: a copy carries nothing the first did not (its
acknowledgement fields are the same bytes), it needs no authentication to be dropped, and it must not
reach the replay window, whose job is to refuse datagrams seen before. Only a copy whose sample has
already been taken in (authenticated, in a keyed session) counts as one, so a forged "copy" cannot
shadow a real sample.

:class:`CopyFilter` remembers, for the last 2048 sequence numbers (half the 12-bit space: no copy
further behind can even be decoded), the full number that arrived and when. :class:`SentRing`
remembers, for our last 4096, when each left and on which paths, so that a path's report (which names
a 12-bit sequence number) yields that path's round trip.
"""

from __future__ import annotations

from typing import Final

from tdtp.wire.seqnum import SEQ_MODULUS

FILTER_SIZE: Final = 2048
"""Sequence numbers the receiver remembers (a power of two)."""
SENT_SIZE: Final = SEQ_MODULUS
"""Sequence numbers the sender remembers (the whole 12-bit space)."""


class CopyFilter:
    """First arrivals of the last :data:`FILTER_SIZE` sequence numbers."""

    __slots__ = ("_at", "_path", "_seq")

    def __init__(self) -> None:
        self._seq = [-1] * FILTER_SIZE
        self._at = [0.0] * FILTER_SIZE
        self._path = [0] * FILTER_SIZE

    def first_arrival(self, seq: int) -> float | None:
        """When the first copy of ``seq`` (a full number) arrived, if one did."""
        slot = seq & (FILTER_SIZE - 1)
        return self._at[slot] if self._seq[slot] == seq else None

    def first_path(self, seq: int) -> int:
        """The path the first copy of ``seq`` came on (-1 if none is remembered)."""
        slot = seq & (FILTER_SIZE - 1)
        return self._path[slot] if self._seq[slot] == seq else -1

    def record(self, seq: int, path_id: int, now: float) -> None:
        slot = seq & (FILTER_SIZE - 1)
        self._seq[slot] = seq
        self._at[slot] = now
        self._path[slot] = path_id


class SentRing:
    """Send time and paths (a bit mask of path ids) of our last :data:`SENT_SIZE` data packets."""

    __slots__ = ("_paths", "_seq", "_time")

    def __init__(self) -> None:
        self._seq = [-1] * SENT_SIZE
        self._time = [0.0] * SENT_SIZE
        self._paths = [0] * SENT_SIZE

    def record(self, seq: int, now: float, paths: int) -> None:
        slot = seq & (SENT_SIZE - 1)
        self._seq[slot] = seq
        self._time[slot] = now
        self._paths[slot] = paths

    @staticmethod
    def expand(low: int, highest_sent: int) -> int:
        """The newest full sequence number up to ``highest_sent`` whose low 12 bits are ``low``."""
        return highest_sent - ((highest_sent - low) & (SENT_SIZE - 1))

    def send_time(self, seq: int) -> float | None:
        slot = seq & (SENT_SIZE - 1)
        return self._time[slot] if self._seq[slot] == seq else None

    def paths(self, seq: int) -> int:
        """The mask of path ids ``seq`` was sent on (0 if it is not remembered)."""
        slot = seq & (SENT_SIZE - 1)
        return self._paths[slot] if self._seq[slot] == seq else 0
