"""The schemes every scenario compares: TDTP, the paper's Trinomial with separate ACKs, TDTP with TFRC."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Final, Literal

from tdtp.config import AckMode, ConnectionConfig, ControllerName
from tdtp.errors import InvalidArgumentError
from tdtp.sim.endpoints import IP_HEADER, UDP_HEADER
from tdtp.wire.header import HEADER_SIZE

Encapsulation = Literal["native", "udp"]

ACK_WIRE_BYTES: Final = 40
"""The paper's Trinomial ACK packets: 40 bytes."""


@dataclass(frozen=True, slots=True)
class Scheme:
    key: str
    label: str
    ack_mode: AckMode
    controller: ControllerName


SCHEMES: Final[dict[str, Scheme]] = {
    "tdtp": Scheme(
        "tdtp", "TDTP (piggybacked ACKs, trinomial)", AckMode.BIDIRECTIONAL, "trinomial"
    ),
    "trinomial": Scheme(
        "trinomial", "Trinomial (separate 40-byte ACKs)", AckMode.SEPARATE, "trinomial"
    ),
    "tfrc": Scheme("tfrc", "TDTP with TFRC (piggybacked ACKs)", AckMode.BIDIRECTIONAL, "tfrc"),
    "teleop": Scheme(
        "teleop",
        "TDTP with teleop, the default (piggybacked ACKs)",
        AckMode.BIDIRECTIONAL,
        "teleop",
    ),
}
DEFAULT_SCHEMES: Final = ("tdtp", "trinomial", "tfrc")


def ip_overhead(encapsulation: Encapsulation) -> int:
    """Bytes below the TDTP header on the wire."""
    if encapsulation == "native":
        return IP_HEADER
    if encapsulation == "udp":
        return IP_HEADER + UDP_HEADER
    raise InvalidArgumentError(f"encapsulation must be 'native' or 'udp', got {encapsulation!r}")


def connection_config(
    scheme: Scheme,
    encapsulation: Encapsulation = "native",
    *,
    plain_acks: bool = False,
    controller_config: object | None = None,
) -> ConnectionConfig:
    """The connection configuration of a scheme: the controllers' defaults unless
    ``controller_config`` says otherwise; ``plain_acks`` for Trinomial's one-report-per-packet ACKs."""
    ack_size = HEADER_SIZE
    separate = scheme.ack_mode is AckMode.SEPARATE
    if separate:
        ack_size = max(HEADER_SIZE, ACK_WIRE_BYTES - ip_overhead(encapsulation))
    return ConnectionConfig(
        ack_mode=scheme.ack_mode,
        ack_size=ack_size,
        plain_acks=plain_acks and separate,
        controller=scheme.controller,
        controller_config=controller_config,
    )


def schemes_named(keys: Sequence[str]) -> list[Scheme]:
    unknown = [k for k in keys if k not in SCHEMES]
    if unknown:
        raise InvalidArgumentError(f"unknown scheme(s) {unknown}; known: {', '.join(SCHEMES)}")
    return [SCHEMES[k] for k in keys]
