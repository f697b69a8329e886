"""What every device's commands share: printing, waiting for a first message, keeping
a velocity command alive, explaining silence, and turning messages into JSON."""

from __future__ import annotations

import contextlib
import logging
import socket
import stat
import sys
import time
from collections.abc import AsyncIterator, Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import anyio

from ..core import compiled
from ..core.charge import battery_text
from ..core.device import Device
from ..core.plain import jsonable
from ..errors import ChassisError, ProtocolError, RequestTimeoutError
from .profile import device_options

if TYPE_CHECKING:
    import argparse

    from ..devices import DeviceProfile

D = TypeVar("D", bound=Device[Any, Any])

__all__ = [
    "DEMO_PATTERN",
    "WrongProtocolError",
    "battery_line",
    "blocked_line",
    "drive_for",
    "driven",
    "explain_silence",
    "first",
    "first_frame",
    "jsonable",
    "out",
    "progress_line",
    "read_secret_file",
    "served_at",
    "show_warnings",
    "simulated",
    "ssh_hint",
]

#: (what, linear m/s, angular rad/s, seconds) of the demos' drive.
DEMO_PATTERN: list[tuple[str, float, float, float]] = [
    ("forward", 0.4, 0.0, 1.5),
    ("turn left", 0.2, 0.8, 1.5),
    ("backward", -0.3, 0.0, 1.0),
    ("spin right", 0.0, -1.0, 1.0),
]


#: A flag of ``motion_blocked()`` -> (what the device is, what to do; ``{port}`` is filled).
_BLOCKED: dict[str, tuple[str, str]] = {
    "SOFTWARE_ESTOP": (
        "e-stopped (software)",
        "release it with `chassis-sdk estop {port} --release`",
    ),
    "HARDWARE_ESTOP": ("e-stopped (hardware button)", "release the button"),
    "REMOTE_ESTOP": ("e-stopped (remote control)", "release it on the remote control"),
    "FRONT_BUMPER": (
        "stopped by its front bumper",
        "free it, then `chassis-sdk clear-faults {port} --front-bumper`",
    ),
    "REAR_BUMPER": (
        "stopped by its rear bumper",
        "free it, then `chassis-sdk clear-faults {port} --rear-bumper`",
    ),
    "FRONT_DRIVER_OFFLINE": ("without its front motor driver", "check its power and cable"),
    "REAR_DRIVER_OFFLINE": ("without its rear motor driver", "check its power and cable"),
}
for _wheel in ("FRONT_LEFT", "FRONT_RIGHT", "REAR_LEFT", "REAR_RIGHT"):
    _BLOCKED[f"{_wheel}_DRIVER_ERROR"] = (
        f"stopped by a {_wheel.lower().replace('_', '-')} motor driver error",
        "clear it with `chassis-sdk clear-faults {port} --driver`",
    )


def blocked_line(device: str, port: str, flags: Sequence[str]) -> str:
    """The one line that refuses to drive ``device`` whose ``motion_blocked()`` gave
    ``flags``: what it is and what to do, for each."""
    known = [_BLOCKED.get(f, (f"blocked ({f})", "see `chassis-sdk info {port}`")) for f in flags]
    whats = " and ".join(what for what, _ in known)
    todo = "; ".join(dict.fromkeys(fix.format(port=port) for _, fix in known))
    return f"the {device} is {whats}; {todo}"


class WrongProtocolError(ChassisError):
    """Bytes arrive, but none of them forms a frame of the expected protocol."""


def battery_line(voltage: float, device: Device[Any, Any]) -> str:
    """``info``'s battery line: the voltage and the state of charge, or why it shows
    none. A model gives a percentage only after ``warmup`` seconds and ``min_readings``
    readings, which a one-shot ``info`` rarely waits for: "not yet known" says so
    rather than leaving the percentage out without a word."""
    text = battery_text(voltage, device)
    model = device.battery_model
    if model is None:
        return f"{text}, state of charge unknown (no [battery] in the profile)"
    if device.battery_percentage is None:
        return (
            f"{voltage:.1f} V, state of charge not yet known (the model needs "
            f"{model.warmup:g} s and {model.min_readings} readings; `monitor` shows it)"
        )
    return text


