"""The robot profile on the command line: a flag beats the environment, the
environment beats the file, the file beats the default.

`apply` turns the profile into the defaults of every command's parser before the
command line is parsed, so each command reads its settings as it always has
(``args.max_linear``) and cannot forget the file. The device tables give the settings
many commands share (``[robot] port``, ``[limits] max_linear``, ``[deadman]
command_timeout``, ...); a command's own table (``[web]``) gives its own options by
their long names (``--max-linear`` is ``max_linear``), checked by the option's own
type, so the file refuses exactly what the flag would.

`settings` says, for ``chassis-sdk config``, what each setting is and where it
came from.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from ..devices.config import COMMAND_TABLES, Profile, ProfileError, did_you_mean
from .arguments import ENV_BROKER, ENV_DEVICE, ENV_PORT, ENV_PROTOCOL

__all__ = [
    "RENAMED",
    "SHARED",
    "TABLE_KEYS",
    "Setting",
    "apply",
    "config_argument",
    "device_options",
    "from_environment",
    "options_of",
    "settings",
    "subparsers",
    "table_options",
]

#: Settings many commands share: the destination of the option -> (table, key).
SHARED: Mapping[str, tuple[str, str]] = {
    "port": ("robot", "port"),
    "baudrate": ("robot", "baudrate"),
    "device": ("robot", "device"),
    "max_linear": ("limits", "max_linear"),
    "max_angular": ("limits", "max_angular"),
    "command_timeout": ("deadman", "command_timeout"),
}
#: Commands that do not take ``[robot] port``: ``ports`` lists every port unless one
#: is typed.
_NO_PROFILE_PORT = frozenset({"ports"})
#: Destinations the environment may give: dest -> its variables, first wins.
_ENVIRONMENT: Mapping[str, tuple[str, ...]] = {
    "port": (ENV_PORT,),
    "device": (ENV_DEVICE, ENV_PROTOCOL),
    "broker": (ENV_BROKER,),
}
_NOT_SETTINGS = frozenset({"help", "config", "verbose", "version", "func", "command"})
#: Every command table may name the device it opens: its port, speed and kind.
_DEVICE_KEYS = frozenset({"port", "baudrate", "device"})
#: What each command's table may set, besides :data:`_DEVICE_KEYS`: settings, never an
#: action or a one-shot input (``estop``'s ``release``, ``calibrate``'s ``measured``,
#: ``drive``'s ``linear``: a file must not turn one command into another, or make a
#: robot move on a bare command), never a flag that loosens safety and that no flag
#: could undo (``serve``'s ``no_token``, ``bridge``'s ``take_over``), never a secret
#: (``serve``'s ``token``: ``token_file`` names the file). A flag that is true in the
#: file (``read_only``) holds for every run of the command: lift it with another
#: profile (``--config``).
TABLE_KEYS: Mapping[str, frozenset[str]] = {
    name: frozenset(keys.split())
    for name, keys in {
        "bridge": "broker robot_id prefix rate read_only require_timestamp username "
        "password_file tls cafile",
        "calibrate": "distance turns speed write max_linear max_angular timeout",
        "clear-faults": "timeout json",
        "demo": "",
        "detect": "seconds",
        "dock": "timeout json",
        "drive": "max_linear max_angular timeout",
        "estop": "timeout json",
        "export": "",
        "info": "timeout",
        "monitor": "json",
        "move": "speed tolerance timeout max_linear max_angular",
        "turn": "rate tolerance timeout max_linear max_angular",
        "goto": "speed tolerance timeout max_linear max_angular",
        "plot": "",
        "ports": "json",
        "record": "ros2 namespace",
        "replay": "json speed",
        "ros2": "namespace frame_prefix domain_id stamped no_tf no_description read_only "
        "localhost static_peer max_linear max_angular command_timeout",
        "serve": "foxglove_port host read_only allow_origin token_file record max_linear "
        "max_angular command_timeout",
        "sim": "tcp noise bit_flips drop reply_delay world",
        "teleop": "max_linear max_angular command_timeout key_timeout speed joystick "
        "enable_button linear_axis angular_axis joy_scale_linear joy_scale_angular "
        "joy_deadzone joy_timeout",
        "web": "host http_port read_only token_file allow_origin enable_button linear_axis "
        "angular_axis pad_scale max_linear max_angular command_timeout",
    }.items()
}

#: Keys that once meant something else in a command's table: (table, old key) -> the new
#: key. One name has one meaning in every table (``port`` is the serial port, as in
#: ``[robot] port``), so a value that can only have been meant the old way (a number for
#: a port) is refused naming the new key rather than read as a device path.
RENAMED: Mapping[tuple[str, str], str] = {("web", "port"): "http_port"}


@dataclass(frozen=True, slots=True)
class Setting:
    """One setting of a command, as ``chassis-sdk config`` prints it.

    Attributes:
        key: Its key in the command's table (the long option without ``--``).
        value: What the command will use.
        source: ``"default"``, ``"[table] key"`` of the file, or ``"$VARIABLE"``.
    """

    key: str
    value: Any
    source: str


def config_argument(p: argparse.ArgumentParser, *, top: bool = False) -> None:
    """``--config FILE``: on the top parser, and on each command's (so it may come
    before or after the command's name)."""
    p.add_argument(
        "--config",
        metavar="FILE",
        default=None if top else argparse.SUPPRESS,
        help="the robot profile (default: $CHASSIS_SDK_CONFIG, ./chassis-sdk.toml, "
        "then the user config dir)",
    )


