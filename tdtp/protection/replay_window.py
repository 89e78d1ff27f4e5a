"""The receiver's replay window over full (64-bit) packet numbers, as SRTP and DTLS keep one.

A packet number is accepted once: the highest authenticated number and a 64-bit mask of the ones
below it are remembered. A number 64 or more below the highest can no longer be checked and is
refused like a replay. The window only moves after a packet authenticated, so a forged packet cannot
push it.
"""

from __future__ import annotations

from typing import Final

WINDOW: Final = 64
_MASK: Final = (1 << WINDOW) - 1


class ReplayWindow:
    __slots__ = ("_mask", "highest")

    def __init__(self) -> None:
        self.highest = -1
        """The highest packet number accepted so far (-1 before any)."""
        self._mask = 0  # bit i: highest - i was accepted

    def seen(self, number: int) -> bool:
        """True if ``number`` was accepted before or is too old to tell (a replay either way)."""
        behind = self.highest - number
        if behind < 0:
            return False
        if behind >= WINDOW:
            return True
        return bool(self._mask >> behind & 1)

    def accept(self, number: int) -> None:
        """Record an authenticated packet number (``seen(number)`` must be False)."""
        ahead = number - self.highest
        if ahead > 0:
            self._mask = ((self._mask << ahead) | 1) & _MASK if ahead < WINDOW else 1
            self.highest = number
        else:
            self._mask |= 1 << -ahead
