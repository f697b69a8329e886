"""Finding the port: every serial port on this machine, what it is, whether this user
can open it now, and names for it that survive renumbering.

Nothing here opens a port: opening one toggles DTR, which resets some boards. Access
is read from the file's permissions and the kernel's table of locks (a program holding
the port, as ``chassis_sdk`` and most serial tools do, is named when it is visible).

Why a port may be named by what it is rather than where it is
-------------------------------------------------------------
A USB serial adapter gets the next free node when it is plugged in: ``/dev/ttyUSB0``
today, ``/dev/ttyUSB1`` after a replug while something still held the old node, or
when a second adapter came first. Two names stay the same:

* udev's ``/dev/serial/by-id/usb-VENDOR_PRODUCT_SERIAL-if00-port0`` symlink. It is an
  ordinary path: the OS follows it at every open, so a device that reopens the same
  path after a replug reaches the new node. Nothing here resolves it in advance;
* ``usb:VID:PID[:SERIAL]`` (`UsbIdentity`), which `resolve_port` looks up in
  ``serial.tools.list_ports.comports()`` at every open and every reconnect attempt.
  It needs no udev (containers, minimal systems) and reads the same on every machine.
"""

from __future__ import annotations

import os
import re
from dataclasses import asdict, dataclass
from typing import Any

from serial.tools import list_ports

from ..errors import PortOpenError

__all__ = [
    "BY_ID_DIR",
    "PortInfo",
    "PortNotFoundError",
    "UsbIdentity",
    "list_serial_ports",
    "lock_holder",
    "parse_usb_identity",
    "resolve_port",
]

#: Where udev keeps its stable names of serial devices.
BY_ID_DIR = "/dev/serial/by-id"

_PREFIX = "usb:"
_HEX4 = re.compile(r"[0-9A-Fa-f]{4}")
_FORM = "usb:VID:PID[:SERIAL] (VID and PID four hex digits each, e.g. usb:10C4:EA60:0001)"


class PortNotFoundError(PortOpenError):
    """No attached device matches a ``usb:VID:PID[:SERIAL]`` port, or several do.

    It is a [`PortOpenError`][chassis_sdk.PortOpenError]: with ``reconnect=True`` the port is
    then simply not there yet, as when a ``/dev`` node is missing, and is looked up
    again at the next attempt.
    """


@dataclass(frozen=True, slots=True)
class UsbIdentity:
    """A USB serial device by what it is: vendor id, product id and, if given, serial
    number. ``str()`` gives the canonical form (``usb:10C4:EA60:0001``).

    Attributes:
        vid: The USB vendor id.
        pid: The USB product id.
        serial: The USB serial number (compared exactly), or ``None`` to match any.
    """

    vid: int
    pid: int
    serial: str | None = None

    def __str__(self) -> str:
        base = f"{_PREFIX}{self.vid:04X}:{self.pid:04X}"
        return base if self.serial is None else f"{base}:{self.serial}"

    def matches(self, vid: int | None, pid: int | None, serial: str | None) -> bool:
        """True if a device with these ids is this one."""
        if vid != self.vid or pid != self.pid:
            return False
        return self.serial is None or serial == self.serial


def _is_serial_text(text: str) -> bool:
    return bool(text) and text.isprintable() and not any(c.isspace() for c in text)


def parse_usb_identity(port: str) -> UsbIdentity | None:
    """The `UsbIdentity` that ``port`` names, or ``None`` if it is not of the
    form ``usb:...`` (a path or a URL). The prefix and the hex digits may be in either
    case; the serial number is the rest after the third colon, taken as written.

    Raises:
        TypeError: ``port`` is not a string.
        ValueError: It starts with ``usb:`` but is not ``usb:VID:PID[:SERIAL]``.
    """
    if not isinstance(port, str):
        raise TypeError(f"port must be a string, got {type(port).__name__}")
    if port[: len(_PREFIX)].lower() != _PREFIX:
        return None
    parts = port[len(_PREFIX) :].split(":", 2)
    if len(parts) < 2 or not all(_HEX4.fullmatch(p) for p in parts[:2]):
        raise ValueError(f"port {port!r} is not of the form {_FORM}")
    serial: str | None = None
    if len(parts) == 3:
        serial = parts[2]
        if not _is_serial_text(serial):
            raise ValueError(
                f"port {port!r}: the serial number after usb:VID:PID: must be printable "
                f"text without spaces; the form is {_FORM}"
            )
    return UsbIdentity(int(parts[0], 16), int(parts[1], 16), serial)


def _text(value: object) -> str:
    return "" if value in (None, "n/a") else str(value)


def _usb_text(port: Any) -> str:
    """``usb:VID:PID`` and where it is, for messages."""
    serial = _text(port.serial_number)
    return (
        f"{UsbIdentity(port.vid, port.pid)}"
        + (f" serial {serial}" if serial else " (no serial number)")
        + f" at {port.device}"
    )


