"""A virtual-time network simulator that runs the real TDTP code: the paper's figures 6-8 and more.

* :mod:`tdtp.sim.engine`: events, packets, nodes, links (a :class:`~tdtp.netem.NetemLink` per
  direction for the rate and the DropTail queue, plus a propagation delay) and static routes;
* :mod:`tdtp.sim.endpoints`: the unchanged sans-IO :class:`~tdtp.session.connection.Connection` at both ends
  of a session, sampling at a fixed rate; a constant-rate UDP source;
* :mod:`tdtp.sim.tcp`: ns-2-like Tahoe/Reno/NewReno TCP with an FTP source, for cross traffic;
* :mod:`tdtp.sim.readings`: what the paper leaves open about its simulation, answered by name;
* :mod:`tdtp.sim.scenarios`: ``paper``, ``friendliness``, ``fairness``, ``best_effort``;
* :mod:`tdtp.sim.spread` and :mod:`tdtp.sim.study`: many seeds in parallel, medians and 95 %
  intervals, starved TCP flows flagged; the lock-out check;
* :mod:`tdtp.sim.plots`: their figures (needs matplotlib: ``pip install 'tdtp[plot]'``);
* :mod:`tdtp.cli.simulate`: ``tdtp simulate NAME --out DIR``.

docs/REPRODUCTION.md compares the results with the paper's.
"""

from tdtp.sim.endpoints import CbrSource, TdtpEndpoint, TdtpSession
from tdtp.sim.engine import Link, Network, Node, Packet, Simulator, Timer
from tdtp.sim.metrics import FlowRecorder, FlowSummary, jain_index
from tdtp.sim.readings import READINGS, Reading
from tdtp.sim.scenarios import SCENARIOS, SCHEMES, best_effort, fairness, friendliness, paper
from tdtp.sim.spread import MedianInterval, median_interval
from tdtp.sim.study import LockoutStudy, PaperStudy, lockout_study, paper_study
from tdtp.sim.tcp import TcpConfig, TcpFlow

__all__ = [
    "READINGS",
    "SCENARIOS",
    "SCHEMES",
    "CbrSource",
    "FlowRecorder",
    "FlowSummary",
    "Link",
    "LockoutStudy",
    "MedianInterval",
    "Network",
    "Node",
    "Packet",
    "PaperStudy",
    "Reading",
    "Simulator",
    "TcpConfig",
    "TcpFlow",
    "TdtpEndpoint",
    "TdtpSession",
    "Timer",
    "best_effort",
    "fairness",
    "friendliness",
    "jain_index",
    "lockout_study",
    "median_interval",
    "paper",
    "paper_study",
]
