"""The board firmware model and its simulator.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.board.firmware`.
"""

from ..devices.board.firmware import *  # noqa: F403
from ..devices.board.firmware import __all__ as __all__
