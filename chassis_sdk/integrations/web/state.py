"""The state pages see: the newest reading of each stream the device's profile shows,
the odometry path, the events, and the state every page is sent, made once as JSON text.

What it shows comes by callback (``chassis_sdk.core.Notifier(device).listen``): each
reading is kept as it arrives, inside the device's read path, with no task per stream
and nothing awaited; a callback never raises into the read path (an error is counted
and logged, the first of each callback with its traceback).
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from ...core.charge import battery_fields
from ...core.device import Device
from ...core.notifier import Notifier
from ...core.plain import outbound
from .page import EVENTS_KEPT, Page

__all__ = ["StateModel"]

_log = logging.getLogger("chassis_sdk.integrations.web")

#: Odometry path points kept, and the least distance (m) between two of them.
_PATH_POINTS = 2000
_PATH_STEP = 0.02


class StateModel:
    """What the pages of one device see.

    Args:
        device: The device shown.
        streams: The streams its profile shows.
        on_error: Called for each error caught in a callback.
    """

    def __init__(
        self, device: Device[Any, Any], streams: Iterable[str], on_error: Callable[[], None]
    ) -> None:
        self.device = device
        self._streams = tuple(streams)
        self._on_error = on_error
        #: The LED's and buzzer's state as the device last reported it (the reply to a
        #: page's switch), by name; absent while not known.
        self.outputs: dict[str, bool] = {}
        #: The pages open: each is given every event as it comes.
        self.pages: set[Page] = set()
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS_KEPT)
        self.path: deque[tuple[float, float]] = deque(maxlen=_PATH_POINTS)
        self.latest: dict[str, Any] = {}
        self._notifier: Notifier | None = None

    def listen(self) -> None:
        """Listen to the device's streams and events (until `close`)."""
        notifier = Notifier(self.device)
        names = notifier.stream_names
        for stream in self._streams:
            if stream not in names:  # a profile naming a stream its device lacks
                self._on_error()
                _log.error("web: %s has no %s stream to show", self.device.device_name, stream)
                continue
            keep = self._keep_odometry if stream == "odometry" else self._keeper(stream)
            notifier.listen(stream, self._guard(f"the {stream} stream", keep))
        notifier.listen("events", self._guard("the events", self._keep_event))
        self._notifier = notifier

    def close(self) -> None:
        """Keep no more readings."""
        if self._notifier is not None:
            self._notifier.close()

    def _guard(self, what: str, callback: Callable[[Any], None]) -> Callable[[Any], None]:
        """``callback``, never raising into the device's read path."""
        failed = 0

        def guarded(item: Any) -> None:
            nonlocal failed
            try:
                callback(item)
            except Exception:
                self._on_error()
                failed += 1
                if failed == 1:
                    _log.exception("web: %s failed; the dashboard goes on", what)

        return guarded

    def _keeper(self, stream: str) -> Callable[[Any], None]:
        latest = self.latest

        def keep(reading: Any) -> None:
            latest[stream] = reading

        return keep

    def _keep_odometry(self, reading: Any) -> None:
        """Keep the newest odometry and the path (a point every `_PATH_STEP`)."""
        self.latest["odometry"] = reading
        x, y = float(reading.x), float(reading.y)
        path = self.path
        if not path or math.dist(path[-1], (x, y)) >= _PATH_STEP:
            path.append((round(x, 4), round(y, 4)))

    def _keep_event(self, event: Any) -> None:
        """Keep an event for the pages that open later and queue it for every open one."""
        body = outbound(event)
        body["time"] = body["timestamp"]  # wall time (the page's name for it)
        body["text"] = str(event)
        self.events.append(body)
        for page in self.pages:
            page.events.append(body)

    def snapshot(self, *, refused: int, commands: int) -> str:
        """The state every page is sent, as JSON text (a non-finite reading as ``null``:
        JSON has none)."""
        device = self.device
        latest = {name: outbound(reading) for name, reading in self.latest.items()}
        commanded = device.commanded_velocity
        estop = any("ESTOP" in block for block in device.motion.blocks)
        telemetry = self.latest.get("telemetry")
        if telemetry is not None and getattr(telemetry, "emergency_stopped", False):
            estop = True
        body = {
            "type": "state",
            "time": time.time(),
            "link": {"state": device.connection_state.name, "age": device.last_frame_age},
            "commanded": list(commanded) if commanded is not None else None,
            "written": list(device.written_velocity),
            "streams": latest,
            "odometry": latest.get("odometry"),
            "battery": self._charge(),
            "estop": estop,
            # The flags that stop the wheels (faults, e-stops): the page shows these as
            # alarms, and the rest (REMOTE_OFFLINE under host control) as information.
            "faults": list(device.motion_blocked()),
            "outputs": dict(self.outputs),
            "refused": refused,
            "commands": commands,
            "clients": len(self.pages),
        }
        try:
            return json.dumps(body, default=str, allow_nan=False)
        except ValueError:
            return json.dumps(_finite_only(body), default=str)

    def _charge(self) -> dict[str, Any] | None:
        """The state of charge (``battery=BatteryModel(...)``): ``{"percentage": 63.2 |
        None, "level": "OK" | "LOW" | "CRITICAL" | None}``, ``None`` while not known;
        ``None`` itself when the device has no model."""
        if self.device.battery_model is None:
            return None
        fields = battery_fields(self.device)
        return {
            "percentage": fields.get("battery_percentage"),
            "level": fields.get("battery_level"),
        }


def _finite_only(value: Any) -> Any:
    """``value`` with every non-finite float as ``None``."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite_only(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite_only(v) for v in value]
    return value
