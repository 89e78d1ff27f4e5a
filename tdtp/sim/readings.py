"""Readings of the paper's experiment: every choice its figure 6-8 simulation leaves open, named.

The paper (section 4) fixes the topology, the rates, the queue limits, the sampling and the ACK size,
but not the direction of the TCP cross traffic, the TCP variant, the form of Trinomial's ACKs, whether
the queues count packets or bytes, or whether the senders are cycle-exact. A :class:`Reading` states one
answer to each. Four are named (:data:`READINGS`):

* ``literal``: what the text says, and ns-2's defaults where it says nothing. TCP congests the
  master-to-slave direction only ("no congestion is simulated between 20 and 30 seconds in the Master
  to Slave direction"), with ns-2's default ``Agent/TCP`` (Tahoe, ``window_`` 20, 1000-byte
  segments, 10 ms ``tcpTick_``, 0.2 s ``minrto_``); Trinomial answers every data packet with one plain
  40-byte ACK that reports that packet only (eq. 4); DropTail queues count packets; senders are exact.
* ``redundant-acks``: the same, but Trinomial's ACKs repeat the status of the 6 packets below, as
  this project's separate-ACK mode does by default: a lost ACK costs the sender nothing.
* ``both-ways``: the literal reading with TCP congesting both directions throughout, the other way
  to read "hard bottleneck congestion due TCP traffic".
* ``project``: what this project's simulator did before it had readings: TCP both ways, NewReno, ACKs
  that repeat the status of the 6 packets below (a lost ACK costs nothing), and a 0-0.5 ms send jitter
  that breaks the phase lock of periodic senders at a DropTail queue.

Any field can be overridden (``tdtp simulate paper --tcp-variant reno``, :func:`dataclasses.replace`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Final, Literal

from tdtp.sim.tcp import TCP_VARIANTS

__all__ = [
    "ACK_FORMS",
    "DEFAULT_READING",
    "NS2_MEAN_PACKET_SIZE",
    "QUEUE_UNITS",
    "READINGS",
    "TCP_DIRECTIONS",
    "Reading",
    "reading",
]

TcpDirections = Literal["master-to-slave", "both"]
AckForm = Literal["plain", "redundant"]
QueueUnit = Literal["packets", "bytes"]

TCP_DIRECTIONS: Final = ("master-to-slave", "both")
ACK_FORMS: Final = ("plain", "redundant")
QUEUE_UNITS: Final = ("packets", "bytes")
NS2_MEAN_PACKET_SIZE: Final = 500
"""ns-2's ``Queue set mean_pktsize_``: a byte-counted queue of ``limit_`` 15 holds 15 x 500 bytes."""
SEND_JITTER: Final = 0.0005
"""Each TDTP datagram leaves its host up to 0.5 ms late (uniform, in order): a real send path is not
cycle-exact, and without it periodic 1 kHz flows lock into phase at the DropTail queues
(:class:`~tdtp.sim.endpoints.TdtpEndpoint`)."""


@dataclass(frozen=True, slots=True)
class Reading:
    """One answer to each question the paper leaves open about its simulation."""

    name: str
    tcp_directions: TcpDirections = "master-to-slave"
    """Where the TCP cross traffic runs: master to slave only (pausing 20-30 s), or also slave to
    master all the time."""
    tcp_variant: str = "tahoe"
    """``tahoe`` (ns-2's ``Agent/TCP``), ``reno`` or ``newreno``."""
    ack_form: AckForm = "plain"
    """Trinomial's ACKs: ``plain`` (each reports its own packet only) or ``redundant`` (each also
    repeats the status of the 6 packets below it)."""
    queue_unit: QueueUnit = "packets"
    """DropTail limits in packets (ns-2's default) or in bytes (``limit x 500``, ns-2's
    ``queue_in_bytes_`` with its ``mean_pktsize_``)."""
    send_jitter: float = 0.0
    """Each TDTP datagram leaves its host a uniform random ``[0, send_jitter)`` s late (in order)."""
    summary: str = ""
    """One line for people."""

    def __post_init__(self) -> None:
        if not (isinstance(self.name, str) and self.name):
            raise ValueError(f"a reading needs a name, got {self.name!r}")
        if self.tcp_directions not in TCP_DIRECTIONS:
            raise ValueError(
                f"tcp_directions must be one of {', '.join(TCP_DIRECTIONS)}, "
                f"got {self.tcp_directions!r}"
            )
        if self.tcp_variant not in TCP_VARIANTS:
            raise ValueError(
                f"tcp_variant must be one of {', '.join(TCP_VARIANTS)}, got {self.tcp_variant!r}"
            )
        if self.ack_form not in ACK_FORMS:
            raise ValueError(
                f"ack_form must be one of {', '.join(ACK_FORMS)}, got {self.ack_form!r}"
            )
        if self.queue_unit not in QUEUE_UNITS:
            raise ValueError(
                f"queue_unit must be one of {', '.join(QUEUE_UNITS)}, got {self.queue_unit!r}"
            )
        if not (
            isinstance(self.send_jitter, int | float)
            and math.isfinite(self.send_jitter)
            and 0.0 <= self.send_jitter <= 0.01
        ):
            raise ValueError(f"send_jitter must be between 0 and 0.01 s, got {self.send_jitter!r}")

    @property
    def tcp_both_ways(self) -> bool:
        """Whether the cross TCP runs in both directions (else master to slave only)."""
        return self.tcp_directions == "both"

    def describe(self) -> str:
        """The parameters in one line: ``TCP master-to-slave, tahoe; plain ACKs; queue in packets; ...``."""
        jitter = (
            f"send jitter 0-{self.send_jitter * 1000:g} ms"
            if self.send_jitter
            else "no send jitter"
        )
        return (
            f"TCP {self.tcp_directions}, {self.tcp_variant}; Trinomial ACKs {self.ack_form}; "
            f"queues in {self.queue_unit}; {jitter}"
        )

    def to_dict(self) -> dict[str, Any]:
        """The reading's parameters and its one-line description, as plain data."""
        return asdict(self) | {"description": self.describe()}


READINGS: Final[dict[str, Reading]] = {
    "literal": Reading(
        "literal",
        summary="the paper's text, ns-2's defaults where it is silent",
    ),
    "redundant-acks": Reading(
        "redundant-acks",
        ack_form="redundant",
        summary="as literal, but Trinomial's ACKs repeat the 6 packets below (a lost ACK is free)",
    ),
    "both-ways": Reading(
        "both-ways",
        tcp_directions="both",
        summary="as literal, but TCP congests both directions",
    ),
    "project": Reading(
        "project",
        tcp_directions="both",
        tcp_variant="newreno",
        ack_form="redundant",
        send_jitter=SEND_JITTER,
        summary="this project's earlier choices: TCP both ways, NewReno, redundant ACKs, jitter",
    ),
}
DEFAULT_READING: Final = "literal"


def reading(name: str) -> Reading:
    """The named reading; :class:`ValueError` listing the names for an unknown one."""
    try:
        return READINGS[name]
    except KeyError:
        raise ValueError(f"unknown reading {name!r}; known: {', '.join(READINGS)}") from None
