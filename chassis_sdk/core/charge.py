"""A device's state of charge as every surface shows it: the CLI's ``monitor``, the web
dashboard and the MQTT bridge read it here, so that they say the same thing.

The state of charge comes from the device's ``battery=BatteryModel(...)``
([`battery_percentage`][chassis_sdk.Board.battery_percentage]). It is ``None`` until it is
known, and shown as such (left out of JSON, ``--`` on a terminal), never as a made-up
number.
"""

from __future__ import annotations

from typing import Any, Protocol

from .battery import BatteryLevel, BatteryModel

__all__ = ["HasBattery", "battery_fields", "battery_level", "battery_text"]


class HasBattery(Protocol):
    """What is read of a device here (``Chassis`` and ``Board`` have both)."""

    @property
    def battery_percentage(self) -> float | None: ...

    @property
    def battery_model(self) -> BatteryModel | None: ...


def battery_level(device: HasBattery) -> BatteryLevel | None:
    """The level (``OK``, ``LOW``, ``CRITICAL``) of the charge, or ``None``: no model,
    or the charge is not known yet."""
    model = device.battery_model
    if model is None or device.battery_percentage is None:
        return None
    return model.level


def battery_fields(device: HasBattery) -> dict[str, Any]:
    """``{"battery_percentage": 63.2, "battery_level": "OK" | "LOW" | "CRITICAL"}``:
    the keys a JSON payload carries beside a voltage; empty without a model or while the
    charge is not known (a value not known is left out, never ``null``: see
    `chassis_sdk.core.plain`)."""
    percentage = device.battery_percentage
    level = battery_level(device)
    if percentage is None or level is None:
        return {}
    return {"battery_percentage": round(percentage, 1), "battery_level": level.name}


def battery_text(voltage: float, device: HasBattery) -> str:
    """A voltage with the charge beside it, for a terminal: ``"24.6 V  63 %"``,
    ``"22.1 V  18 % LOW"``, ``"24.6 V  --"`` while the charge is not known, and the
    voltage alone when the device has no model."""
    text = f"{voltage:.1f} V"
    if device.battery_model is None:
        return text
    percentage = device.battery_percentage
    if percentage is None:
        return f"{text}  --"
    text = f"{text}  {percentage:.0f} %"
    level = battery_level(device)
    if level is not None and level is not BatteryLevel.OK:
        text += f" {level.name}"
    return text
