"""The robot profile: one TOML file that describes a robot once, for every command and
for applications.

The file is found as ``--config FILE`` (or ``find_profile(FILE)``), then
``$CHASSIS_SDK_CONFIG``, then ``./chassis-sdk.toml``, then ``chassis-sdk.toml`` in the
user's configuration directory (``~/.config/chassis-sdk/`` on Linux). Its tables:

* ``[robot]``: ``device``, ``port`` (a path, ``socket://host:port`` or a stable
  ``usb:VID:PID[:SERIAL]``), ``baudrate``, ``reconnect``, ``request_timeout``,
  ``link_timeout``;
* ``[limits]``: the fields of [`MotionLimits`][chassis_sdk.MotionLimits];
* ``[deadman]``: ``command_timeout``;
* ``[calibration]``: the fields of [`Calibration`][chassis_sdk.Calibration];
* ``[battery]``: the options of [`BatteryModel`][chassis_sdk.BatteryModel];
* ``[safety]``: the reflexes ([`SafetyPolicy`][chassis_sdk.SafetyPolicy]): per hazard
  (``bumper``, ``stall``, ``tilt``, ``geofence``, ``battery``, ``link``) an action
  (``"stop"``, ``"back_off"``, ``"slow"``, ``"ignore"``), ``back_off_distance``,
  ``slow_speed``, the thresholds, ``allow_unsafe``, and a geofence as
  ``geofence_rectangle = [W, H]``, ``geofence_circle = [X, Y, R]`` or
  ``geofence_polygon = [[X, Y], ...]``;
* one table per ``chassis-sdk`` command (``[web]``, ``[ros2]``, ``[bridge]``, ...) whose
  keys are that command's long options (``--max-linear`` is ``max_linear``), checked by
  the command line against the command's own parser.

A key that is not one of these, a value of the wrong type and a value out of range are
each a `ProfileError` of one line naming the file, the key and what is allowed.
Unknown keys are errors, never ignored: a typo must not leave a limit unset.

Nothing here opens a port. [`open_robot`][chassis_sdk.open_robot] (in
`chassis_sdk.devices.robot`) builds the device the profile describes;
``Chassis.from_config()`` and ``Board.from_config()`` do the same for one class.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import os
import tomllib
import types
import typing
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Self, TypeAlias, get_args, get_origin

from ..core.battery import BatteryModel
from ..core.calibration import Calibration
from ..core.motion import MotionLimits
from ..core.motion.safety import HAZARDS, Geofence, Reflex, SafetyPolicy

__all__ = [
    "COMMAND_TABLES",
    "DEVICE_TABLES",
    "ENV_CONFIG",
    "PROFILE_NAME",
    "FromConfig",
    "Profile",
    "ProfileError",
    "Source",
    "constructor_options",
    "did_you_mean",
    "find_profile",
    "load_profile",
    "locate_profile",
    "profile_device",
    "profile_options",
    "update_profile",
    "user_profile_path",
]

#: The environment variable naming the profile file.
ENV_CONFIG = "CHASSIS_SDK_CONFIG"
#: The profile's file name, in the working directory and the user's config directory.
PROFILE_NAME = "chassis-sdk.toml"
#: The tables a command's options may be given in (``chassis-sdk`` command names).
COMMAND_TABLES = frozenset(
    {
        "bridge",
        "calibrate",
        "demo",
        "detect",
        "dock",
        "drive",
        "estop",
        "clear-faults",
        "export",
        "info",
        "monitor",
        "move",
        "turn",
        "goto",
        "plot",
        "ports",
        "record",
        "replay",
        "ros2",
        "serve",
        "sim",
        "teleop",
        "web",
    }
)

#: Where a setting came from: ``"default"``, ``"file"``, an environment variable
#: (``"$CHASSIS_SDK_PORT"``) or ``"flag"``.
Source: TypeAlias = str
Value: TypeAlias = "str | int | float | bool | list[Any]"


class ProfileError(ValueError):
    """The profile cannot be used: the message is one line naming the file, the key,
    and what is allowed."""


@dataclass(frozen=True, slots=True)
class _Key:
    """One key of a device table: its type (as an annotation), default and meaning."""

    kind: Any
    default: Any
    doc: str


def _robot_keys() -> dict[str, _Key]:
    return {
        "device": _Key(str, None, "the registered device (chassis, board, ...)"),
        "port": _Key(str, None, "a device path, socket://host:port or usb:VID:PID[:SERIAL]"),
        "baudrate": _Key(int, 115200, "serial speed"),
        "reconnect": _Key(bool, None, "reopen the port after an unplug (commands decide)"),
        "request_timeout": _Key(float, 1.0, "seconds to wait for a reply"),
        "link_timeout": _Key(float, 1.0, "seconds of silence before the link is stale"),
    }


def _dataclass_keys(cls: type[Any]) -> dict[str, _Key]:
    hints = typing.get_type_hints(cls)
    doc = inspect.getdoc(cls) or ""
    return {
        f.name: _Key(hints[f.name], f.default, _attribute_doc(doc, f.name))
        for f in dataclasses.fields(cls)
    }


def _signature_keys(cls: type[Any], skip: Sequence[str] = ("self",)) -> dict[str, _Key]:
    function = cls.__init__
    hints = typing.get_type_hints(function)
    doc = inspect.getdoc(cls) or ""
    keys = {}
    for name, parameter in inspect.signature(function).parameters.items():
        if name in skip:
            continue
        keys[name] = _Key(hints[name], parameter.default, _attribute_doc(doc, name))
    return keys


def _attribute_doc(doc: str, name: str) -> str:
    """What a Google-style docstring says of ``name`` (its entry, continuation lines
    joined), or ``""``."""
    lines = doc.splitlines()
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped.startswith((f"{name}:", f"{name} (")):
            continue
        indent = len(line) - len(line.lstrip())
        text = [stripped.split(":", 1)[1].strip()]
        for more in lines[i + 1 :]:
            if not more.strip() or len(more) - len(more.lstrip()) <= indent:
                break
            text.append(more.strip())
        return " ".join(text)
    return ""


def _device_tables() -> dict[str, dict[str, _Key]]:
    return {
        "robot": _robot_keys(),
        "limits": _dataclass_keys(MotionLimits),
        "deadman": {
            "command_timeout": _Key(float, 0.5, "stop this long after the last velocity (s)")
        },
        "calibration": _dataclass_keys(Calibration),
        "battery": _signature_keys(BatteryModel),
        "safety": _safety_keys(),
    }


def _safety_keys() -> dict[str, _Key]:
    hazards = {
        hazard: _Key(str, "stop", f"what the {hazard} reflex does: {', '.join(actions)}")
        for hazard, actions in HAZARDS.items()
    }
    thresholds = {
        name: key
        for name, key in _dataclass_keys(SafetyPolicy).items()
        if name not in HAZARDS and name != "fence"
    }
    return {
        **hazards,
        "back_off_distance": _Key(float, 0.1, "how far a bumper's back_off drives (m)"),
        "slow_speed": _Key(float, 0.1, "the speed cap of slow (m/s)"),
        **thresholds,
        "geofence_rectangle": _Key(list[float], None, "[width, height] (m) centred on the start"),
        "geofence_circle": _Key(list[float], None, "[x, y, radius] (m)"),
        "geofence_polygon": _Key(list[Any], None, "[[x, y], ...] (m), at least three points"),
    }


#: The device tables and their keys (name -> key -> type, default, meaning).
DEVICE_TABLES: Mapping[str, Mapping[str, _Key]] = _device_tables()


@dataclass(frozen=True, slots=True)
class Profile:
    """A profile file, read and checked.

    Attributes:
        path: The file, or ``None`` for the empty profile (no file found).
        found_by: How it was found (``"--config"``, ``"$CHASSIS_SDK_CONFIG"``,
            ``"./chassis-sdk.toml"``, ``"user config dir"``), or ``""``.
        tables: Every table as written (device tables checked, command tables kept
            for the command line to check against each command's parser).
    """

    path: Path | None = None
    found_by: str = ""
    tables: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The file's path as text, for messages (``"no profile"`` when empty)."""
        return str(self.path) if self.path is not None else "no profile"

    def table(self, name: str) -> Mapping[str, Any]:
        """Table ``name`` (empty if the file has none)."""
        return self.tables.get(name, {})

    def get(self, table: str, key: str, default: Any = None) -> Any:
        """``[table] key``, or ``default``."""
        return self.table(table).get(key, default)

    @property
    def limits(self) -> MotionLimits | None:
        """``[limits]`` as `MotionLimits` (``None`` when the table is absent)."""
        values = self.table("limits")
        return MotionLimits(**values) if values else None

    @property
    def calibration(self) -> Calibration | None:
        """``[calibration]`` as [`Calibration`][chassis_sdk.Calibration] (``None`` when absent)."""
        values = self.table("calibration")
        return Calibration(**values) if values else None

    def battery(self) -> BatteryModel | None:
        """A new `BatteryModel` from ``[battery]`` (``None`` when absent): one per
        device, since a model holds the state of one pack."""
        values = dict(self.table("battery"))
        if not values:
            return None
        if "curve" in values:
            values["curve"] = [tuple(point) for point in values["curve"]]
        return BatteryModel(**values)

    @property
    def safety(self) -> SafetyPolicy | None:
        """``[safety]`` as a `SafetyPolicy` (``None`` when the table is absent)."""
        values = dict(self.table("safety"))
        if not values:
            return None
        distance = values.pop("back_off_distance", 0.1)
        speed = values.pop("slow_speed", 0.1)
        fences = [
            k for k in ("geofence_rectangle", "geofence_circle", "geofence_polygon") if k in values
        ]
        if len(fences) > 1:
            raise ValueError(f"one geofence, not {' and '.join(fences)}")
        fence: Geofence | None = None
        if "geofence_rectangle" in values:
            width, height = values.pop("geofence_rectangle")
            fence = Geofence.rectangle(width, height)
        elif "geofence_circle" in values:
            x, y, radius = values.pop("geofence_circle")
            fence = Geofence(centre=(x, y), radius=radius)
        elif "geofence_polygon" in values:
            fence = Geofence(tuple((float(x), float(y)) for x, y in values.pop("geofence_polygon")))
        for hazard in HAZARDS:
            if hazard in values:
                values[hazard] = Reflex(values[hazard], distance=distance, speed=speed)
        return SafetyPolicy(fence=fence, **values)

    def device_options(self) -> dict[str, Any]:
        """The keyword options of a device constructor the profile sets (nothing for
        what it leaves out, so each constructor's default holds)."""
        options: dict[str, Any] = {}
        robot = self.table("robot")
        for key in ("baudrate", "reconnect", "request_timeout", "link_timeout"):
            if key in robot:
                options[key] = robot[key]
        if "command_timeout" in self.table("deadman"):
            options["command_timeout"] = self.table("deadman")["command_timeout"]
        if (limits := self.limits) is not None:
            options["limits"] = limits
        if (calibration := self.calibration) is not None:
            options["calibration"] = calibration
        if (battery := self.battery()) is not None:
            options["battery"] = battery
        if (safety := self.safety) is not None:
            options["safety"] = safety
        return options


def user_profile_path() -> Path:
    """``chassis-sdk.toml`` in the user's configuration directory (it may not exist)."""
    import platformdirs

    return platformdirs.user_config_path("chassis-sdk") / PROFILE_NAME


def locate_profile(explicit: str | os.PathLike[str] | None = None) -> tuple[Path, str] | None:
    """The profile file in use and how it was found, or ``None`` when there is none.

    Raises:
        ProfileError: ``explicit`` or ``$CHASSIS_SDK_CONFIG`` names a file that does not
            exist (a named file that is missing is a mistake, not "no profile").
    """
    if explicit is not None:
        path = Path(explicit)
        if not path.is_file():
            raise ProfileError(f"--config {path}: no such file")
        return path, "--config"
    if named := os.environ.get(ENV_CONFIG):
        path = Path(named)
        if not path.is_file():
            raise ProfileError(f"${ENV_CONFIG}={named}: no such file")
        return path, f"${ENV_CONFIG}"
    here = Path(PROFILE_NAME)
    if here.is_file():
        return here, f"./{PROFILE_NAME}"
    user = user_profile_path()
    if user.is_file():
        return user, "user config dir"
    return None


def find_profile(explicit: str | os.PathLike[str] | None = None) -> Path | None:
    """The profile file in use (see `locate_profile`), or ``None``."""
    found = locate_profile(explicit)
    return found[0] if found is not None else None


def load_profile(config: str | os.PathLike[str] | Profile | None = None) -> Profile:
    """The profile ``config`` names (or the one found, or the empty profile), checked.

    Raises:
        ProfileError: The file is not TOML, or a table, key, type or value is wrong.
    """
    if isinstance(config, Profile):
        return config
    found = locate_profile(config)
    if found is None:
        return Profile()
    path, how = found
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(f"{path}: not TOML: {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ProfileError(f"{path}: cannot be read: {exc}") from None
    return Profile(path, how, check_tables(data, path))


def check_tables(data: Mapping[str, Any], path: Path | str) -> dict[str, dict[str, Any]]:
    """``data`` (a parsed profile) checked: every top-level entry is a known table, and
    every device table's keys, types and values are allowed.

    Raises:
        ProfileError: One line naming ``path``, the key and what is allowed.
    """
    tables: dict[str, dict[str, Any]] = {}
    known = sorted(DEVICE_TABLES) + sorted(COMMAND_TABLES)
    for name, table in data.items():
        if not isinstance(table, dict):
            raise ProfileError(
                f"{path}: {name} = {table!r} is outside any table (keys go in a table: "
                f"{', '.join(f'[{t}]' for t in sorted(DEVICE_TABLES))} or a command's)"
            )
        if name not in DEVICE_TABLES and name not in COMMAND_TABLES:
            raise ProfileError(
                f"{path}: unknown table [{name}]{did_you_mean(name, known)} "
                f"(allowed: {', '.join(f'[{t}]' for t in known)})"
            )
        if name in DEVICE_TABLES:
            _check_device_table(name, table, path)
        tables[name] = dict(table)
    _check_objects(tables, path)
    return tables


def _check_device_table(name: str, table: Mapping[str, Any], path: Path | str) -> None:
    keys = DEVICE_TABLES[name]
    for key, value in table.items():
        if key not in keys:
            raise ProfileError(
                f"{path}: [{name}] {key}: unknown key{did_you_mean(key, keys)} "
                f"(allowed: {', '.join(keys)})"
            )
        problem = _type_problem(value, keys[key].kind)
        if problem:
            raise ProfileError(f"{path}: [{name}] {key}: {problem}, got {value!r}")
    if name == "robot" and "device" in table:
        from . import names

        known = names()
        if table["device"] not in known:
            raise ProfileError(
                f"{path}: [robot] device: {table['device']!r} is not a known device "
                f"(known: {', '.join(known)})"
            )


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """``", did you mean 'x'?"`` for the closest of ``known``, or ``""``."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


def _check_objects(tables: Mapping[str, Mapping[str, Any]], path: Path | str) -> None:
    """Build each device table's object once, so a value out of range is refused when
    the file is read, not when a device opens."""
    profile = Profile(None, "", tables)
    checks: list[tuple[str, Callable[[], object]]] = [
        ("limits", lambda: profile.limits),
        ("calibration", lambda: profile.calibration),
        ("battery", profile.battery),
        ("safety", lambda: profile.safety),
    ]
    for name, build in checks:
        try:
            build()
        except (TypeError, ValueError) as exc:
            raise ProfileError(f"{path}: [{name}] {exc}") from None
    for table, key in (
        ("robot", "baudrate"),
        ("robot", "request_timeout"),
        ("robot", "link_timeout"),
        ("deadman", "command_timeout"),
    ):
        value = tables.get(table, {}).get(key)
        if value is not None and (not math.isfinite(value) or value <= 0):
            raise ProfileError(f"{path}: [{table}] {key}: must be > 0, got {value!r}")


def _type_problem(value: Any, kind: Any) -> str:
    """What is wrong with ``value`` as a ``kind`` (an annotation), or ``""``."""
    origin = get_origin(kind)
    if kind is typing.Any:
        return ""
    if origin in (typing.Union, types.UnionType):
        options = [k for k in get_args(kind) if k is not type(None)]
        problems = [_type_problem(value, k) for k in options]
        if all(problems):
            return " or ".join(problems)
        return ""
    if origin is Literal:
        allowed = get_args(kind)
        if value not in allowed:
            return f"must be one of {', '.join(repr(a) for a in allowed)}"
        return ""
    if kind is bool:
        return "" if isinstance(value, bool) else "must be true or false"
    if kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        return "" if ok else "must be a whole number"
    if kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if ok and not math.isfinite(value):
            return "must be a finite number"
        return "" if ok else "must be a number"
    if kind is str:
        return "" if isinstance(value, str) else "must be a string"
    if origin in (Sequence, list, tuple):
        if not isinstance(value, list):
            return "must be a list"
        args = get_args(kind)
        if origin is tuple:
            if len(value) != len(args):
                return f"must be a list of {len(args)}"
            for item, item_kind in zip(value, args, strict=True):
                if problem := _type_problem(item, item_kind):
                    return f"each item {problem}"
            return ""
        item_kind = args[0] if args else typing.Any
        for item in value:
            if problem := _type_problem(item, item_kind):
                return f"each item {problem}"
        return ""
    return ""


def update_profile(
    path: str | os.PathLike[str], table: str, values: Mapping[str, str | int | float | bool]
) -> None:
    """Set ``[table] key = value`` for each of ``values`` in the profile at ``path``,
    creating the file and the table as needed and keeping every comment and every other
    key as written (``chassis-sdk calibrate`` writes its factors so).

    The result is checked as `load_profile` would before it replaces the file
    (atomically), so a bad value never reaches the disk.

    Raises:
        ProfileError: The file is not TOML, or the result would not be a valid profile.
    """
    import tomlkit

    target = Path(path)
    text = target.read_text(encoding="utf-8") if target.exists() else ""
    try:
        document = tomlkit.parse(text)
    except tomlkit.exceptions.ParseError as exc:
        raise ProfileError(f"{target}: not TOML: {exc}") from None
    section = document.get(table)
    if section is None:
        section = tomlkit.table()
        document[table] = section
    for key, value in values.items():
        section[key] = value
    result = tomlkit.dumps(document)
    check_tables(tomllib.loads(result), target)
    real = target.resolve()  # a profile that is a link stays a link to the file it names
    temporary = real.with_name(f".{real.name}.tmp")
    temporary.write_text(result, encoding="utf-8")
    if real.exists():  # its permissions too (a profile may be readable by one user only)
        os.chmod(temporary, real.stat().st_mode & 0o7777)
    os.replace(temporary, real)


def profile_device(profile: Profile, device: str | None) -> str:
    """The device ``profile`` describes (``[robot] device``, default ``chassis``), which
    must be ``device`` when that is given.

    Raises:
        ProfileError: The profile names another device than ``device``.
    """
    named = profile.get("robot", "device")
    if named is not None and device is not None and named != device:
        raise ProfileError(f"{profile.name}: [robot] device is {named!r}, not {device!r}")
    return device or named or "chassis"


def profile_options(profile: Profile, overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword options (``port`` included) of the device ``profile`` describes,
    ``overrides`` beating the file.

    Raises:
        ProfileError: The profile names no port and none is given.
    """
    return _constructor_options(profile, overrides)


def _constructor_options(profile: Profile, overrides: Mapping[str, Any]) -> dict[str, Any]:
    options = profile.device_options()
    options.update(overrides)
    if "port" not in options:
        port = profile.get("robot", "port")
        if port is None:
            raise ProfileError(f"{profile.name}: no [robot] port, and no port given")
        options["port"] = port
    return options


class FromConfig:
    """``from_config()`` for a device class (a mixin of `Chassis` and
    `Board`)."""

    @classmethod
    def from_config(
        cls, config: str | os.PathLike[str] | Profile | None = None, **overrides: Any
    ) -> Self:
        """This device as the robot profile describes it (the file ``config`` names,
        else the one found; see `chassis_sdk.devices.config`), not yet open:
        ``async with Chassis.from_config() as robot:``. ``overrides`` beat the file
        (``port=``, ``limits=``, any option of the constructor).

        Raises:
            ProfileError: The profile is wrong, its ``[robot] device`` is another
                device, or it names no port and none is given.
        """
        return cls(**constructor_options(config, getattr(cls, "device_name", None), overrides))


def constructor_options(
    config: str | os.PathLike[str] | Profile | None,
    device: str | None,
    overrides: Mapping[str, Any],
) -> dict[str, Any]:
    """The keyword options (``port`` included) that build device ``device`` as the
    profile describes it, ``overrides`` beating the file: what ``from_config()`` of the
    async and the blocking classes pass to their constructor.

    Raises:
        ProfileError: The profile is wrong, its ``[robot] device`` is not ``device``,
            or it names no port and none is given.
    """
    loaded = load_profile(config)
    named = loaded.get("robot", "device")
    if named is not None and device is not None and named != device:
        raise ProfileError(
            f"{loaded.name}: [robot] device is {named!r}, not {device!r}: use open_robot()"
        )
    return _constructor_options(loaded, overrides)
