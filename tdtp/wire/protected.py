"""The keyed packet layout: what packet protection adds to a datagram.

In a keyed session every datagram after the opening handshake is::

    prefix | PN (2 bytes) | body, sealed | tag (16 bytes)

``prefix`` is the 5-byte base header, followed by the code byte for a CONTROL packet. ``PN`` is the
low 16 bits of the sender's packet number. The sealing itself lives in ``tdtp.protection``; these are
the sizes every other module needs to know.
"""

from __future__ import annotations

from typing import Final

PN_SIZE: Final = 2
"""Bytes of the packet number on the wire (low 16 bits of a 64-bit per-direction counter)."""
TAG_SIZE: Final = 16
"""Bytes of an AEAD authentication tag: the full 128 bits (docs/SECURITY.md says why not fewer)."""
PROTECTION_OVERHEAD: Final = PN_SIZE + TAG_SIZE
"""Bytes a keyed session adds to every protected datagram (18)."""
