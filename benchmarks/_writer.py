"""N chassis that only stream, in their own process (for benchmarks/scaling.py).

    python benchmarks/_writer.py N SECONDS

Opens N pseudo-terminals and prints a JSON line ``{"ports": [...], "t0": T,
"period": 0.02}``; from ``t0`` (a second later, CLOCK_MONOTONIC) writes one 28-byte
0x81 frame to each every 20 ms, chassis i offset by ``i * period / N``, frame k of
chassis i due at ``t0 + i * period / N + k * period``. After SECONDS it prints
``{"late_p99_ms": ..., "frames": ...}`` (how late its own writes were) and exits. A plain
sleep-and-write loop over precomputed frames, so it costs a few microseconds a frame.
"""

from __future__ import annotations

import json
import os
import sys
import time
import tty

from chassis_sdk.protocol import (
    ChassisEncoder,
    ChassisStatus,
    DockingState,
    Telemetry,
    WheelSpeeds,
)

PERIOD = 0.02
_TELEMETRY = Telemetry(24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, -0.2,
                       WheelSpeeds(0.2, 0.4, 0.2, 0.4))  # fmt: skip


def main(n: int, seconds: float) -> None:
    masters, ports = [], []
    for _ in range(n):
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        masters.append(master)
        ports.append(os.ttyname(slave))
    encoder = ChassisEncoder(0)
    frames = [encoder.encode(_TELEMETRY) for _ in range(65536)]  # seq 0..65535
    t0 = time.monotonic() + 1.0
    print(json.dumps({"ports": ports, "t0": t0, "period": PERIOD}), flush=True)
    late: list[float] = []
    written = 0
    end = t0 + seconds
    k = 0
    while (tick := t0 + k * PERIOD) < end:
        for i, master in enumerate(masters):
            due = tick + i * PERIOD / n
            delay = due - time.monotonic()
            if delay > 0.0002:  # sleep only when it is worth a wake-up
                time.sleep(delay)
            try:
                os.write(master, frames[k % 65536])
                written += 1
            except BlockingIOError:
                pass  # the reader is not keeping up: counted as lost on its side
            late.append(max(0.0, time.monotonic() - due))
        k += 1
    late.sort()
    p99 = late[int(len(late) * 0.99)] * 1e3 if late else 0.0
    print(json.dumps({"late_p99_ms": p99, "late_share": len(late) / max(written, 1),
                      "frames": written}), flush=True)  # fmt: skip
    sys.stdin.read()  # keep the ptys open until the reader is done
    for master in masters:
        os.close(master)


if __name__ == "__main__":
    main(int(sys.argv[1]), float(sys.argv[2]))