def config_from_argv(argv: Sequence[str]) -> str | None:
    """The ``--config FILE`` in ``argv`` (the last one, as argparse would take), read
    before parsing since the file gives the parsers their defaults."""
    found = None
    words = list(argv)
    for i, word in enumerate(words):
        if word == "--":
            break
        if word == "--config" and i + 1 < len(words):
            found = words[i + 1]
        elif word.startswith("--config="):
            found = word.split("=", 1)[1]
    return found


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Each command's parser by its name."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def table_options(name: str, p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """The options command ``name``'s table may set (`TABLE_KEYS`), by key."""
    allowed = TABLE_KEYS.get(name, frozenset()) | _DEVICE_KEYS
    return {key: action for key, action in options_of(p).items() if key in allowed}


def options_of(p: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """A command's settings by their key in its table: each long option without its
    dashes (``-`` read as ``_``), and the positional ``port``."""
    found: dict[str, argparse.Action] = {}
    for action in p._actions:
        if action.dest in _NOT_SETTINGS or action.help == argparse.SUPPRESS:
            continue
        longs = [o for o in action.option_strings if o.startswith("--")]
        if longs:
            found[longs[0][2:].replace("-", "_")] = action
        elif not action.option_strings and action.dest == "port":
            found.setdefault("port", action)
    return found


def from_environment(dest: str) -> str | None:
    """``"$VARIABLE"`` when the environment gives option ``dest`` (it beats the file),
    else ``None``."""
    return _from_environment(dest)


def _from_environment(dest: str) -> str | None:
    for variable in _ENVIRONMENT.get(dest, ()):
        if os.environ.get(variable):
            return f"${variable}"
    return None


def _convert(action: argparse.Action, value: Any, where: str) -> Any:
    """``value`` from the file as ``action`` would take it from the command line.

    Raises:
        ProfileError: Refused as the flag would be, naming ``where``.
    """
    if isinstance(action, argparse._StoreConstAction):  # store_true, store_false too
        if not isinstance(value, bool):
            raise ProfileError(f"{where}: must be true or false, got {value!r}")
        return action.const if value else action.default
    if isinstance(action, argparse.BooleanOptionalAction):
        if not isinstance(value, bool):
            raise ProfileError(f"{where}: must be true or false, got {value!r}")
        return value
    if isinstance(action, argparse._CountAction):
        if not isinstance(value, int) or isinstance(value, bool) or value < 0:
            raise ProfileError(f"{where}: must be a whole number >= 0, got {value!r}")
        return value
    many = isinstance(action, argparse._AppendAction) or action.nargs in ("*", "+")
    if many:
        if not isinstance(value, list):
            raise ProfileError(f"{where}: must be a list, got {value!r}")
        return [_one(action, item, where) for item in value]
    if isinstance(action.nargs, int):
        if not isinstance(value, list) or len(value) != action.nargs:
            raise ProfileError(f"{where}: must be a list of {action.nargs}, got {value!r}")
        return [_one(action, item, where) for item in value]
    return _one(action, value, where)


def _one(action: argparse.Action, value: Any, where: str) -> Any:
    if isinstance(value, bool | list | dict) or value is None:
        raise ProfileError(f"{where}: must be a {_kind(action)}, got {value!r}")
    converted: Any = str(value)
    if action.type is not None:
        convert: Any = action.type
        try:
            converted = convert(str(value))
        except (argparse.ArgumentTypeError, TypeError, ValueError) as exc:
            raise ProfileError(f"{where}: {exc}") from None
    if action.choices is not None and converted not in action.choices:
        allowed = ", ".join(repr(c) for c in action.choices)
        raise ProfileError(f"{where}: must be one of {allowed}, got {value!r}")
    return converted


def _kind(action: argparse.Action) -> str:
    if action.type in (int, float) or getattr(action.type, "__name__", "") == "parse":
        return "number or string"
    return "string"


def _shared(name: str, p: argparse.ArgumentParser) -> Iterator[tuple[argparse.Action, str, str]]:
    """(action, table, key) of each shared setting command ``name``'s parser has."""
    by_dest: dict[str, argparse.Action] = {}
    for a in p._actions:
        if a.help != argparse.SUPPRESS:
            by_dest.setdefault(a.dest, a)
    for dest, (table, key) in SHARED.items():
        if dest == "port" and name in _NO_PROFILE_PORT:
            continue
        if (action := by_dest.get(dest)) is not None:
            yield action, table, key


