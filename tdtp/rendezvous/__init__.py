"""Rendezvous and relay (docs/PROTOCOL.md 5.12, docs/NAT.md): how two endpoints behind NATs meet.

* :mod:`~tdtp.rendezvous.settings`: :class:`Rendezvous` (where and under which name to meet),
  :class:`RelayConfig`, and the derivation of what a pair meets under;
* :mod:`~tdtp.rendezvous.relay`: the relay's core: cookies, registrations, pairing, forwarding;
* :mod:`~tdtp.rendezvous.client`: an endpoint's side: registration, hole punching, path choice.

Sans-IO, like the session core: no sockets, no clock. This ``__init__`` imports nothing.
"""
