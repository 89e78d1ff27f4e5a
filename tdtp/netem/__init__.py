"""In-process network impairment with tc-netem's parameters, semantics and syntax.

* :func:`parse_netem` reads netem options (``"delay 20ms 5ms loss 1%"``) into a
  :class:`NetemSpec`; ``str(spec)`` writes them back.
* :class:`NetemLink` is a sans-IO model of one direction: datagrams in with ``now``, out at their
  delivery time, with netem's order of operations and a seeded random generator.
* ``trace FILE`` (a tdtp extension) replaces the rate with a recorded capacity in Mahimahi's format:
  :func:`load_trace` reads one, :class:`TraceQueue` serves datagrams at its opportunities.

See ``docs/NETEM.md`` for what is emulated and how it differs from the kernel's netem.
"""

from tdtp.netem.link import NetemLink, NetemStats
from tdtp.netem.parser import NetemSyntaxError, parse_netem
from tdtp.netem.spec import (
    DEFAULT_LIMIT,
    DISTRIBUTIONS,
    CorruptSpec,
    DelaySpec,
    Distribution,
    DuplicateSpec,
    GilbertElliottLoss,
    LossModel,
    NetemSpec,
    RandomLoss,
    RateSpec,
    ReorderSpec,
    StateLoss,
    TraceSpec,
)
from tdtp.netem.trace_file import OPPORTUNITY_BYTES, Trace, TraceFileError, load_trace
from tdtp.netem.trace_queue import TraceQueue

__all__ = [
    "DEFAULT_LIMIT",
    "DISTRIBUTIONS",
    "OPPORTUNITY_BYTES",
    "CorruptSpec",
    "DelaySpec",
    "Distribution",
    "DuplicateSpec",
    "GilbertElliottLoss",
    "LossModel",
    "NetemLink",
    "NetemSpec",
    "NetemStats",
    "NetemSyntaxError",
    "RandomLoss",
    "RateSpec",
    "ReorderSpec",
    "StateLoss",
    "Trace",
    "TraceFileError",
    "TraceQueue",
    "TraceSpec",
    "load_trace",
    "parse_netem",
]