def out(text: str = "") -> None:
    """Print one line of the command's output at once."""
    print(text, flush=True)


async def first(stream: AsyncIterator[Any], timeout: float, what: str) -> Any:
    """The first item of ``stream``, or `RequestTimeoutError` naming ``what``."""
    with anyio.move_on_after(timeout):
        return await anext(stream)
    raise RequestTimeoutError(f"no {what} within {timeout:g} s")


async def drive_for(
    device: Device[Any, Any],
    linear: float,
    angular: float,
    seconds: float,
    show: Callable[[], None],
) -> None:
    """Keep a velocity command alive for ``seconds`` (as a control loop would), showing
    live data at 5 Hz."""
    end = time.monotonic() + seconds
    next_show = 0.0
    while (now := time.monotonic()) < end:
        await device.set_velocity(linear, angular)
        if now >= next_show:
            show()
            next_show = now + 0.2
        await anyio.sleep(0.1)


def port_lines(port: str) -> None:
    """The first lines of every ``info``: the port, and which decoders run (the
    compiled fast path, or the pure Python code and why)."""
    out(f"port         {port}")
    out(f"decoders     {compiled.status()}")


@contextlib.asynccontextmanager
async def simulated(name: str, device: type[D]) -> AsyncIterator[D]:
    """A demo's stage: device ``name``'s simulator on a pty and ``device`` connected to
    it through the real serial stack, narrated."""
    from ..sim import simulator

    out(f"Starting the {name} simulator on a pseudo-terminal ...")
    async with simulator(name) as sim:
        out(f"simulator    {sim.port}")
        async with device(sim.port) as connected:
            out(f"connected    via {connected.transport_backend}")
            yield connected


async def first_frame(
    device: Device[Any, Any],
    timeout: float,
    what: str,
    *,
    command: str = "",
    able: Sequence[str] | None = None,
) -> None:
    """``device.verify()``, with errors that name the other known devices and what
    was expected: proof that the device on the port is this one before anything is
    done to it. ``able``: the only devices ``command`` works on, if not every one (no
    ``--device`` is suggested that the command would then refuse).

    Raises:
        WrongProtocolError: Bytes arrive, but none forms a frame of this protocol.
        RequestTimeoutError: Nothing arrived within ``timeout`` seconds.
    """
    try:
        await device.verify(timeout)
    except ProtocolError:
        _wrong_protocol(device, command, able)
    except RequestTimeoutError:
        raise RequestTimeoutError(f"no {what} from {device.port} within {timeout:g} s") from None


def _wrong_protocol(
    device: Device[Any, Any], command: str = "", able: Sequence[str] | None = None
) -> None:
    from ..devices import profiles

    others = [name for name in profiles() if name != device.device_name] or ["different device"]
    tried = [name for name in others if able is None or name in able]
    if tried:
        advice = f"Try --device {tried[0]}, or `chassis-sdk detect`"
    else:  # the other devices cannot do it: --device would only be refused
        advice = (
            f"{command} works on a {' or a '.join(able or [device.device_name])} only "
            "(`chassis-sdk detect` says which device it is)"
        )
    raise WrongProtocolError(
        f"{device.stats.bytes_received} bytes arrived on {device.port} but none is a "
        f"{device.device_name} frame: is it a {' or a '.join(others)}? {advice}"
    )


class ProgressLine:
    """Progress of a long command: one live line on a terminal (through rich when it
    is installed), plain lines at most once a second when piped (never a carriage
    return into a pipe), and at once when something important changes."""

    def __init__(self, label: str) -> None:
        self.label = label
        self._tty = sys.stdout.isatty()
        self._last = 0.0
        self._important = False
        self._live: Any = None
        if self._tty:
            try:
                from rich.console import Console
                from rich.live import Live

                self._live = Live(console=Console(), auto_refresh=False, transient=True)
                self._live.start()
            except ImportError:
                pass

    def __call__(self, text: str, important: bool = False) -> None:
        line = f"{self.label}: {text}"
        if self._live is not None:
            self._live.update(line, refresh=True)
        elif self._tty:
            print(f"\r{line}\033[K", end="", flush=True)
        else:
            now = time.monotonic()
            if important != self._important or now - self._last >= 1.0:
                out(line)
                self._last = now
        self._important = important

    def done(self, text: str) -> None:
        """End the live line and print the result (nothing if ``text`` is empty)."""
        if self._live is not None:
            self._live.stop()
        elif self._tty:
            print("\r\033[K", end="")
        if text:
            out(text)


