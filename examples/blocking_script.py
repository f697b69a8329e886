"""Drive a chassis from a plain script, without async: the blocking API.

    python examples/blocking_script.py [PORT]

PORT is a device path (/dev/ttyUSB0), a pty path or socket://host:port; without it the
example starts the built-in simulator. ``chassis_sdk.sync`` runs the event loop, the
watchdog and the deadman in a background thread: this script only waits on it, so a
``time.sleep`` (or a crash) here still stops the robot. Ctrl-C in any call stops it too.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path

from chassis_sdk import ChassisError, RequestTimeoutError, sync


def main(port: str | None) -> None:
    with contextlib.ExitStack() as stack:
        if port is None:
            port = stack.enter_context(sync.Simulator("chassis")).port
        robot = stack.enter_context(sync.Chassis(port))  # leaving the block writes zero
        robot.verify()  # the device on the port is a chassis

        print("firmware:", robot.get_firmware_version())
        print("geometry:", robot.get_chassis_info())

        # Forward for one second: ``duration`` holds the command, then zero.
        robot.set_velocity(0.3, 0.0, duration=1.0)
        start = time.monotonic()
        for t in robot.telemetry():  # a plain iterator; breaking out unsubscribes
            if t.seq % 10 == 0:
                print(f"{time.monotonic() - start:4.2f} s  v={t.linear:+.2f} m/s")
            if time.monotonic() - start > 1.3:
                break

        # Without ``duration`` the deadman ends the command 0.5 s after the last call,
        # even while this script sleeps: the background thread writes the zero.
        robot.set_velocity(0.2, 0.0)
        time.sleep(1.5)
        latest = robot.latest_telemetry
        assert latest is not None
        print(
            f"after sleeping 1.5 s: v={latest.linear:+.2f} m/s, command {robot.commanded_velocity}"
        )
        print("link:", robot.stats)


if __name__ == "__main__":
    try:
        main(sys.argv[1] if len(sys.argv) > 1 else None)
    except RequestTimeoutError as exc:
        print(f"{Path(sys.argv[0]).name}: {exc}", file=sys.stderr)
        sys.exit(2)
    except ChassisError as exc:
        print(f"{Path(sys.argv[0]).name}: {exc}", file=sys.stderr)
        sys.exit(1)
