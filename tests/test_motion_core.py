"""The motion core's rules, each a row: a script of commands from sources, blocks and
the passing of time (an injected clock; no I/O, no sleep), and what reaches the wire.

`Motion` is the arbiter and the watchdog together, as a device has them; its writes
are recorded with the clock's time. ``advance`` runs the watchdog's ticks that fall due
on the way, as its task would.
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass, field
from typing import Any

import pytest

from chassis_sdk import MotionBlockedError, NotConnectedError
from chassis_sdk.core.motion import (
    DEFAULT_PRIORITIES,
    WRITE_JITTER,
    WRITE_PERIOD,
    Arbiter,
    Motion,
    MotionSource,
    Refusal,
)

pytestmark = pytest.mark.codec  # pure: no I/O, an injected clock


@dataclass
class Rig:
    """A `Motion` on a fake clock, recording what it writes."""

    t: float = 0.0
    open: bool = True
    writes: list[tuple[float, tuple[float, float]]] = field(default_factory=list)
    sources: dict[str, MotionSource] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.motion = Motion(
            self._write,
            self._ensure_open,
            lambda: b"0,0",
            self._builder,
            interval=0.05,
            command_timeout=0.49,  # not a multiple of the resend interval
            logger=logging.getLogger("test_motion_core"),
            clock=lambda: self.t,
        )
        self.sources["api"] = self.motion.api

    def _write(self, frame: bytes, expires: float) -> None:
        self._ensure_open()
        a, b = (float(x) for x in frame.decode().split(","))
        self.writes.append((round(self.t, 6), (a, b)))

    def _ensure_open(self) -> None:
        if not self.open:
            raise NotConnectedError("closed")

    @staticmethod
    def _builder(a: float, b: float) -> Any:
        if math.isnan(a) or math.isnan(b):
            raise ValueError("NaN")
        return lambda x, y: f"{x},{y}".encode()

    def advance(self, to: float) -> None:
        watchdog = self.motion.watchdog
        while (due := watchdog.due()) is not None and due <= to:
            self.t = max(self.t, due)
            watchdog.tick(self.t)
        self.t = to

    def add(self, name: str, kind: str, streaming: bool = True) -> None:
        source = self.motion.source(name, kind=kind, streaming=streaming)
        self.sources[source.name] = source  # "web page", "web page 2"...

    def v(self, name: str, a: float, b: float = 0.0, **kw: Any) -> str:
        """Offer a velocity: ``"taken"`` (or ignored: nothing refused) or the refusal's
        ``reason: detail``; the API's refusals are raised, so they are caught here."""
        if name == "api":
            try:
                self.motion.drive(a, b, self._builder(a, b), kw.get("duration"), "velocity")
            except MotionBlockedError as exc:
                return f"raised {exc.reasons}"
            return "taken"
        refusal = self.sources[name].set_velocity(a, b, **kw)
        return "taken" if refusal is None else f"{refusal.reason}: {refusal.detail}"


