"""The bound behind ``Connection.timer_hint``: how early any of the session's deadlines moved.

Every piece of the session that owns a deadline (the pacer's sample, the ACK delay, loss detection, the
watchdog, the opening's retries) lowers one shared :class:`TimerHint` when it moves a deadline earlier,
or sets it to ``-math.inf`` when anything may have changed; ``Connection.get_timer`` resets it to
``math.inf``. An event loop that keeps one timer armed asks ``get_timer`` again only when the hint is
earlier than the armed deadline, instead of after every datagram.
"""

from __future__ import annotations

import math

from tdtp.control.base import RateController


class TimerHint:
    """``value``: no deadline moved earlier than it since the last ``get_timer``."""

    def __init__(self, controller: RateController) -> None:
        self.value = -math.inf
        self.controller_seen: float | None = None
        """The controller's deadline when get_timer last asked."""
        self._controller = controller

    def check_controller(self) -> None:
        """After a controller hook: lower the bound if the controller's deadline moved earlier than
        get_timer last saw it."""
        deadline = self._controller.get_timer()
        if deadline is not None and deadline < self.value:
            seen = self.controller_seen
            if seen is None or deadline < seen:
                self.value = deadline
