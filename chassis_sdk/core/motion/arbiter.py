"""The arbiter: which source may move the robot now, sans-IO.

Every motion request comes from a *source*: the application's own calls (``"api"``),
each client of a remote surface (a dashboard page, an MQTT sender, a ROS 2 ``cmd_vel``
writer, a Foxglove client), terminal teleop and the gamepad, goals and reflexes. The
arbiter decides, from the sources, the blocks and an injected clock, whether a command
may act; it writes nothing. [`Motion`][chassis_sdk.core.motion.Motion] acts on what it
decides, and every surface goes through it, so each rule lives here once:

* **Blocks end commands; clearing one restarts nothing** (ISO 13850). An e-stop of any
  origin, a latched bumper, a driver fault or a lost link *blocks*: a velocity is
  refused while any block holds, and the block's start ends the command in force. After
  the last block clears, a *streaming* source (one that repeats its command: a held key,
  a stick, a ``cmd_vel`` publisher) must first send a neutral (zero, or a stop) before
  its velocity is taken again, the joystick rule of "neutral before re-enable". Silence
  longer than the deadman (`quiet`) counts as letting go, as the deadman takes it: a
  panel that publishes only while a button is held (Foxglove's Teleop) has let go once
  it has been silent that long. A one-shot source (the API) gives a new command by
  calling again.
* **One source drives at a time**, under a lease that lapses with its command's
  deadline. Another source's velocity is refused ("driven by web page 2") unless its
  priority is higher (an order like twist_mux's, `DEFAULT_PRIORITIES`) or it takes over
  explicitly. A neutral from a source that does not drive is ignored (an idle publisher
  of zeros does not stop the one driving).
* **A stop always acts**, from any source, read-only viewers included, and ends the
  lease.

Refusals are returned as [`Refusal`][chassis_sdk.core.motion.Refusal] values and counted
per source and reason; reporting them is the caller's.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Final, Literal

__all__ = [
    "DEFAULT_PRIORITIES",
    "WRITE_JITTER",
    "WRITE_PERIOD",
    "Arbiter",
    "Refusal",
    "RefusalReason",
    "Source",
]

#: The least time between two velocity writes (s), for every source together: at most
#: 50 velocity frames a second reach the device however fast commands arrive (the
#: newest is written; a stop never waits for it).
WRITE_PERIOD: Final = 0.02
#: How early a velocity frame may be against that period, as long as the rate holds
#: (the tolerance of a GCRA rate limit): a control loop that writes at the telemetry's
#: 50 Hz keeps its pace through its jitter; a flood is still written 50 times a second.
WRITE_JITTER: Final = 0.005

#: The default order between kinds of source, highest first, as twist_mux orders its
#: inputs: an operator at the robot (terminal teleop, a gamepad) above one at a
#: dashboard or viewer above the application's own calls above goals (so a velocity
#: from the application ends its goal) above ROS 2 above MQTT. Reflexes act as blocks
#: and stops, above all of them. Change it per device with
#: ``robot.motion.priorities[kind] = n``.
DEFAULT_PRIORITIES: Final[Mapping[str, int]] = {
    "teleop": 100,
    "gamepad": 100,
    "web": 80,
    "foxglove": 80,
    "api": 70,
    "goal": 65,
    "ros2": 60,
    "mqtt": 40,
}

#: Why a velocity was refused: motion is blocked; another source holds the lease; the
#: source must send a neutral first; the command was older than its deadman.
RefusalReason = Literal["blocked", "driven", "neutral", "stale"]


@dataclass(frozen=True, slots=True)
class Refusal:
    """A velocity that was not taken, and why.

    Attributes:
        source: The name of the source refused.
        reason: ``"blocked"``, ``"driven"``, ``"neutral"`` or ``"stale"``.
        detail: One line for a person: ``"blocked by HARDWARE_ESTOP"``, ``"driven by web
            page 2"``.
        blocks: The blocks in force (for ``"blocked"`` and ``"neutral"``), e.g.
            ``("HARDWARE_ESTOP",)``.
    """

    source: str
    reason: RefusalReason
    detail: str
    blocks: tuple[str, ...] = ()


class Source:
    """One origin of motion commands, made by `Arbiter.add` (through ``robot.motion.source``).

    Attributes:
        name: Unique among the arbiter's sources (``"web page 2"``).
        kind: What it is, for its priority (``"web"``, ``"ros2"``, ``"api"``...).
        streaming: Whether it repeats its command (must send a neutral after a block).
        ended_by: Why its last lease ended before its command did (``"stopped by
            api"``, ``"taken by web page"``, ``"blocked by FRONT_BUMPER"``), ``None``
            while it drives or after it ended its command itself; a goal reads it to
            end at once, and never acts again after it.
    """

    __slots__ = ("_last", "_needs_neutral", "closed", "ended_by", "kind", "name", "streaming")

    def __init__(self, name: str, kind: str, streaming: bool) -> None:
        self.name = name
        self.kind = kind
        self.streaming = streaming
        self.closed = False
        self.ended_by: str | None = None
        self._needs_neutral = False
        self._last = -math.inf  # when it last offered a velocity

    def __repr__(self) -> str:
        return f"<Source {self.name!r} kind={self.kind!r}>"


class Arbiter:
    """Decides which commands act, from the sources, the blocks and the clock.

    The caller (`Motion`) asks `velocity` before taking a velocity, tells `granted`
    its deadline once taken, calls `stop` for a stop, and `set_blocks` when what blocks
    motion changes; each returns what to do. Nothing here writes or sleeps.

    Args:
        clock: Monotonic clock (injected in tests).
        priorities: Kind -> priority, higher wins (default `DEFAULT_PRIORITIES`);
            an unknown kind has priority 0.
        quiet: Seconds of silence after which a streaming source has let go (owes no
            neutral): the deadman; ``None``: silence never counts.
    """

    def __init__(
        self,
        *,
        clock: Callable[[], float] = time.monotonic,
        priorities: Mapping[str, int] | None = None,
        quiet: float | None = None,
    ) -> None:
        self._clock = clock
        #: Silence (s) that counts as a streaming source letting go; ``None``: never.
        self.quiet = quiet
        #: Kind -> priority (higher wins); change it at any time.
        self.priorities: dict[str, int] = dict(
            DEFAULT_PRIORITIES if priorities is None else priorities
        )
        self._sources: dict[str, Source] = {}
        self._holder: Source | None = None
        self._until = -math.inf
        self._blocks: dict[str, tuple[str, ...]] = {}
        #: Refusals counted by (source name, reason), since the start.
        self.refused: Counter[tuple[str, RefusalReason]] = Counter()
        #: Stops (from any source) and blocks that began, counted: a goal that sees it
        #: change since it was called ends, whether or not it held the lease yet.
        self.epoch = 0

    # --- sources ---------------------------------------------------------------------------

    def add(self, name: str, kind: str, *, streaming: bool) -> Source:
        """A new source named ``name`` (``"name 2"``, ``"name 3"``... if taken)."""
        if not isinstance(name, str) or not name:
            raise ValueError(f"a source needs a name, got {name!r}")
        if not isinstance(kind, str) or not kind:
            raise ValueError(f"a source needs a kind, got {kind!r}")
        unique, n = name, 1
        while unique in self._sources:
            n += 1
            unique = f"{name} {n}"
        source = Source(unique, kind, streaming)
        self._sources[unique] = source
        return source

    def remove(self, source: Source) -> bool:
        """Forget ``source``; True if it held the lease with a command in force (the
        caller ends that command: a client that went away leaves the robot stopped)."""
        source.closed = True
        self._sources.pop(source.name, None)
        if self.holder is source:
            self._holder = None
            return True
        return False

    @property
    def sources(self) -> tuple[Source, ...]:
        """The sources, oldest first."""
        return tuple(self._sources.values())

    def priority(self, source: Source) -> int:
        """``source``'s priority now (its kind's)."""
        return self.priorities.get(source.kind, 0)

    @property
    def holder(self) -> Source | None:
        """The source that drives, while its command is in force; else ``None``."""
        if self._holder is not None and self._clock() >= self._until:
            self._holder = None
        return self._holder

    # --- blocks ----------------------------------------------------------------------------

    @property
    def blocks(self) -> tuple[str, ...]:
        """What blocks motion now (flag names such as ``"HARDWARE_ESTOP"``), each once,
        in the order first reported; empty when motion is free."""
        seen: dict[str, None] = {}
        for reasons in self._blocks.values():
            seen.update(dict.fromkeys(reasons))
        return tuple(seen)

    def set_blocks(self, origin: str, reasons: Iterable[str]) -> bool:
        """What ``origin`` (``"device"``, ``"link"``, ``"software"``...) says blocks
        motion now, replacing what it said before.

        Returns:
            True if a block began (one that was not in force): the caller ends every
            command in force; every source then needs a new command, and a streaming
            one a neutral first.
        """
        before = set(self.blocks)
        now = tuple(dict.fromkeys(reasons))
        if now:
            self._blocks[origin] = now
        else:
            self._blocks.pop(origin, None)
        began = bool(set(now) - before)
        if began:
            self.epoch += 1
            self._end_lease(f"blocked by {', '.join(self.blocks)}")
            self._holder = None
            for source in self._sources.values():
                source._needs_neutral = source.streaming
        return began

    # --- commands --------------------------------------------------------------------------

    def velocity(self, source: Source, *, neutral: bool, take_over: bool = False) -> Refusal | bool:
        """May ``source``'s velocity act now?

        Args:
            source: Who asks.
            neutral: The velocity is zero (a neutral clears the need for one).
            take_over: Take the lease from a source of any priority.

        Returns:
            True: take it (then call `granted`). False: ignore it, silently (a neutral
            from a source that does not drive, or during a block). A `Refusal`: refuse
            it, and report it (counted here).
        """
        if source.closed:
            raise RuntimeError(f"source {source.name!r} is closed")
        now = self._clock()
        if self.quiet is not None and now - source._last >= self.quiet:
            source._needs_neutral = False  # silent that long: it has let go
        source._last = now
        blocks = self.blocks
        if blocks:
            if neutral:
                source._needs_neutral = False
                return False
            source._needs_neutral = source.streaming
            names = ", ".join(blocks)
            return self._refuse(source, "blocked", f"blocked by {names}", blocks)
        if neutral:
            source._needs_neutral = False
        elif source._needs_neutral:
            return self._refuse(
                source,
                "neutral",
                "send a zero (neutral) first: motion was blocked since this source last drove",
            )
        holder = self.holder
        if holder is None or holder is source:
            return True
        if take_over or self.priority(source) > self.priority(holder):
            return True
        if neutral:
            return False
        return self._refuse(source, "driven", f"driven by {holder.name}")

    def granted(self, source: Source, until: float) -> None:
        """``source``'s velocity was taken: it holds the lease until ``until``
        (``clock()`` time; the command's deadline, ``math.inf`` for none)."""
        if self.holder is not source:
            self._end_lease(f"taken by {source.name}")
        source.ended_by = None
        self._holder = source
        self._until = until

    def stop(self, source: Source | None = None) -> None:
        """A stop (always acts): the lease ends; a stop is ``source``'s neutral."""
        self.epoch += 1
        holder = self.holder
        if holder is not None and holder is not source:
            self._end_lease("stopped" if source is None else f"stopped by {source.name}")
        self._holder = None
        self._until = -math.inf
        if source is not None:
            source._needs_neutral = False

    def _end_lease(self, why: str) -> None:
        """The lease in force (if any) ends for ``why``, not by its holder's wish."""
        holder = self.holder
        if holder is not None:
            holder.ended_by = why

    def stale(self, source: Source, detail: str) -> Refusal:
        """Refuse ``source``'s command as older than its deadman (counted)."""
        return self._refuse(source, "stale", detail)

    def _refuse(
        self, source: Source, reason: RefusalReason, detail: str, blocks: tuple[str, ...] = ()
    ) -> Refusal:
        self.refused[source.name, reason] += 1
        return Refusal(source.name, reason, detail, blocks or self.blocks)
