"""``chassis-sdk teleop``: drive from a terminal's keys, or a gamepad on the robot
computer, with a status line.

The keys' meaning and timing are `chassis_sdk.teleop.keys.KeyTeleop` (sans-IO);
this is the I/O around it: the terminal in cbreak mode with signals and flow control
off (Ctrl-C, Ctrl-Z and Ctrl-S arrive as bytes: Ctrl-C quits, the others are ignored,
so the process is never suspended with the robot moving), stdin read from the event
loop, the device opened by `driven` (reconnecting,
within the limits, under the deadman), and a loop that sleeps until the next thing due:
a key, the held key's release deadline, the pad's, a refresh of the command (20 Hz) or
of the status line (10 Hz).

Every way out writes zero: ``q``/Ctrl-C (exit 0), ``--seconds``, the terminal gone
(end of file or EIO on stdin: at once, exit 1), SIGHUP or SIGTERM (through
[`chassis_sdk.run`][chassis_sdk.run]), an exception. The terminal's mode is restored on every one.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import sys
import termios
import time
import tty
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import anyio

from ..devices import DeviceProfile
from ..errors import ChassisError, NotConnectedError
from ..teleop.gamepad import JoyMapping, Pad
from ..teleop.keys import KEY_HELP, Effect, Key, KeyTeleop
from .common import driven, out

if TYPE_CHECKING:
    from ..core.motion import MotionSource

__all__ = ["REFRESH", "drive_from_terminal", "teleop"]

#: How often a held command is written again (s): well inside the deadman.
REFRESH = 0.05
#: How often the status line is redrawn (s).
STATUS_EVERY = 0.1
#: The terminal's width when it cannot be asked (columns).
FALLBACK_COLUMNS = 80


def _columns() -> int:
    """The width of the terminal on stdout now (it may have been resized)."""
    try:
        return os.get_terminal_size(sys.stdout.fileno()).columns or FALLBACK_COLUMNS
    except (OSError, ValueError):
        return FALLBACK_COLUMNS


def _write_or_drop(data: bytes) -> None:
    """Write ``data`` to the terminal without ever blocking the loop: over a stalled
    SSH link the terminal's buffer fills, and a blocking write would freeze the loop
    (no resend, no deadman). A status line that does not fit now is dropped (the next
    one is complete); the descriptor's blocking mode is put back as it was."""
    sys.stdout.flush()
    fd = sys.stdout.fileno()
    blocking = os.get_blocking(fd)
    try:
        os.set_blocking(fd, False)
        with contextlib.suppress(BlockingIOError):
            os.write(fd, data)
    finally:
        os.set_blocking(fd, blocking)


@contextlib.contextmanager
def cbreak(fd: int) -> Iterator[None]:
    """The terminal ``fd`` in cbreak mode, without signal keys, flow control or echo,
    for the block; its mode is restored however the block ends (a terminal already
    gone cannot be restored, and is not)."""
    saved = termios.tcgetattr(fd)
    try:
        tty.setcbreak(fd, termios.TCSANOW)
        mode = termios.tcgetattr(fd)
        mode[tty.LFLAG] &= ~(termios.ISIG | termios.ECHO | termios.ICANON)
        mode[tty.IFLAG] &= ~(termios.IXON | termios.ICRNL)
        termios.tcsetattr(fd, termios.TCSANOW, mode)
        yield
    finally:
        with contextlib.suppress(OSError, termios.error):
            termios.tcsetattr(fd, termios.TCSAFLUSH, saved)


