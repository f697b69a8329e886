"""Protocol B, the controller-board protocol: frames, typed messages, encoder and decoders.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.devices.board.protocol`.
"""

from ..devices.board.protocol import *  # noqa: F403
from ..devices.board.protocol import __all__ as __all__
