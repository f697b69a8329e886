"""A bridge's goals: ``request/move``, ``request/turn`` and ``request/goto`` start one
(the device's ``drive_distance``, ``rotate``, ``go_to``), its progress goes out on
``goal``, its end is the request's response, and ``cmd/cancel`` ends it at once.

One goal at a time per robot: a newer one replaces the running one (whose response
says so). Each runs in a task of its own, so the request workers stay free; closing the
bridge cancels it (the robot stops).

Payloads (JSON objects; SI units, radians, as the API):

======== ====================================================================
request  fields
======== ====================================================================
move     ``distance`` (m), ``speed`` (m/s), ``tolerance`` (m), ``timeout`` (s)
turn     ``angle`` (rad), ``rate`` (rad/s), ``tolerance`` (rad), ``timeout`` (s)
goto     ``x``, ``y`` (m), ``heading`` (rad), ``speed``, ``tolerance``, ``timeout``
======== ====================================================================

Only the first field of each (the second and third of ``goto``) is required.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
from collections.abc import Awaitable, Callable
from typing import Any, Final

import anyio

from ...core.motion import MoveResult
from ...errors import ChassisError, MovePreemptedError, MoveTimeoutError
from ..inbound import CommandError, command_number, command_object
from .context import CommandContext

__all__ = ["GOALS", "PROGRESS_PERIOD", "RemoteGoals"]

#: The goal requests, and their fields: (name, required).
GOALS: Final[dict[str, tuple[tuple[str, bool], ...]]] = {
    "move": (("distance", True), ("speed", False), ("tolerance", False), ("timeout", False)),
    "turn": (("angle", True), ("rate", False), ("tolerance", False), ("timeout", False)),
    "goto": (
        ("x", True),
        ("y", True),
        ("heading", False),
        ("speed", False),
        ("tolerance", False),
        ("timeout", False),
    ),
}
#: Seconds between two progress messages on ``goal``.
PROGRESS_PERIOD: Final = 0.2


def result_body(result: MoveResult) -> dict[str, Any]:
    """A `MoveResult` as JSON (NaN as ``null``)."""
    pose = result.pose

    def num(v: float) -> float | None:
        return v if math.isfinite(v) else None

    return {
        "ended": result.ended,
        "error": num(result.error),
        "heading_error": num(result.heading_error),
        "duration": round(result.duration, 3),
        "pose": None if pose is None else {"x": pose.x, "y": pose.y, "heading": pose.heading},
    }


class RemoteGoals:
    """The goals a bridge runs for its senders (see the module docstring)."""

    def __init__(self, context: CommandContext) -> None:
        self._ctx = context
        self._tasks: set[asyncio.Task[None]] = set()
        #: Goals started, and cancelled by ``cmd/cancel``.
        self.started = 0
        self.cancelled = 0

    def parse(self, name: str, payload: bytes | bytearray | str | Any) -> dict[str, float]:
        """The goal's arguments from its payload.

        Raises:
            CommandError: Not a JSON object, a required field missing, a field not a
                finite number, or one not known.
        """
        body = command_object(payload)
        fields = dict(GOALS[name])
        unknown = sorted(set(body) - set(fields))
        if unknown:
            raise CommandError(
                f"{name}: unknown field {unknown[0][:40]!r}; known: {', '.join(fields)}"
            )
        args: dict[str, float] = {}
        for field, required in fields.items():
            if field in body:
                args[field] = command_number(body, field)
            elif required:
                raise CommandError(f"{name} needs {field!r}")
        return args

    def start(
        self, name: str, args: dict[str, float], answer: Callable[[dict[str, Any]], Awaitable[None]]
    ) -> None:
        """Start the goal ``name`` (``move``...); ``answer`` publishes its response. A
        goal still running is replaced (cancelled: the new one starts from rest)."""
        self.started += 1
        self.cancel()
        task = asyncio.get_running_loop().create_task(
            self._run(name, args, answer), name=f"mqtt goal {name}"
        )
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def cancel(self) -> bool:
        """``cmd/cancel``: end the running goal now (the robot stops). False if none."""
        live = [t for t in self._tasks if not t.done()]
        for task in live:
            task.cancel()
        self.cancelled += len(live)
        return bool(live)

    def close(self) -> None:
        """The bridge ends (or another took the robot id over): cancel its goals."""
        self.cancel()

    async def _run(
        self, name: str, args: dict[str, float], answer: Callable[[dict[str, Any]], Awaitable[None]]
    ) -> None:
        device: Any = self._ctx.device
        body: dict[str, Any]
        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._progress, name)
                try:
                    result = await _call(device, name, args)
                finally:
                    tg.cancel_scope.cancel()
            body = {"result": result_body(result)}
            state = "done"
        except asyncio.CancelledError:
            body, state = {"error": "cancelled"}, "cancelled"
        except (MoveTimeoutError, MovePreemptedError) as exc:
            body = {"error": str(exc), "result": result_body(exc.result)}
            state = exc.result.ended
        except (ChassisError, ValueError, TypeError) as exc:
            body, state = {"error": str(exc)}, "failed"
        with contextlib.suppress(Exception):  # the broker may be gone: nothing to tell
            await self._publish_state(name, state)
            await answer(body)

    async def _progress(self, name: str) -> None:
        device: Any = self._ctx.device
        last = -math.inf
        async with device.odometry() as samples:
            async for o in samples:
                now = o.timestamp
                if now - last < PROGRESS_PERIOD:
                    continue
                last = now
                pose = {"x": o.x, "y": o.y, "heading": o.heading}
                await self._send({"goal": name, "state": "active", "pose": pose})

    async def _publish_state(self, name: str, state: str) -> None:
        await self._send({"goal": name, "state": state})

    async def _send(self, body: dict[str, Any]) -> None:
        ctx = self._ctx
        await ctx.client.publish(f"{ctx.topic}/goal", json.dumps(body).encode(), qos=0)


async def _call(device: Any, name: str, a: dict[str, float]) -> MoveResult:
    # Its goals rank as the bridge's velocities do (kind "mqtt"), not above ROS 2.
    options: dict[str, Any] = {k: a[k] for k in ("tolerance", "timeout") if k in a}
    options["kind"] = "mqtt"
    if name == "move":
        result: MoveResult = await device.drive_distance(a["distance"], a.get("speed"), **options)
    elif name == "turn":
        result = await device.rotate(a["angle"], a.get("rate"), **options)
    else:
        result = await device.go_to(
            a["x"], a["y"], a.get("heading"), speed=a.get("speed"), **options
        )
    return result
