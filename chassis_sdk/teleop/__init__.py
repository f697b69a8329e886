"""Driving by hand, sans-IO where it can be: what ``chassis-sdk teleop`` (and anything
else that drives from a keyboard or a pad) is made of.

* `keys`: `KeyTeleop`, a terminal's bytes to a held key and its command (autorepeat
  read as holding, a key timeout as letting go), and `KeyDecoder`;
* `gamepad`: `JoyMapping` and `JoyState`, an evdev pad's events to a command (the
  enable button, deadzones, a silent pad), and `Pad`, reading one from the event loop.

Each drives through a motion-core source of kind ``"teleop"`` or ``"gamepad"`` (the
highest default priority), made by the program that reads the keys or the pad.
"""
