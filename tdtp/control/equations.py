"""The throughput equations the controllers cap their rates with.

* :func:`tcp_friendly_rate` is the paper's eq. 2, the simple square-root law: what a conformant TCP
  flow averages at loss rate ``p`` and round-trip time ``rtt`` when retransmission timeouts are
  ignored, ``sqrt(3) / (rtt * sqrt(2p))`` packets per second.
* :func:`padhye_rate` is the paper's eq. 1 (Padhye et al., 1998) in packets per second, the same law
  with the retransmission-timeout term that dominates at high loss.
* :func:`tfrc_rate` is RFC 5348's form of eq. 1 in bytes per second with ``b = 1`` and
  ``t_RTO = 4 R``.

All three return ``math.inf`` for ``p == 0`` (no loss seen: the equations put no bound on the rate).
"""

from __future__ import annotations

import math

__all__ = ["padhye_rate", "tcp_friendly_rate", "tfrc_rate"]

_SQRT3 = math.sqrt(3.0)


def _check_rtt(name: str, value: float) -> None:
    if not (0.0 < value < math.inf):
        raise ValueError(
            f"{name} must be a positive, finite number of seconds, got {value!r}; "
            "pass the smoothed round-trip time (for example 0.05 for 50 ms)"
        )


def _check_p(p: float) -> None:
    if not (0.0 <= p <= 1.0):
        raise ValueError(
            f"p must be a loss (event) rate between 0 and 1, got {p!r}; "
            "pass a fraction such as 0.01 for 1 %, not a percentage"
        )


def tcp_friendly_rate(rtt: float, p: float) -> float:
    """Eq. 2 of the paper: ``sqrt(3) / (rtt * sqrt(2 p))`` packets per second.

    ``rtt`` in seconds (> 0), ``p`` the loss (event) rate in ``[0, 1]``. ``p == 0`` gives ``math.inf``.
    """
    _check_rtt("rtt", rtt)
    _check_p(p)
    if p == 0.0:
        return math.inf
    return _SQRT3 / (rtt * math.sqrt(2.0 * p))


def padhye_rate(rtt: float, p: float, rto: float) -> float:
    """Eq. 1 of the paper (Padhye et al. 1998) in packets per second (the packet size ``s = 1``).

    ``1 / (rtt * sqrt(2p/3) + rto * 3 * sqrt(3p/8) * p * (1 + 32 p^2))``; ``rto`` is the TCP
    retransmission timeout in seconds (RFC 5348 uses ``4 * rtt``). ``p == 0`` gives ``math.inf``.
    """
    _check_rtt("rtt", rtt)
    _check_rtt("rto", rto)
    _check_p(p)
    if p == 0.0:
        return math.inf
    denominator = rtt * math.sqrt(2.0 * p / 3.0) + rto * 3.0 * math.sqrt(3.0 * p / 8.0) * p * (
        1.0 + 32.0 * p * p
    )
    return 1.0 / denominator


def tfrc_rate(s: float, rtt: float, p: float) -> float:
    """RFC 5348's throughput equation in bytes per second, with ``b = 1`` and ``t_RTO = 4 * rtt``.

    ``s`` is the segment (packet) size in bytes (> 0). Equal to ``s * padhye_rate(rtt, p, 4 * rtt)``.
    """
    if not (0.0 < s < math.inf):
        raise ValueError(f"s must be a positive packet size in bytes, got {s!r}")
    return s * padhye_rate(rtt, p, 4.0 * rtt)