def resolve_port(port: str) -> str:
    """The path to open for ``port``, looked up now.

    A ``usb:VID:PID[:SERIAL]`` port is looked up in
    ``serial.tools.list_ports.comports()``; exactly one attached device must match, and
    its node (``/dev/ttyUSB1``) is returned. Everything else (a device path, a
    ``/dev/serial/by-id`` symlink, a pty, ``socket://``) is returned unchanged: the OS
    follows a symlink at every open, so re-opening the same path after a replug
    reaches the new node.

    Raises:
        TypeError: ``port`` is not a string.
        ValueError: A malformed ``usb:`` form.
        PortNotFoundError: No attached device matches, or several do (one line naming
            what is attached).
    """
    wanted = parse_usb_identity(port)
    if wanted is None:
        return port
    usb = [p for p in list_ports.comports() if p.vid is not None and p.pid is not None]
    found = [p for p in usb if wanted.matches(p.vid, p.pid, _text(p.serial_number) or None)]
    if len(found) == 1:
        return str(found[0].device)
    if not found:
        attached = "; ".join(_usb_text(p) for p in usb) or "no USB serial device"
        raise PortNotFoundError(
            f"no USB serial device is {wanted} (attached: {attached}; see `chassis-sdk ports`)"
        )
    serials = [_text(p.serial_number) for p in found]
    hint = (
        f"add the serial number, e.g. {UsbIdentity(wanted.vid, wanted.pid, serials[0])}"
        if all(serials) and len(set(serials)) == len(serials)
        else "they share a serial number: name one by its /dev/serial/by-path link instead"
    )
    raise PortNotFoundError(
        f"{len(found)} USB serial devices are {wanted} "
        f"({'; '.join(_usb_text(p) for p in found)}): {hint}"
    )


@dataclass(frozen=True, slots=True)
class PortInfo:
    """One serial port.

    Attributes:
        device: The path to open (``/dev/ttyUSB0``).
        description: What the system calls it (``CP2102 USB to UART Bridge``), or ``""``.
        manufacturer: The USB manufacturer string, or ``""``.
        vid_pid: ``"10C4:EA60"`` for a USB device, ``""`` otherwise.
        serial_number: The USB serial number, or ``""``.
        access: ``"ok"``, ``"permission denied"``, ``"busy: held by ..."`` or
            ``"missing"``.
        identity: A port name that survives renumbering: ``usb:10C4:EA60:SERIAL``, or
            ``usb:10C4:EA60`` when the device has no serial number, or one that another
            attached device of the same ids shares; ``""`` for a port that is not USB.
        by_id: udev's ``/dev/serial/by-id/...`` link to `device`, or ``""``.
    """

    device: str
    description: str
    manufacturer: str
    vid_pid: str
    serial_number: str
    access: str
    identity: str = ""
    by_id: str = ""

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain ``dict`` (for JSON)."""
        return asdict(self)


def lock_holder(path: str) -> str | None:
    """Who holds the advisory lock on ``path`` (from ``/proc/locks``), if we can see it.

    A symlink (``/dev/serial/by-id/...``) is followed: the lock is on the node."""
    try:
        st = os.stat(path)
        with open("/proc/locks") as f:
            lines = f.readlines()
    except OSError:
        return None
    wanted = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    for line in lines:
        parts = line.split()
        if len(parts) > 5 and parts[1] == "FLOCK" and parts[5] == wanted:
            pid = parts[4]
            if pid == str(os.getpid()):
                return f"this process (pid {pid})"
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    argv = f.read().decode(errors="replace").split("\0")
            except OSError:
                argv = []
            cmd = command_line(argv)
            return f"process {pid}" + (f" ({cmd})" if cmd else "")
    return None


def command_line(argv: list[str], width: int = 80) -> str:
    """The part of a process's command line that says what it is: the program's name
    and its arguments (``chassis-sdk monitor /dev/ttyUSB0``), not the interpreter's
    path: ``python -m mod`` is ``mod``, ``python /venv/bin/tool`` is ``tool``. Cut to
    ``width`` characters at most, marked with ``…``."""
    words = [w for w in argv if w]
    if not words:
        return ""
    program, rest = os.path.basename(words[0]), words[1:]
    if re.fullmatch(r"python[\d.]*", program):
        while rest and rest[0].startswith("-") and rest[0] != "-m":
            rest = rest[1:]
        if rest[:1] == ["-m"] and len(rest) > 1:
            program, rest = rest[1], rest[2:]
        elif rest:
            program, rest = os.path.basename(rest[0]), rest[1:]
    text = " ".join([program, *rest])
    return text if len(text) <= width else text[: width - 1] + "…"


def _access(path: str) -> str:
    if not os.path.exists(path):
        return "missing"
    if not os.access(path, os.R_OK | os.W_OK):
        return "permission denied (join the group that owns it, usually dialout)"
    holder = lock_holder(path)
    return f"busy: held by {holder}" if holder else "ok"


def _by_id_links() -> dict[str, str]:
    """The node each link in `BY_ID_DIR` points at -> the link."""
    directory = BY_ID_DIR
    try:
        names = sorted(os.listdir(directory))
    except OSError:  # no udev, or no serial device: no directory
        return {}
    links: dict[str, str] = {}
    for name in names:
        link = os.path.join(directory, name)
        links.setdefault(os.path.realpath(link), link)
    return links


def list_serial_ports() -> list[PortInfo]:
    """Every serial port the system lists (``serial.tools.list_ports``), USB first,
    each with its `identity` and `by_id` link."""
    listed = list(list_ports.comports())
    links = _by_id_links()
    ids = [(p.vid, p.pid, _text(p.serial_number)) for p in listed if p.vid is not None]
    found = []
    for port in listed:
        serial = _text(port.serial_number)
        vid_pid = identity = ""
        if port.vid is not None and port.pid is not None:
            vid_pid = f"{port.vid:04X}:{port.pid:04X}"
            unique = _is_serial_text(serial) and ids.count((port.vid, port.pid, serial)) == 1
            identity = str(UsbIdentity(port.vid, port.pid, serial if unique else None))
        found.append(
            PortInfo(
                device=port.device,
                description=_text(port.description),
                manufacturer=_text(port.manufacturer),
                vid_pid=vid_pid,
                serial_number=serial,
                access=_access(port.device),
                identity=identity,
                by_id=links.get(os.path.realpath(port.device), ""),
            )
        )
    return sorted(found, key=lambda p: (not p.vid_pid, p.device))
