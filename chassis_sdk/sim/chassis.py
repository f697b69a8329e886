"""The chassis firmware model and its simulator.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.chassis.firmware`.
"""

from ..devices.chassis.firmware import *  # noqa: F403
from ..devices.chassis.firmware import __all__ as __all__
