"""Waiting between attempts to reconnect: one backoff for every reconnecting loop (a
device's link, a recording, the MQTT bridge's broker)."""

from __future__ import annotations

import random

from .validation import check_real

__all__ = ["Backoff"]


class Backoff:
    """Delays that double from ``start`` up to ``cap``, each jittered to 50-100 %:
    the jitter keeps a fleet of clients from retrying in lockstep.

    Args:
        start: The first delay (s).
        cap: The longest delay (s).
        factor: Growth per attempt.
    """

    def __init__(self, start: float, cap: float, factor: float = 2.0) -> None:
        self.start = check_real(start, "start", low=0, low_open=True, unit="s")
        self.cap = check_real(cap, "cap", low=self.start, unit="s")
        self.factor = check_real(factor, "factor", low=1)
        self._delay = self.start

    def reset(self) -> None:
        """Start from ``start`` again (an attempt succeeded and held)."""
        self._delay = self.start

    def next(self) -> float:
        """The delay before the next attempt; the one after grows."""
        delay = self._delay * random.uniform(0.5, 1.0)
        self._delay = min(self._delay * self.factor, self.cap)
        return delay