# Each row: (rule, script, expected writes). A script is steps of
#   ("at", t)                    the clock moves to t (ticks due on the way run)
#   ("add", name, kind[, streaming])
#   ("v", name, a, b, expect[, options])   expect "taken", "raised (...)", "reason: ..."
#   ("stop", name) / ("close", name)
#   ("block", origin, (reasons...))
ROWS: list[tuple[str, list[tuple[Any, ...]], list[tuple[float, tuple[float, float]]]]] = [
    (
        "a command is written at once and re-sent every resend interval",
        [("v", "api", 0.3, 0.0, "taken"), ("at", 0.12)],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0)), (0.1, (0.3, 0.0))],
    ),
    (
        "per source the newest counts; at most one write per period",
        [
            ("v", "api", 0.1, 0.0, "taken"),
            ("at", 0.001),
            ("v", "api", 0.2, 0.0, "taken"),
            ("at", 0.002),
            ("v", "api", 0.3, 0.0, "taken"),
            ("at", 0.03),
        ],
        [(0.0, (0.1, 0.0)), (WRITE_PERIOD - WRITE_JITTER, (0.3, 0.0))],
    ),
    (
        "a stop acts at once; a velocity taken before it is never written after it",
        [
            ("v", "api", 0.1, 0.0, "taken"),
            ("at", 0.001),
            ("v", "api", 0.2, 0.0, "taken"),
            ("at", 0.002),
            ("stop", "api"),
            ("at", 0.3),
        ],
        [(0.0, (0.1, 0.0)), (0.002, (0.0, 0.0))],
    ),
    (
        "the deadman: a command not repeated ends after command_timeout, with one zero",
        [("v", "api", 0.3, 0.0, "taken"), ("at", 0.7)],
        [(t, (0.3, 0.0)) for t in (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45)]
        + [(0.49, (0.0, 0.0))],
    ),
    (
        "a duration holds exactly that long",
        [("v", "api", 0.3, 0.0, "taken", {"duration": 0.12}), ("at", 0.3)],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0)), (0.1, (0.3, 0.0)), (0.12, (0.0, 0.0))],
    ),
    (
        "a stamped command holds for its deadman counted from its stamp",
        [
            ("add", "mqtt", "mqtt"),
            ("v", "mqtt", 0.3, 0.0, "taken", {"age": 0.42}),
            ("at", 0.3),
        ],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0)), (0.07, (0.0, 0.0))],
    ),
    (
        "a command older than its deadman is refused",
        [
            ("add", "mqtt", "mqtt"),
            (
                "v",
                "mqtt",
                0.3,
                0.0,
                "stale: the command is 0.600 s old, more than its 0.49 s",
                {"age": 0.6},
            ),
            ("at", 0.3),
        ],
        [],
    ),
    (
        "while blocked, the API's velocity raises with the block's name",
        [
            ("block", "device", ("HARDWARE_ESTOP",)),
            ("v", "api", 0.3, 0.0, "raised ('HARDWARE_ESTOP',)"),
            ("at", 0.3),
        ],
        [],
    ),
    (
        "a block ends the command in force; clearing it restarts nothing",
        [
            ("v", "api", 0.3, 0.0, "taken", {"duration": 5.0}),
            ("at", 0.11),
            ("block", "device", ("HARDWARE_ESTOP",)),
            ("at", 0.2),
            ("block", "device", ()),
            ("at", 1.0),
        ],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0)), (0.1, (0.3, 0.0)), (0.11, (0.0, 0.0))],
    ),
    (
        "after a block the API drives on a new call",
        [
            ("block", "software", ("SOFTWARE_ESTOP",)),
            ("block", "software", ()),
            ("v", "api", 0.3, 0.0, "taken", {"duration": 0.04}),
            ("at", 0.3),
        ],
        [(0.0, (0.3, 0.0)), (0.04, (0.0, 0.0))],
    ),
    (
        "a streaming source must send a neutral after a block before it drives again",
        [
            ("add", "page", "web"),
            ("v", "page", 0.3, 0.0, "taken"),
            ("at", 0.01),
            ("block", "device", ("REMOTE_ESTOP",)),
            ("v", "page", 0.3, 0.0, "blocked: blocked by REMOTE_ESTOP"),
            ("block", "device", ()),
            ("at", 0.1),
            (
                "v",
                "page",
                0.3,
                0.0,
                "neutral: send a zero (neutral) first: motion was "
                "blocked since this source last drove",
            ),
            ("v", "page", 0.0, 0.0, "taken"),
            ("at", 0.13),
            ("v", "page", 0.2, 0.0, "taken"),
            ("at", 0.14),
        ],
        [(0.0, (0.3, 0.0)), (0.01, (0.0, 0.0)), (0.1, (0.0, 0.0)), (0.13, (0.2, 0.0))],
    ),
    (
        "a neutral sent during the block counts; a velocity refused after it owes another",
        [
            ("add", "pad", "gamepad"),
            ("block", "link", ("LINK_LOST",)),
            ("v", "pad", 0.0, 0.0, "taken"),
            ("v", "pad", 0.4, 0.0, "blocked: blocked by LINK_LOST"),
            ("block", "link", ()),
            (
                "v",
                "pad",
                0.4,
                0.0,
                "neutral: send a zero (neutral) first: motion was "
                "blocked since this source last drove",
            ),
            ("stop", "pad"),
            ("at", 0.05),
            ("v", "pad", 0.4, 0.0, "taken"),
            ("at", 0.06),
        ],
        [(0.0, (0.0, 0.0)), (0.05, (0.4, 0.0))],
    ),
    (
        "a streaming source silent for longer than the deadman has let go: no neutral owed",
        [
            ("add", "panel", "foxglove"),
            ("v", "panel", 0.3, 0.0, "taken", {"duration": 0.02}),
            ("at", 0.01),
            ("block", "device", ("HARDWARE_ESTOP",)),
            ("at", 0.3),
            ("v", "panel", 0.3, 0.0, "blocked: blocked by HARDWARE_ESTOP"),
            ("block", "device", ()),
            ("at", 0.5),
            (
                "v",
                "panel",
                0.3,
                0.0,
                "neutral: send a zero (neutral) first: motion was "
                "blocked since this source last drove",
            ),
            ("at", 1.0),  # the button let go: the panel sends nothing for 0.5 s
            ("v", "panel", 0.2, 0.0, "taken"),
            ("at", 1.01),
        ],
        [(0.0, (0.3, 0.0)), (0.01, (0.0, 0.0)), (1.0, (0.2, 0.0))],
    ),
    (
        "one source drives at a time: a second page of the same priority is refused",
        [
            ("add", "web page", "web"),
            ("add", "web page", "web"),
            ("v", "web page", 0.3, 0.0, "taken"),
            ("at", 0.03),
            ("v", "web page 2", -0.3, 0.0, "driven: driven by web page"),
            ("v", "web page 2", 0.0, 0.0, "taken"),  # its neutral: ignored, not refused
            ("at", 0.06),
        ],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0))],
    ),
    (
        "a source of higher priority takes the lease; the one it took it from is refused",
        [
            ("add", "web page", "web"),
            ("add", "teleop", "teleop"),
            ("v", "web page", 0.3, 0.0, "taken"),
            ("at", 0.03),
            ("v", "teleop", -0.2, 0.0, "taken"),
            ("at", 0.04),
            ("v", "web page", 0.3, 0.0, "driven: driven by teleop"),
            ("at", 0.06),
        ],
        [(0.0, (0.3, 0.0)), (0.03, (-0.2, 0.0))],
    ),
    (
        "a source of lower priority is refused; the API below a page, above ROS 2",
        [
            ("add", "web page", "web"),
            ("add", "ros2 cmd_vel", "ros2"),
            ("v", "web page", 0.3, 0.0, "taken"),
            ("v", "api", 0.1, 0.0, "raised ('DRIVEN',)"),
            ("at", 0.6),
            ("v", "api", 0.1, 0.0, "taken", {"duration": 0.01}),
            ("v", "ros2 cmd_vel", 0.2, 0.0, "driven: driven by api"),
            ("at", 0.7),
        ],
        [(t, (0.3, 0.0)) for t in (0.0, 0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45)]
        + [(0.49, (0.0, 0.0)), (0.6, (0.1, 0.0)), (0.61, (0.0, 0.0))],
    ),
    (
        "taking over explicitly wins whatever the priority",
        [
            ("add", "teleop", "teleop"),
            ("add", "mqtt", "mqtt"),
            ("v", "teleop", 0.3, 0.0, "taken"),
            ("at", 0.03),
            ("v", "mqtt", 0.1, 0.0, "taken", {"take_over": True}),
            ("at", 0.04),
        ],
        [(0.0, (0.3, 0.0)), (0.03, (0.1, 0.0))],
    ),
    (
        "the lease lapses with its deadman",
        [
            ("add", "web page", "web"),
            ("add", "web page", "web"),
            ("v", "web page", 0.3, 0.0, "taken", {"duration": 0.03}),
            ("at", 0.06),
            ("v", "web page 2", -0.3, 0.0, "taken"),
            ("at", 0.07),
        ],
        [(0.0, (0.3, 0.0)), (0.03, (0.0, 0.0)), (0.06, (-0.3, 0.0))],
    ),
    (
        "a stop from any source acts, a read-only viewer's included, and ends the lease",
        [
            ("add", "web page", "web"),
            ("add", "viewer", "web"),
            ("add", "mqtt", "mqtt"),
            ("v", "web page", 0.3, 0.0, "taken"),
            ("at", 0.03),
            ("stop", "viewer"),
            ("at", 0.06),
            ("v", "mqtt", 0.1, 0.0, "taken"),
            ("at", 0.07),
        ],
        [(0.0, (0.3, 0.0)), (0.03, (0.0, 0.0)), (0.06, (0.1, 0.0))],
    ),
    (
        "a source that goes away while driving leaves the robot stopped",
        [
            ("add", "web page", "web"),
            ("v", "web page", 0.3, 0.0, "taken"),
            ("at", 0.03),
            ("close", "web page"),
            ("at", 0.3),
        ],
        [(0.0, (0.3, 0.0)), (0.03, (0.0, 0.0))],
    ),
    (
        "a source that goes away while another drives changes nothing",
        [
            ("add", "web page", "web"),
            ("add", "web page", "web"),
            ("v", "web page", 0.3, 0.0, "taken", {"duration": 0.06}),
            ("close", "web page 2"),
            ("at", 0.3),
        ],
        [(0.0, (0.3, 0.0)), (0.05, (0.3, 0.0)), (0.06, (0.0, 0.0))],
    ),
]