class Terminal:
    """stdin's bytes from the event loop, and the status line on stdout."""

    def __init__(self, fd: int, wake: asyncio.Event) -> None:
        self.fd = fd
        self.chunks: list[tuple[bytes, float]] = []
        #: Set when the terminal is gone: why.
        self.gone: str | None = None
        self._wake = wake
        self._loop = asyncio.get_running_loop()
        self._loop.add_reader(fd, self._readable)
        self._tty = sys.stdout.isatty()
        self._shown = ""

    def _readable(self) -> None:
        try:
            data = os.read(self.fd, 1024)
        except BlockingIOError:
            return
        except OSError as exc:  # EIO: the terminal hung up
            data = b""
            self.gone = f"the terminal went away ({exc.strerror})"
        if not data:
            self.gone = self.gone or "the terminal went away (end of input)"
            self.close()
        else:
            self.chunks.append((data, time.monotonic()))
        self._wake.set()

    def take(self) -> list[tuple[bytes, float]]:
        """The chunks read since the last call, each with its arrival time."""
        chunks, self.chunks = self.chunks, []
        return chunks

    def status(self, line: str) -> None:
        """Show ``line`` as the status line (in place on a terminal, cut to its width
        less one column, so it never wraps; a plain line when stdout is piped and the
        line changed)."""
        if self._tty:
            line = line[: max(_columns() - 1, 1)]
        if line == self._shown:
            return
        self._shown = line
        try:
            if self._tty:
                _write_or_drop(f"\r{line}\033[K".encode())
            else:
                out(line)
        except OSError as exc:
            self.gone = self.gone or f"the terminal went away ({exc.strerror})"

    def end_status(self) -> None:
        """Leave the status line on screen and go to the next line."""
        if self._tty and self._shown:
            with contextlib.suppress(OSError):
                sys.stdout.write("\r\n")
                sys.stdout.flush()

    def close(self) -> None:
        """Stop reading stdin."""
        with contextlib.suppress(ValueError, OSError):
            self._loop.remove_reader(self.fd)


def _mapping(args: argparse.Namespace) -> JoyMapping:
    scale_lin = args.joy_scale_linear
    scale_ang = args.joy_scale_angular
    return JoyMapping(
        scale_linear=args.max_linear if scale_lin is None else scale_lin,
        scale_angular=args.max_angular if scale_ang is None else scale_ang,
        enable_button=args.enable_button,
        linear_axis=args.linear_axis,
        angular_axis=args.angular_axis,
        deadzone=args.joy_deadzone,
        timeout=args.joy_timeout,
    )


