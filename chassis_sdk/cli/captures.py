"""What ``replay``, ``plot`` and ``export`` share: which device a capture file is of,
and the one-line error for a capture without that device's frames."""

from __future__ import annotations

from typing import NoReturn

from ..devices import profiles
from ..errors import ChassisError
from ..recording import capture

__all__ = ["detect_file", "head", "no_messages"]


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