@pytest.mark.parametrize(("rule", "script", "wire"), ROWS, ids=[r[0] for r in ROWS])
def test_rule(rule: str, script: list[tuple[Any, ...]], wire: list[Any]) -> None:
    rig = Rig()
    for step in script:
        match step:
            case ("at", t):
                rig.advance(t)
            case ("add", name, kind):
                rig.add(name, kind)
            case ("v", name, a, b, expect):
                assert rig.v(name, a, b) == expect, step
            case ("v", name, a, b, expect, options):
                assert rig.v(name, a, b, **options) == expect, step
            case ("stop", name):
                rig.sources[name].stop()
            case ("close", name):
                rig.sources[name].close()
            case ("block", origin, reasons):
                rig.motion.set_blocks(origin, reasons)
            case _:
                raise AssertionError(f"bad step {step}")
    expected: list[Any] = [(pytest.approx(t), v) for t, v in wire]
    assert rig.writes == expected, rule


def test_a_flood_is_written_at_most_once_per_period() -> None:
    rig = Rig()
    rig.add("page", "web")
    n = 10_000
    for i in range(n):  # 10,000 commands in one second
        rig.advance(i / n)
        assert rig.v("page", 0.1 + (i % 7) / 100, 0.0) == "taken"
    rig.advance(1.02)
    moving = [t for t, v in rig.writes if t <= 1.0]
    assert len(moving) <= 1.0 / WRITE_PERIOD + 1, len(moving)
    assert len(moving) >= 1.0 / WRITE_PERIOD - 1, len(moving)
    gaps = [b - a for a, b in itertools.pairwise(moving)]
    assert min(gaps) >= WRITE_PERIOD - WRITE_JITTER - 1e-9
    # the newest is written: the last offered, at the end of the period it came in
    assert rig.writes[-1][1] == (0.1 + ((n - 1) % 7) / 100, 0.0)