async def teleop(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Drive ``device`` on ``port`` from the terminal (and ``args.joystick``) until
    ``q``, Ctrl-C, ``--seconds`` or a signal; zero is written on every way out.

    Raises:
        ChassisError: The terminal went away, or the pad was unplugged (the robot is
            stopped first), or the pad cannot be used (before the device opens).
    """
    try:
        keys = KeyTeleop(
            max_linear=args.max_linear,
            max_angular=args.max_angular,
            key_timeout=args.key_timeout,
            speed=args.speed,
        )
        mapping = _mapping(args) if args.joystick else None
    except ValueError as exc:
        raise ChassisError(str(exc)) from None
    pad = None if mapping is None else Pad(args.joystick, mapping, time.monotonic())
    fd = sys.stdin.fileno()
    try:
        with cbreak(fd):
            async with driven(device, port, args) as dev:
                await drive_from_terminal(dev, keys, pad, fd, args)
    finally:
        if pad is not None:
            pad.close()


async def drive_from_terminal(
    dev: Any, keys: KeyTeleop, pad: Pad | None, fd: int, args: argparse.Namespace
) -> None:
    """Drive ``dev`` from the terminal on ``fd`` (already in cbreak or raw mode) and
    ``pad`` until quit, the terminal or the pad goes away, or ``args.seconds`` pass: the
    keys through ``keys``, both through the device's motion core as one source of kind
    ``"teleop"`` (``"gamepad"`` with a pad). The robot is stopped when it returns."""
    wake = asyncio.Event()
    term = Terminal(fd, wake)
    if pad is not None:
        pad.start(time.monotonic, wake.set)
    out(KEY_HELP)
    out("status: commanded and measured v (m/s), w (rad/s), speed scale, link")
    if pad is not None:
        out(f"gamepad {pad.name} ({pad.path}): hold the enable button and steer")
    note = ""
    sent: tuple[float, float] | None = None  # the command written, None: stopped
    refused = False  # the motion core refused the last one: a stop is owed at release
    next_refresh = next_status = 0.0
    end = None if args.seconds is None else time.monotonic() + args.seconds
    has_estop = hasattr(dev, "emergency_stop")
    # The terminal's operator outranks a dashboard, ROS 2 and MQTT (the motion core's
    # priorities); with a gamepad the kind is the pad's (the same rank by default).
    source = dev.motion.source("teleop", kind="teleop" if pad is None else "gamepad")
    try:
        while True:
            now = time.monotonic()
            effects: list[Effect] = []
            for data, at in term.take():  # each at its own arrival time
                effects.extend(keys.feed(data, at))
            effects.extend(keys.poll(now))
            for effect in effects:
                if effect is Effect.QUIT:
                    break
                if effect is Effect.STOP:
                    _stop(source)
                    sent, refused = None, False
                elif effect is Effect.ESTOP:
                    if has_estop:
                        await _guard(dev.emergency_stop())
                        note = "E-STOP: r releases"
                    else:
                        _stop(source)
                        note = f"no e-stop on a {dev.device_name}: stopped; r resumes"
                    sent, refused = None, False
                elif effect is Effect.RELEASE:
                    if has_estop:
                        await _guard(dev.release_emergency_stop())
                    note = ""
            if keys.quit:
                break
            if term.gone is not None:
                _stop(source)
                raise ChassisError(f"{term.gone}; the robot is stopped")
            if pad is not None and pad.gone is not None:
                _stop(source)
                raise ChassisError(f"{pad.gone}; the robot is stopped")
            target = _target(keys, pad, now)
            if target is None:
                if sent is not None or refused:  # let go: the neutral the core asks for
                    _stop(source)
                    sent, refused = None, False
            elif target != sent or now >= next_refresh:
                try:
                    refusal = source.set_velocity(*target)
                except NotConnectedError:
                    keys.key(Key.STOP, now)  # after a reconnect, a fresh press drives
                    refusal, target = None, None
                if refusal is not None:  # blocked, another source drives, neutral owed
                    note, refused, target = f"refused: {refusal.detail}", True, None
                elif refused or note.startswith("refused"):
                    note, refused = "", False
                sent = target
                next_refresh = now + REFRESH
            if now >= next_status or effects:
                term.status(_status_line(dev, keys, pad, sent, note, now))
                next_status = now + STATUS_EVERY
            if end is not None and now >= end:
                break
            due = [next_status, *([next_refresh] if sent is not None else [])]
            pad_due = None if pad is None else pad.state.deadline
            due += [d for d in (keys.deadline, pad_due, end) if d is not None]
            wake.clear()
            if term.chunks or term.gone or (pad is not None and pad.gone):
                continue
            with anyio.move_on_after(max(0.0, min(due) - time.monotonic())):
                await wake.wait()
        _stop(source)
        term.status(_status_line(dev, keys, pad, None, note, time.monotonic()))
    finally:
        source.close()
        term.close()
        term.end_status()
    out("stopped")


async def _guard(request: Any) -> None:
    """Await a command, a link down reported as such rather than ending teleop."""
    with contextlib.suppress(NotConnectedError):
        await request


def _stop(source: MotionSource) -> None:
    with contextlib.suppress(NotConnectedError):
        source.stop()


def _target(keys: KeyTeleop, pad: Pad | None, now: float) -> tuple[float, float] | None:
    """What should be driven now: the enabled pad's command, else the held key's;
    ``None``: nothing (stopped)."""
    if keys.estopped:
        return None
    if pad is not None:
        command = pad.state.velocity(now)
        if command is not None:
            return command
    return keys.velocity if keys.held is not None else None


def _status_line(
    dev: Any,
    keys: KeyTeleop,
    pad: Pad | None,
    sent: tuple[float, float] | None,
    note: str,
    now: float,
) -> str:
    """``cmd v w @speed | meas v w | link | e-stop | pad`` (v in m/s, w in rad/s);
    `Terminal.status` cuts it to the terminal's width."""
    v, w = sent or (0.0, 0.0)
    parts = [f"cmd v{v:+.2f} w{w:+.2f} @{keys.percent}%"]
    odometry = dev.latest_odometry
    if odometry is None:
        parts.append("meas -")
    else:
        parts.append(f"meas v{odometry.linear:+.2f} w{odometry.angular:+.2f}")
    parts.append(dev.connection_state.name.lower())
    telemetry = getattr(dev, "latest_telemetry", None)
    if note:
        parts.append(note)
    elif telemetry is not None and getattr(telemetry, "emergency_stopped", False):
        parts.append("E-STOP")
    if pad is not None:
        parts.append(pad.state.why(now) or "pad")
    return " | ".join(parts)
