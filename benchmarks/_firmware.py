"""A minimal protocol A firmware in its own process, for the latency benchmarks.

It owns the master side of a pty (fd passed by the parent as argv[1]) and takes
one-line commands on stdin, answering each with one JSON line on stdout:

* ``stream N PERIOD``: write N 0x81 frames, seq 0..N-1, one every PERIOD seconds;
  answer with the ``time.monotonic()`` taken just before each write.
* ``drives``: answer with the arrival times of the 0x02 frames received so far, and
  forget them.
* ``quit``.

It answers 0x07 (firmware version) at once, whenever it arrives. It is written as a
plain selector loop, not asyncio, so its own overhead stays small and steady;
``time.monotonic()`` is CLOCK_MONOTONIC, the same clock in both processes.
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
    CommandId,
    DockingState,
    DriveVelocity,
    FirmwareVersion,
    Telemetry,
    WheelSpeeds,
)

_TELEMETRY = Telemetry(24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, -0.2,
                       WheelSpeeds(0.2, 0.4, 0.2, 0.4))  # fmt: skip


class _Stream:
    """An ongoing ``stream`` command."""

    def __init__(self, n: int, period: float) -> None:
        self.encoder = ChassisEncoder(0)
        self.n = n
        self.period = period
        self.due = time.monotonic()
        self.times: list[float] = []


def main() -> None:
    master = int(sys.argv[1])
    os.set_blocking(master, False)
    sel = selectors.DefaultSelector()
    sel.register(master, selectors.EVENT_READ, "pty")
    sel.register(sys.stdin, selectors.EVENT_READ, "stdin")
    decoder = ChassisCommandDecoder()
    replies = ChassisEncoder()
    drives: list[float] = []
    stream: _Stream | None = None
    while True:
        timeout = None if stream is None else max(0.0, stream.due - time.monotonic())
        for key, _ in sel.select(timeout):
            if key.data == "pty":
                try:
                    data = os.read(master, 4096)
                except BlockingIOError:
                    continue
                now = time.monotonic()
                for cmd in decoder.feed(data, now):
                    if isinstance(cmd, DriveVelocity):
                        drives.append(now)
                    elif getattr(cmd, "id", None) is CommandId.FIRMWARE_VERSION:
                        os.write(master, replies.encode(FirmwareVersion(0x0103)))
                continue
            words = sys.stdin.readline().split()
            if not words or words[0] == "quit":
                return
            if words[0] == "stream":
                stream = _Stream(int(words[1]), float(words[2]))
            elif words[0] == "drives":
                print(json.dumps(drives), flush=True)
                drives = []
        if stream is not None and time.monotonic() >= stream.due:
            frame = stream.encoder.encode(_TELEMETRY)
            stream.times.append(time.monotonic())
            os.write(master, frame)
            stream.due += stream.period
            if len(stream.times) == stream.n:
                print(json.dumps(stream.times), flush=True)
                stream = None


if __name__ == "__main__":
    main()
