"""A protocol A firmware in its own process, for the reflex benchmark: 50 Hz telemetry
with a bumper hit in it every few frames.

It owns the master side of a pty (fd passed by the parent as argv[1]) and takes
one-line commands on stdin, answering each with one JSON line on stdout:

* ``run N PERIOD EVERY``: write N 0x81 frames, one every PERIOD seconds, the front
  bumper bit set in every EVERY-th (from the third; 0: never); answer with
  ``{"hazards": [time of each hazard frame's write], "drives": [[arrival, mm/s], ...]}``
  (every 0x02 frame that arrived meanwhile);
* ``quit``.

It is a plain selector loop, so its own overhead stays small and steady; both processes
read ``time.monotonic()`` (CLOCK_MONOTONIC, one clock per machine).
"""

from __future__ import annotations

import json
import os
import selectors
import sys
import time

from chassis_sdk.protocol import (
    ChassisCommandDecoder,
    ChassisEncoder,
    ChassisStatus,
    DockingState,
    DriveVelocity,
    Telemetry,
    WheelSpeeds,
)

_WHEELS = WheelSpeeds(0.3, 0.3, 0.3, 0.3)
_NORMAL = Telemetry(24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, 0.0, _WHEELS)
_HIT = Telemetry(
    24.6,
    ChassisStatus.REMOTE_OFFLINE | ChassisStatus.FRONT_BUMPER,
    DockingState.SEARCHING,
    0.3,
    0.0,
    _WHEELS,
)


def main() -> None:
    master = int(sys.argv[1])
    os.set_blocking(master, False)
    sel = selectors.DefaultSelector()
    sel.register(master, selectors.EVENT_READ, "pty")
    sel.register(sys.stdin, selectors.EVENT_READ, "stdin")
    decoder = ChassisCommandDecoder()
    encoder = ChassisEncoder(0)
    drives: list[tuple[float, int]] = []
    hazards: list[float] = []
    left = 0
    period = every = 0.0
    due = 0.0
    sent = 0
    while True:
        timeout = None if left == 0 else max(0.0, due - time.monotonic())
        for key, _ in sel.select(timeout):
            if key.data == "pty":
                try:
                    data = os.read(master, 4096)
                except BlockingIOError:
                    continue
                now = time.monotonic()
                for cmd in decoder.feed(data, now):
                    if isinstance(cmd, DriveVelocity):
                        drives.append((now, cmd.linear_mm))
                continue
            words = sys.stdin.readline().split()
            if not words or words[0] == "quit":
                return
            if words[0] == "run":
                left, period, every = int(words[1]), float(words[2]), int(words[3])
                due, sent = time.monotonic(), 0
                drives, hazards = [], []
        if left and time.monotonic() >= due:
            hit = every > 0 and sent % every == every - 1 and sent >= 2
            frame = encoder.encode(_HIT if hit else _NORMAL)
            if hit:
                hazards.append(time.monotonic())
            os.write(master, frame)
            sent += 1
            left -= 1
            due += period
            if left == 0:
                time.sleep(0.1)  # the last replies arrive
                try:
                    data = os.read(master, 65536)
                except BlockingIOError:
                    data = b""
                now = time.monotonic()
                drives += [
                    (now, c.linear_mm)
                    for c in decoder.feed(data, now)
                    if isinstance(c, DriveVelocity)
                ]
                print(json.dumps({"hazards": hazards, "drives": drives}), flush=True)


if __name__ == "__main__":
    main()
