"""Dead-reckoned odometry from reported velocities.

Kept at this path for code written against it; the code lives in
:mod:`chassis_sdk.core.odometry`.
"""

from .core.odometry import *  # noqa: F403
from .core.odometry import __all__ as __all__