def progress_line(label: str) -> ProgressLine:
    """A `ProgressLine` for ``label``."""
    return ProgressLine(label)


def explain_silence(device: Device[Any, Any], exc: RequestTimeoutError) -> None:
    """Re-raise a request's timeout, as `WrongProtocolError` if bytes arrived
    but none formed a frame of this device's protocol."""
    stats = device.stats
    if stats.bytes_received and not stats.frames:
        try:
            _wrong_protocol(device)
        except WrongProtocolError as wrong:
            raise wrong from exc
    raise exc


def read_secret_file(path: str, option: str) -> str:
    """A secret (a password, a token) from the file ``option`` names: its text without
    the final newline (nothing else is stripped: a secret may end in a space). Like ssh
    with a private key, a file that group or others may read is refused: the secret is
    as good as published.

    Raises:
        ChassisError: The file cannot be read, is open to group or others, is not UTF-8
            text, or is empty; one line naming ``option`` and the file.
    """
    file = Path(path)
    try:
        mode = file.stat().st_mode
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise ChassisError(
                f"{option} {path} is open to group or others (mode "
                f"{stat.S_IMODE(mode):04o}); chmod 600 it"
            )
        text = file.read_text(encoding="utf-8")
    except OSError as exc:
        raise ChassisError(f"cannot read {option} {path}: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise ChassisError(f"{option} {path} is not UTF-8 text") from None
    secret = text.removesuffix("\n").removesuffix("\r")
    if not secret:
        raise ChassisError(f"{option} {path} is empty")
    return secret


#: Hosts that bind every address of the computer.
_WILDCARDS = ("0.0.0.0", "::", "")


def served_at(scheme: str, host: str, port: int) -> list[str]:
    """The addresses to print for a server bound to ``host``:``port``, the one to open
    first: for a wildcard (``0.0.0.0``, ``::``) this computer's name, which another
    computer reaches (127.0.0.1 there is that computer itself), then loopback, for a
    browser on this one; for any other host, that host."""
    if host in _WILDCARDS:
        local = "[::1]" if host == "::" else "127.0.0.1"
        return [f"{scheme}://{socket.gethostname()}:{port}/", f"{scheme}://{local}:{port}/"]
    shown = f"[{host}]" if ":" in host else host
    return [f"{scheme}://{shown}:{port}/"]


def ssh_hint(port: int) -> str:
    """The ssh command that brings the TCP ``port`` served on this computer to the same
    port of the one ssh runs on (``http://127.0.0.1:PORT/`` there)."""
    return f"ssh -L {port}:127.0.0.1:{port} {socket.gethostname()}"


def show_warnings(logger: str, command: str) -> None:
    """Print ``logger``'s warnings (refused connections or messages: already
    rate-limited) on stderr as ``chassis-sdk COMMAND: ...``: the CLI shows only errors
    unless ``-v``, and a refusal is what an operator must see."""
    log = logging.getLogger(logger)
    if log.getEffectiveLevel() > logging.WARNING:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter(f"chassis-sdk {command}: %(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.WARNING)
        log.propagate = False


@contextlib.asynccontextmanager
async def driven(
    device: DeviceProfile,
    port: str,
    args: argparse.Namespace,
    *,
    read_only: bool = False,
    record: bool = True,
) -> AsyncIterator[Device[Any, Any]]:
    """The device a surface that moves the robot (``serve``, ``ros2``) drives, for the
    block: reconnecting through unplugs, within ``--max-linear``/``--max-angular``, under
    ``--command-timeout`` (``arguments.limit_args``, ``deadman_args``), with the
    profile's limits, calibration and battery (`.profile.device_options`), recording
    to ``--record`` (``arguments.record_arg``; ``record=False``: the caller records it
    itself), and proven to be this device (`first_frame`) before anything is done to
    it. ``read_only``: a viewer's, which writes nothing."""
    file = getattr(args, "record", None) if record else None
    options = device_options(args, reconnect=True, read_only=read_only, record=file)
    async with device.device(port, **options) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        yield dev
