"""A datagram's source or destination, as the socket API gives it.

The slave's front door (:mod:`tdtp.admission`) and the session (:mod:`tdtp.session`) both key their
state by it, so it lives here, below both.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Address"]

Address = tuple[Any, ...]
"""A socket address as asyncio reports it: ``(host, port)`` or ``(host, port, flowinfo, scope_id)``."""
