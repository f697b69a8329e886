"""The one check of what a command needs from an extra, before any port opens.

Every command that imports an extra's packages (``web``, ``serve``, ``bridge``,
``ros2``, ``plot``, ``record FILE.mcap``, ``replay``/``export``/``plot`` of an MCAP
file, ``teleop --joystick``) calls `require` in its ``func``, before it returns the
job: a missing package is one line naming the extra and the pip command that installs
it from the checkout (README's form), never a traceback from deep inside, and never
after the device's port was opened.
"""

from __future__ import annotations

from importlib import import_module

from ..errors import ChassisError, install_hint

__all__ = ["EXTRAS", "install_hint", "require"]

#: Each extra of pyproject.toml that a command needs, and the modules (import names)
#: it brings that the commands import.
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib", "numpy"),
    "mqtt": ("aiomqtt",),
    "foxglove": ("foxglove", "mcap", "websockets"),
    "ros2": ("cyclonedds", "mcap"),
    "web": ("aiohttp",),
    "joystick": ("evdev",),
}


def require(command: str, extra: str, *modules: str) -> None:
    """Make sure ``command`` can import ``modules`` (default: every module of
    ``extra``, `EXTRAS`).

    Raises:
        ChassisError: One of them cannot be imported: one line naming the module
            missing (it, or one it needs), the extra and `install_hint` (and why, if it
            is installed but does not import).
    """
    for module in modules or EXTRAS[extra]:
        try:
            import_module(module)
        except ImportError as exc:
            if isinstance(exc, ModuleNotFoundError) and exc.name:  # it, or what it needs
                what = exc.name.partition(".")[0]
            else:  # there, but it does not import (a C library missing)
                reason = (str(exc).splitlines() or [type(exc).__name__])[0]
                what = f"{module} (installed, but: {reason})"
            raise ChassisError(
                f"{command} needs {what}, from the {extra} extra: {install_hint(extra)}"
            ) from None
