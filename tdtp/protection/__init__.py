"""Keyed sessions: pre-shared keys, key derivation, packet protection and the replay window.

One layer around the wire codec: a keyed and an unkeyed session run the same
:class:`~tdtp.session.connection.Connection`, which hands its datagrams through this layer when it has keys.
docs/SECURITY.md describes the threat model; docs/PROTOCOL.md the keyed packet layout.
"""

from tdtp.protection.derivation import SessionSecrets, TrafficSecret
from tdtp.protection.keys import KEY_SIZE, KeyRing, PresharedKey
from tdtp.protection.packet_protection import PacketOpener, PacketSealer
from tdtp.protection.replay_window import ReplayWindow

__all__ = [
    "KEY_SIZE",
    "KeyRing",
    "PacketOpener",
    "PacketSealer",
    "PresharedKey",
    "ReplayWindow",
    "SessionSecrets",
    "TrafficSecret",
]
