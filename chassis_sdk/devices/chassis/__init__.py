"""The chassis (protocol A): a four-wheel skid-steer base.

* :mod:`.messages`: the typed messages and their enums;
* :mod:`.protocol`: the sans-IO codec (frames, encoder, decoders);
* :mod:`.device`: :class:`Chassis`, the public API (:mod:`.commands`: its commands);
* :mod:`.health`: what its status words mean (events, diagnosis findings);
* :mod:`.firmware`: the sans-IO firmware model (served by :mod:`chassis_sdk.sim`);
* :mod:`.profile`: its registry entry.

``Chassis`` is imported on first use, so the codec loads without the runtime.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .device import Chassis

__all__ = ["Chassis"]


__getattr__, __dir__ = _lazy(__name__, {"Chassis": ".device"}, globals())