def apply(parser: argparse.ArgumentParser, profile: Profile) -> None:
    """Give every command's parser the profile's settings as defaults (the environment
    keeps its place above the file).

    Raises:
        ProfileError: A command's table names an option the command does not have, or
            a value it would refuse; or the profile names a table of no command.
    """
    commands = subparsers(parser)
    for table in profile.tables:
        if table in COMMAND_TABLES and table not in commands:
            raise ProfileError(f"{profile.name}: [{table}]: no such command here")
    for name, p in commands.items():
        defaults: dict[str, Any] = {}
        for action, table, key in _shared(name, p):
            value = profile.get(table, key)
            if value is None or _from_environment(action.dest):
                continue
            defaults[action.dest] = _convert(action, value, f"{profile.name}: [{table}] {key}")
        own = profile.table(name)
        options = table_options(name, p)
        for key, value in own.items():
            new = RENAMED.get((name, key))
            if new is not None and not isinstance(value, str):
                raise ProfileError(
                    f"{profile.name}: [{name}] {key} = {value!r}: renamed {new} "
                    f"({key} is the serial port here, as in [robot] {key})"
                )
            found = options.get(key)
            if found is None:
                raise ProfileError(_refusal(profile, name, key, options, options_of(p)))
            where = f"{profile.name}: [{name}] {key}"
            converted = _convert(found, value, where)
            if not _from_environment(found.dest):  # the environment beats the file
                defaults[found.dest] = converted
        if defaults:
            p.set_defaults(**defaults)


def _refusal(
    profile: Profile,
    name: str,
    key: str,
    allowed: Mapping[str, argparse.Action],
    every: Mapping[str, argparse.Action],
) -> str:
    """Why ``[name] key`` is refused: no such option, or one that is not a setting."""
    where = f"{profile.name}: [{name}] {key}: "
    keys = ", ".join(allowed) or "none"
    if key in every:
        return (
            f"{where}--{key.replace('_', '-')} is given on the command line only (an "
            f"action or a one-shot input, not a setting; allowed here: {keys})"
        )
    return (
        f"{where}`chassis-sdk {name}` has no such option{did_you_mean(key, every)} "
        f"(allowed here: {keys})"
    )


def settings(p: argparse.ArgumentParser, name: str, profile: Profile) -> list[Setting]:
    """What command ``name`` (parser ``p``, with `apply` done) will use for each
    of its settings, and where each came from."""
    shared = {action.dest: (table, key) for action, table, key in _shared(name, p)}
    own = profile.table(name)
    found = []
    for key, action in table_options(name, p).items():
        value = p.get_default(action.dest)
        if (variable := _from_environment(action.dest)) is not None:
            source = variable
        elif key in own:
            source = f"[{name}] {key}"
        elif action.dest in shared and profile.get(*shared[action.dest]) is not None:
            source = "[{}] {}".format(*shared[action.dest])
        else:
            source = "default"
        found.append(Setting(key, value, source))
    return found


def device_options(args: argparse.Namespace, **command: Any) -> dict[str, Any]:
    """The keyword options a command opens its device with: the command's own choices
    (``reconnect=True``), beaten by the profile's device settings (``[robot]``,
    ``[limits]``, ``[calibration]``, ``[battery]``, ``[deadman]``), beaten by the
    command line (``--baudrate``, ``--max-linear``, ``--max-angular``,
    ``--command-timeout``, which already hold the file's values when not typed)."""
    import dataclasses

    from ..core.motion import MotionLimits

    profile: Profile = getattr(args, "profile", None) or Profile()
    options = {**command, **profile.device_options()}
    if getattr(args, "baudrate", None) is not None:
        options["baudrate"] = args.baudrate
    if getattr(args, "command_timeout", None) is not None:
        options["command_timeout"] = args.command_timeout
    speeds = {
        key: getattr(args, key)
        for key in ("max_linear", "max_angular")
        if getattr(args, key, None) is not None
    }
    if speeds:
        limits = options.get("limits") or command.get("limits") or MotionLimits()
        options["limits"] = dataclasses.replace(limits, **speeds)
    return options
