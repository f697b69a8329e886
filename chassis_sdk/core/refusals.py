"""Counting what was refused and saying so without flooding: the first refusal at once,
then at most one summary per interval. Shared by the motion core (a velocity refused
for a block, a lease, a missing neutral) and every surface that reads commands from
outside the process (a message that does not parse, a stale stamp).

A flood of junk must not turn into a flood of reports that throttles the commands behind
it (an MQTT QoS 1 report per refusal ran at about 1,500 a second, and 50,000 junk
messages held an e-stop up for half a minute). Pure: no I/O, an injected clock.
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass

__all__ = ["MAX_REASON_CHARS", "RefusalReport", "Refusals"]

_NUMBERS = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
#: The longest reason kept (a reason quoting a payload stays one readable line).
MAX_REASON_CHARS = 160


@dataclass(frozen=True, slots=True)
class RefusalReport:
    """What was refused since the previous report."""

    #: Refusals in this report.
    count: int
    #: Refusals since the start.
    total: int
    #: Where the latest one came from (a topic, a channel).
    where: str
    #: Why the latest one was refused.
    why: str
    #: The reasons in this report with their counts (at most eight), each with its
    #: numbers as ``N`` (a stale command's age must not make every refusal a reason
    #: of its own).
    reasons: dict[str, int]
    #: Refusals not reported at all (the reasons past eight), in this report.
    unlisted: int

    def summary(self) -> str:
        """One line: the latest reason, and the count when it is more than one."""
        if self.count == 1:
            return f"{self.where}: {self.why}"
        return f"{self.count} refused, latest {self.where}: {self.why}"


class Refusals:
    """Counts refusals and decides when to report them: the first at once, then at most
    one report per ``interval`` summarising those in between.

    Call `add` for each refusal (it returns a report when one is due now), and
    `due` from time to time (every ``interval``) to send what is pending.

    Args:
        interval: The least time between two reports, seconds.
        clock: Monotonic clock (replaceable in tests).
    """

    _MAX_REASONS = 8

    def __init__(self, interval: float = 1.0, clock: Callable[[], float] = time.monotonic):
        if not interval > 0:
            raise ValueError(f"interval must be > 0, got {interval!r}")
        self.interval = interval
        self._clock = clock
        #: Refusals since the start.
        self.total = 0
        self._count = 0
        self._reasons: dict[str, int] = {}
        self._unlisted = 0
        self._where = ""
        self._why = ""
        self._last_report = -math.inf

    @property
    def pending(self) -> int:
        """Refusals not yet reported."""
        return self._count

    def add(self, where: str, why: str) -> RefusalReport | None:
        """Count one refusal; return a report if one is due now."""
        self.total += 1
        self._count += 1
        self._where, self._why = where, why
        reasons = self._reasons
        key = _NUMBERS.sub("N", why[:MAX_REASON_CHARS])
        if key in reasons:
            reasons[key] += 1
        elif len(reasons) < self._MAX_REASONS:
            reasons[key] = 1
        else:
            self._unlisted += 1
        return self.due()

    def due(self) -> RefusalReport | None:
        """The report of what is pending, if there is any and ``interval`` has passed
        since the previous report."""
        if not self._count:
            return None
        now = self._clock()
        if now - self._last_report < self.interval:
            return None
        report = RefusalReport(
            self._count, self.total, self._where, self._why, self._reasons, self._unlisted
        )
        self._last_report = now
        self._count = 0
        self._reasons = {}
        self._unlisted = 0
        return report
