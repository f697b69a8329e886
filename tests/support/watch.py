"""What the running test does that needs a marker: the state behind
``tests/support/markers.py``, kept free of pytest so that the support modules the
benchmarks share (the broker, the browser, the DDS peer) can report through it."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable, Iterator

__all__ = ["arm", "disarm", "exempt", "needs"]

_lock = threading.Lock()
#: The running test's ``get_closest_marker``, while the check is armed.
_marked: Callable[[str], object] | None = None
_seen: dict[str, str] = {}  # marker -> the first thing the test did that needs it
_exempt = threading.local()


def arm(marked: Callable[[str], object]) -> None:
    """Start noting for a test; ``marked(name)`` is its marker of that name, or None."""
    global _marked
    with _lock:
        _marked = marked
        _seen.clear()


def disarm() -> dict[str, str]:
    """Stop noting; what the test did that its markers do not say (marker -> what)."""
    global _marked
    with _lock:
        _marked = None
        seen = dict(_seen)
        _seen.clear()
    return seen


def needs(marker: str, what: str) -> None:
    """Note that the running test does something that needs ``marker``.

    Args:
        marker: The marker's name (``integration``, ``mqtt``, ...).
        what: What the test did, for the failure message ("starts mosquitto").
    """
    if getattr(_exempt, "depth", 0):
        return
    with _lock:
        if _marked is None or _marked(marker) is not None:
            return
        _seen.setdefault(marker, what)


@contextlib.contextmanager
def exempt() -> Iterator[None]:
    """Within this block (on this thread) nothing is noted: the test machinery's own
    processes, such as the netns plugin's child pytest."""
    _exempt.depth = getattr(_exempt, "depth", 0) + 1
    try:
        yield
    finally:
        _exempt.depth -= 1