def test_refusals_are_counted_per_source_and_reason_and_summarised() -> None:
    rig = Rig()
    rig.add("web page", "web")
    rig.add("web page", "web")
    rig.v("web page", 0.3)
    for _ in range(5):
        rig.v("web page 2", 0.2)
    rig.motion.set_blocks("device", ("FRONT_BUMPER",))
    rig.v("web page", 0.3)
    refused = rig.motion.arbiter.refused
    assert refused["web page 2", "driven"] == 5
    assert refused["web page", "blocked"] == 1
    # The first was reported at once; the rest wait for the next report a second on.
    assert rig.motion.refusals.pending == 5
    rig.advance(1.0)  # a second on, the next refusal brings the summary of all six
    rig.v("web page", 0.3)
    assert rig.motion.refusals.pending == 0
    assert refused["web page", "blocked"] == 2


def test_blocks_from_several_origins_clear_only_when_all_have() -> None:
    rig = Rig()
    rig.motion.set_blocks("device", ("HARDWARE_ESTOP",))
    rig.motion.set_blocks("software", ("SOFTWARE_ESTOP",))
    rig.motion.set_blocks("device", ())
    assert rig.motion.blocks == ("SOFTWARE_ESTOP",)
    assert rig.v("api", 0.3) == "raised ('SOFTWARE_ESTOP',)"
    rig.motion.set_blocks("software", ())
    assert not rig.motion.blocks
    assert rig.v("api", 0.3) == "taken"


def test_priorities_are_configurable_and_unknown_kinds_rank_last() -> None:
    rig = Rig()
    rig.add("planner", "planner")
    rig.add("mqtt", "mqtt")
    assert rig.v("mqtt", 0.1) == "taken"
    assert rig.v("planner", 0.2) == "driven: driven by mqtt"
    rig.motion.priorities["planner"] = 50
    assert rig.v("planner", 0.2) == "taken"
    assert rig.motion.driver == "planner"
    assert DEFAULT_PRIORITIES["teleop"] > DEFAULT_PRIORITIES["web"] > DEFAULT_PRIORITIES["ros2"]
    assert DEFAULT_PRIORITIES["ros2"] > DEFAULT_PRIORITIES["mqtt"]


def test_bad_values_raise_before_anything_is_written_and_a_closed_port_too() -> None:
    rig = Rig()
    rig.add("page", "web")
    with pytest.raises(ValueError, match="NaN"):
        rig.sources["page"].set_velocity(math.nan, 0.0)
    with pytest.raises(ValueError, match="age"):
        rig.sources["page"].set_velocity(0.1, 0.0, age=-1.0)
    with pytest.raises(TypeError):
        rig.sources["page"].set_velocity(0.1, 0.0, duration="1")  # type: ignore[arg-type]
    rig.open = False
    with pytest.raises(NotConnectedError):
        rig.sources["page"].set_velocity(0.1, 0.0)
    assert rig.writes == []
    assert rig.motion.arbiter.refused.total() == 0


def test_a_closed_source_cannot_drive_and_names_stay_unique() -> None:
    arbiter = Arbiter(clock=lambda: 0.0)
    a = arbiter.add("page", "web", streaming=True)
    b = arbiter.add("page", "web", streaming=True)
    assert (a.name, b.name) == ("page", "page 2")
    arbiter.remove(a)
    with pytest.raises(RuntimeError, match="closed"):
        arbiter.velocity(a, neutral=False)
    assert isinstance(arbiter.stale(b, "old"), Refusal)
    with pytest.raises(ValueError, match="name"):
        arbiter.add("", "web", streaming=True)
