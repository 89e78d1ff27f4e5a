"""Where a session is in its life: :class:`State`."""

from __future__ import annotations

import enum


class State(enum.Enum):
    """Where a :class:`Connection` is in its life: opening, established or closed."""

    IDLE = "idle"
    """A master that has not called :meth:`Connection.connect` yet."""
    LISTENING = "listening"
    """A slave waiting for its master's OPEN."""
    OPENING = "opening"
    """A master whose OPEN is not answered yet."""
    ESTABLISHED = "established"
    CLOSED = "closed"
