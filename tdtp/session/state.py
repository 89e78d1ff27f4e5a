"""Where a session is in its life: :class:`State`, and the error for a call its state refuses."""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING, Final

from tdtp.config import Role
from tdtp.errors import ArgumentTypeError, ConnectionClosedError, ConnectionStateError

if TYPE_CHECKING:
    from tdtp.session.events import ConnectionClosed


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


# The members the per-packet paths compare with, as module constants: reading one off its class
# goes through the enum metaclass (about 0.1 us in either build on Python 3.11), a constant does not.
OPENING: Final = State.OPENING
ESTABLISHED: Final = State.ESTABLISHED
CLOSED: Final = State.CLOSED


def refusal(state: State, event: ConnectionClosed | None) -> ConnectionStateError:
    """Why nothing can be sent in ``state`` (not ESTABLISHED): closed (``event`` says why), or not
    open yet."""
    if state is State.CLOSED:
        why = "" if event is None else f" ({event.cause.value}: {event.detail})"
        return ConnectionClosedError(
            f"the connection is closed{why}; open a new one to send again", event
        )
    return ConnectionStateError(
        f"cannot send while {state.value}: wait for the ConnectionEstablished event"
    )


def dialing(role: object, dials: object) -> bool:
    """Whether a connection of ``role`` sends the OPEN: ``dials`` if given, else the master does."""
    if not isinstance(role, Role):
        raise ArgumentTypeError(f"role must be Role.MASTER or Role.SLAVE, got {role!r}")
    if dials is None:
        return role is Role.MASTER
    if not isinstance(dials, bool):
        raise ArgumentTypeError(f"dials must be True, False or None, got {dials!r}")
    return dials
