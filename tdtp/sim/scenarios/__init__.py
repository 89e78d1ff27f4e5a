"""The simulated experiments: the paper's figures 7 and 8, TCP-friendliness, fairness and best effort.

One module per scenario (``paper``, ``friendliness``, ``fairness``, ``best_effort``); ``schemes`` holds
what they compare, ``dumbbell`` the topology and probes they share, ``results`` the JSON-safe result
base. :data:`SCENARIOS` names them for ``tdtp simulate``. ``cellular`` (recorded LTE traces, the
yardsticks of issue 32) is not among them: ``benchmarks/cellular.py`` runs it, beside Zenoh and raw UDP
on real sockets.

Each scenario is a function returning a result dataclass with ``to_dict()``/``to_json()``; a run is a
pure function of its arguments (``seed`` included). Every scenario runs each *scheme*:

* ``tdtp``: TDTP as the paper proposes it, acknowledgements piggybacked, trinomial control;
* ``trinomial``: the paper's comparison, the same controller with one separate ACK packet per data
  packet, padded so that it is 40 bytes on the wire (``ack_size`` 20 in the native encapsulation);
* ``tfrc``: TDTP's piggybacked acknowledgements with the TFRC controller (the paper's future work).

Packets are counted at their IP size: the paper's native encapsulation (IP 20 + TDTP 5 + data) unless
``encapsulation="udp"`` (IP 20 + UDP 8 + TDTP 5 + data).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from tdtp.sim.scenarios.best_effort import BestEffortResult, best_effort
from tdtp.sim.scenarios.fairness import FairnessResult, fairness
from tdtp.sim.scenarios.friendliness import FriendlinessResult, friendliness
from tdtp.sim.scenarios.paper import (
    MS,
    SM,
    STARVATION_SHARE,
    WINDOWS,
    PaperResult,
    PaperRun,
    TcpOutcome,
    paper,
    paper_windows,
    tail_window,
    tcp_pause,
)
from tdtp.sim.scenarios.results import ScenarioResult
from tdtp.sim.scenarios.schemes import SCHEMES, Scheme, connection_config

__all__ = [
    "MS",
    "SCENARIOS",
    "SCHEMES",
    "SM",
    "STARVATION_SHARE",
    "WINDOWS",
    "BestEffortResult",
    "FairnessResult",
    "FriendlinessResult",
    "PaperResult",
    "PaperRun",
    "ScenarioResult",
    "Scheme",
    "TcpOutcome",
    "best_effort",
    "connection_config",
    "fairness",
    "friendliness",
    "paper",
    "paper_windows",
    "tail_window",
    "tcp_pause",
]

SCENARIOS: Final[dict[str, Callable[..., ScenarioResult]]] = {
    "paper": paper,
    "friendliness": friendliness,
    "fairness": fairness,
    "best-effort": best_effort,
}
"""The scenarios by the name ``tdtp simulate`` knows them by."""
