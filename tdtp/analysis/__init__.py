"""Analytic models of what TDTP costs on the wire.

* :mod:`tdtp.analysis.bandwidth`: the paper's bandwidth model (eqs. 3-8, figure 5) for TDTP, the
  Trinomial protocol with separate ACKs, UDP and TCP, in three encapsulations.
"""
