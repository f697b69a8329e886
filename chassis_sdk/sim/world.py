"""The simulators' world: walls the simulated robot can run into. Pure geometry: no
clock, no I/O, no randomness.

A `World` is a set of wall segments in the frame of the robot's *true* pose (metres;
the robot starts at the origin, heading 0, facing +x). The firmware models ask it one
thing (`World.sweep`): moving the robot's box from one pose to the next, where does
it stop, and where does it touch? They then latch a bumper, stop the wheels or show
the impact on the IMU as the device would.

Why a sweep and not a check of the end pose: a step of the model can be long (up to
a second when its loop is held up), and a box checked only at the ends of a long step
would pass through a thin wall. The sweep checks poses at most `SWEEP_STEP` apart
along the way, then bisects between the last free pose and the first blocked one, so
the robot stops touching the wall (within a micrometre), never inside it.

The firmware models do not import this module (the simulators sit above the devices):
each names what it needs of a world in a small protocol (``Obstacles``) that `World`
satisfies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..core.validation import check_real

__all__ = ["SWEEP_STEP", "Pose", "Wall", "World"]

#: A pose: x, y (m) and heading (rad), in the world's frame.
Pose = tuple[float, float, float]
#: The farthest (m) any point of the box moves between two poses a sweep checks.
SWEEP_STEP = 0.02
#: Bisections between the last free pose and the first blocked one (2⁻¹⁸ of a step).
_BISECTIONS = 18

_EXPECTED = (
    "expected arena:WxH (a W by H metre rectangle centred on the start pose, e.g. "
    "arena:4x3) or wall:X1,Y1,X2,Y2 (a segment, metres), several joined by '+'"
)


@dataclass(frozen=True, slots=True)
class Wall:
    """A wall: the segment from ``(x1, y1)`` to ``(x2, y2)`` (metres), of no thickness."""

    x1: float
    y1: float
    x2: float
    y2: float

    def __post_init__(self) -> None:
        for name in ("x1", "y1", "x2", "y2"):
            check_real(getattr(self, name), name)


@dataclass(frozen=True, slots=True)
class World:
    """Walls for a simulated robot to run into.

    Example:
        ```python
        world = World.arena(4, 3)  # or World.parse("arena:4x3+wall:1,-1.5,1,0")
        async with ChassisSimulator(world=world) as sim, Chassis(sim.port) as robot:
            ...
            print(sim.firmware.true_pose, robot.motion_blocked())
        ```

    Attributes:
        walls: The wall segments, in the frame of the robot's start pose.
    """

    walls: tuple[Wall, ...] = ()

    @classmethod
    def arena(cls, width: float, height: float) -> World:
        """A closed ``width`` × ``height`` rectangle (metres, ``width`` along the start
        heading) centred on the start pose.

        Raises:
            ValueError: A side is not a finite number above 0.
        """
        w = check_real(width, "width", low=0, low_open=True, unit="m") / 2
        h = check_real(height, "height", low=0, low_open=True, unit="m") / 2
        corners = [(-w, -h), (w, -h), (w, h), (-w, h)]
        after = corners[1:] + corners[:1]
        return cls(tuple(Wall(*a, *b) for a, b in zip(corners, after, strict=True)))

    @classmethod
    def parse(cls, spec: str) -> World:
        """A world from its command-line form: ``arena:WxH`` or ``wall:X1,Y1,X2,Y2``,
        several joined by ``+`` (``arena:4x3+wall:1,-1.5,1,0``).

        Raises:
            ValueError: ``spec`` is not of that form (the message says what is expected).
        """
        walls: list[Wall] = []
        for part in spec.split("+"):
            kind, _, value = part.strip().partition(":")
            try:
                if kind == "arena":
                    width, sep, height = value.lower().partition("x")
                    if not sep:
                        raise ValueError("no 'x' between width and height")
                    walls += cls.arena(float(width), float(height)).walls
                elif kind == "wall":
                    numbers = [float(n) for n in value.split(",")]
                    if len(numbers) != 4:
                        raise ValueError(f"{len(numbers)} numbers, not 4")
                    walls.append(Wall(*numbers))
                else:
                    raise ValueError(f"unknown kind {kind!r}")
            except (TypeError, ValueError) as exc:
                raise ValueError(f"bad world {spec!r} ({exc}): {_EXPECTED}") from None
        return cls(tuple(walls))

    def contact(self, pose: Pose, length: float, width: float) -> tuple[float, float] | None:
        """Where a ``length`` × ``width`` box centred on ``pose`` (``length`` along its
        heading) overlaps a wall: the middle of the overlap in the box's own frame
        (x forward, y left), or ``None`` if it is free. Touching counts."""
        x, y, heading = pose
        cos, sin = math.cos(heading), math.sin(heading)
        half_l, half_w = length / 2, width / 2
        best: tuple[float, float] | None = None
        for wall in self.walls:
            # The wall in the box's frame, clipped to the box (Liang-Barsky).
            ax, ay = wall.x1 - x, wall.y1 - y
            bx, by = wall.x2 - x, wall.y2 - y
            p0 = (ax * cos + ay * sin, -ax * sin + ay * cos)
            p1 = (bx * cos + by * sin, -bx * sin + by * cos)
            clipped = _clip(p0, p1, half_l, half_w)
            if clipped is not None and (best is None or abs(clipped[0]) > abs(best[0])):
                best = clipped  # the deepest towards an end decides front or rear
        return best

    def collides(self, pose: Pose, length: float, width: float) -> bool:
        """True if a ``length`` × ``width`` box centred on ``pose`` touches a wall."""
        return self.contact(pose, length, width) is not None

    def sweep(
        self, start: Pose, end: Pose, length: float, width: float
    ) -> tuple[Pose, tuple[float, float] | None]:
        """Move the box from ``start`` (free) towards ``end`` in a straight line (x, y
        and heading together): the pose where it stops, and where it touched a wall
        (as `contact` tells, at the first blocked pose) or ``None`` if nothing was in
        the way (then the pose is ``end``).

        A ``start`` that already touches a wall stays where it is (a contact is
        reported).
        """
        if not self.walls:
            return end, None
        first = self.contact(start, length, width)
        if first is not None:
            return start, first
        dx, dy, dh = end[0] - start[0], end[1] - start[1], end[2] - start[2]
        reach = math.hypot(dx, dy) + abs(dh) * math.hypot(length, width) / 2
        steps = max(1, math.ceil(reach / SWEEP_STEP))

        def at(t: float) -> Pose:
            return (start[0] + dx * t, start[1] + dy * t, start[2] + dh * t)

        free = 0.0
        for i in range(1, steps + 1):
            blocked = i / steps
            hit = self.contact(at(blocked), length, width)
            if hit is None:
                free = blocked
                continue
            for _ in range(_BISECTIONS):
                middle = (free + blocked) / 2
                found = self.contact(at(middle), length, width)
                if found is None:
                    free = middle
                else:
                    blocked, hit = middle, found
            return at(free), hit
        return end, None


def _clip(
    p0: tuple[float, float], p1: tuple[float, float], half_l: float, half_w: float
) -> tuple[float, float] | None:
    """The middle of the part of segment p0-p1 inside the box |x| <= half_l,
    |y| <= half_w, or ``None`` if no part is."""
    t0, t1 = 0.0, 1.0
    dx, dy = p1[0] - p0[0], p1[1] - p0[1]
    for p, q in (
        (-dx, p0[0] + half_l),
        (dx, half_l - p0[0]),
        (-dy, p0[1] + half_w),
        (dy, half_w - p0[1]),
    ):
        if p == 0:
            if q < 0:
                return None  # parallel to this edge and outside it
            continue
        r = q / p
        if p < 0:
            t0 = max(t0, r)
        else:
            t1 = min(t1, r)
        if t0 > t1:
            return None
    middle = (t0 + t1) / 2
    return (p0[0] + dx * middle, p0[1] + dy * middle)
