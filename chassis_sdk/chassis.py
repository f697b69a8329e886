"""``Chassis``: the protocol A robot base.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.chassis.device`.
"""

from .devices.chassis.device import *  # noqa: F403
from .devices.chassis.device import __all__ as __all__
