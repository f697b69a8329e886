"""Protocol A, the chassis protocol: frames, typed messages, encoder and decoders.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.chassis.protocol`.
"""

from ..devices.chassis.protocol import *  # noqa: F403
from ..devices.chassis.protocol import __all__ as __all__
