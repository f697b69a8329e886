"""``Board``: the protocol B controller board.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.board.device`.
"""

from .devices.board.device import *  # noqa: F403
from .devices.board.device import __all__ as __all__
