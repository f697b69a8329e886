"""What the commands on capture files share (``record``, ``replay``, ``plot``,
``export``): the checks made before anything is read or opened (the extra that reads
the file, the file or directory written), which device a capture file is of, and the
one-line error for a capture without that device's frames."""

from __future__ import annotations

import os
from pathlib import Path
from typing import NoReturn

from ..devices import profiles
from ..errors import ChassisError
from ..recording import capture
from .extras import require

__all__ = [
    "detect_file",
    "head",
    "no_messages",
    "output_directory",
    "require_reader",
    "writable",
]


def require_reader(command: str, path: str) -> None:
    """Before ``command`` reads the capture ``path``: if it is an MCAP file, the
    package that reads it (`chassis_sdk.cli.extras.require`).

    Raises:
        FileNotFoundError, IsADirectoryError: ``path`` is not a file (one line).
        ChassisError: It is MCAP, and mcap is not installed.
    """
    if capture.is_mcap(path):
        require(command, "foxglove", "mcap")


def writable(file: str, option: str = "") -> None:
    """Refuse, before anything is read or opened, an output ``file`` that cannot be
    written (``option``: the option that named it, for the message).

    Raises:
        ChassisError: Its directory does not exist or is not writable, or it is a
            directory.
    """
    name = f"{option} {file}" if option else file
    target = Path(file)
    folder = target.parent
    if not folder.is_dir():
        raise ChassisError(f"cannot write {name}: no such directory {folder}")
    if target.is_dir():
        raise ChassisError(f"cannot write {name}: it is a directory")
    if not os.access(folder, os.W_OK) or (target.exists() and not os.access(target, os.W_OK)):
        raise ChassisError(f"cannot write {name}: permission denied")


def output_directory(directory: str, option: str) -> None:
    """Make the output ``directory`` (named by ``option``) and its parents if missing,
    and make sure files can be made in it, before anything is read.

    Raises:
        ChassisError: It cannot be made, is a file, or is not writable (one line).
    """
    path = Path(directory)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ChassisError(f"{option} {directory} is a file, not a directory") from None
    except OSError as exc:
        raise ChassisError(f"cannot make {option} {directory}: {exc.strerror or exc}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise ChassisError(f"cannot write in {option} {directory}: permission denied")


def head(path: str, size: int = 1 << 16) -> bytes:
    """The first ``size`` bytes the device sent in a capture (enough to tell which
    device it is: thousands of frames), without reading the rest."""
    data = bytearray()
    for _, chunk in capture.read_capture(path):
        data += chunk
        if len(data) >= size:
            break
    return bytes(data)


def detect_file(path: str) -> str:
    """The device a capture is of: the one its MCAP metadata names, else the one whose
    frames are in its first bytes.

    Raises:
        ChassisError: No known device's frames are in it.
    """
    if capture.is_mcap(path):
        recorded = capture.mcap_metadata(path).get("device")
        if recorded in profiles():
            return recorded
    found = capture.detect_in(head(path))
    if found is None:
        raise ChassisError(f"no frames of any known device ({', '.join(profiles())}) in {path}")
    return found


def no_messages(path: str, device: str) -> NoReturn:
    """Raise the error for a capture ``path`` with no frames of ``device``, naming the
    device it looks like if any.

    Raises:
        ChassisError: Always.
    """
    data = head(path)
    if not data:
        raise ChassisError(f"{path} holds no bytes")
    other = capture.detect_in(data)
    hint = f": it looks like a {other} capture; try --device {other}" if other else ""
    raise ChassisError(f"no {device} frames in {path}{hint}")
