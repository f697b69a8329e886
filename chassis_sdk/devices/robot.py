"""`open_robot`: the device a robot profile describes, typed by the device's name.

It sits above the device packages (it names `Chassis` and `Board` for the type
checker) and beside `chassis_sdk.devices.config`, which reads the profile and which the
device classes themselves use for ``from_config()``.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, Literal, overload

from .config import Profile, load_profile, profile_device, profile_options

if TYPE_CHECKING:
    from ..core.device import Device
    from .board.device import Board
    from .chassis.device import Chassis

__all__ = ["open_robot"]


@overload
def open_robot(
    config: str | os.PathLike[str] | Profile | None = None,
    *,
    device: Literal["chassis"],
    **overrides: Any,
) -> Chassis: ...
@overload
def open_robot(
    config: str | os.PathLike[str] | Profile | None = None,
    *,
    device: Literal["board"],
    **overrides: Any,
) -> Board: ...
@overload
def open_robot(
    config: str | os.PathLike[str] | Profile | None = None,
    *,
    device: str | None = None,
    **overrides: Any,
) -> Device[Any, Any]: ...
def open_robot(
    config: str | os.PathLike[str] | Profile | None = None,
    *,
    device: str | None = None,
    **overrides: Any,
) -> Device[Any, Any]:
    """The device the profile describes (``[robot] device``, default ``chassis``), not
    yet open: use it as ``async with open_robot() as robot:``. ``overrides`` beat the
    file (``port=``, ``limits=``, any option of the device's constructor).

    The profile's device is known only when the file is read, so ``open_robot()`` is
    typed as the base ``Device``; name the device for its own type
    (``open_robot(device="chassis")`` is a `Chassis`, ``device="board"`` a `Board`),
    or use ``Chassis.from_config()``. A profile of another device is then refused.

    Raises:
        ProfileError: The profile is wrong, names another device than ``device``, or
            names no port and none is given.
    """
    from . import profile as device_profile

    loaded = load_profile(config)
    name = profile_device(loaded, device)
    return device_profile(name).device(**profile_options(loaded, overrides))
