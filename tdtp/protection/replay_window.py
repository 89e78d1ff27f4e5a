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


class WideReplayWindow(ReplayWindow):
    """A replay window ``width`` packet numbers wide (a power of two), for a multipath session.

    Its datagrams travel paths whose delays differ by tens or hundreds of milliseconds, so one
    path's datagrams arrive far behind the packet numbers another path has already delivered: a
    64-number window would refuse them as replays. Each of ``width`` slots holds the full number
    that last used it (``number % width``), so a number within the window was accepted exactly
    when its slot holds it; the work per packet does not grow with the width."""

    __slots__ = ("_slots", "_width")

    def __init__(self, width: int) -> None:
        super().__init__()
        if width < WINDOW or width & (width - 1):
            raise ValueError(f"a replay window's width is a power of two >= {WINDOW}, not {width}")
        self._width = width
        self._slots = [-1] * width

    def seen(self, number: int) -> bool:
        behind = self.highest - number
        if behind < 0:
            return False
        if behind >= self._width:
            return True
        return self._slots[number & (self._width - 1)] == number

    def accept(self, number: int) -> None:
        if number > self.highest:
            self.highest = number
        self._slots[number & (self._width - 1)] = number
