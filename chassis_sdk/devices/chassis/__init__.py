"""The chassis (protocol A): a four-wheel skid-steer base.

* `.messages`: the typed messages and their enums;
* `.protocol`: the sans-IO codec (frames, encoder, decoders);
* `.device`: [`Chassis`][chassis_sdk.Chassis], the public API (`.commands`: its commands);
* `.health`: what its status words mean (events, diagnosis findings);
* `.firmware`: the sans-IO firmware model (served by `chassis_sdk.sim`);
* `.profile`: its registry entry.

``Chassis`` is imported on first use, so the codec loads without the runtime.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..._lazy import lazy as _lazy

if TYPE_CHECKING:
    from .device import Chassis

__all__ = ["Chassis"]


__getattr__, __dir__ = _lazy(__name__, {"Chassis": ".device"}, globals())
