"""What the commands' parsers share: the environment's defaults, argument types that
refuse what the SDK would refuse, the port and ``--device`` arguments, and how a
command registers itself.

Each command module has an ``add_parser(sub, names)`` that adds its subparser and sets
its ``func``: ``func(args)`` checks what it needs, does a command that needs no event
loop there and then (returning ``None``), or returns the coroutine that
`chassis_sdk.cli.main` runs under [`chassis_sdk.run`][chassis_sdk.run].
"""

from __future__ import annotations

import argparse
import ast
import difflib
import os
import re
from collections.abc import Callable, Coroutine, Sequence
from typing import TYPE_CHECKING, Any, NoReturn, TypeAlias

from ..core.validation import check_int, check_probability, check_real

if TYPE_CHECKING:
    Subparsers: TypeAlias = argparse._SubParsersAction[argparse.ArgumentParser]

__all__ = [
    "BAUD",
    "DRIVE_CEILING_ANGULAR",
    "DRIVE_CEILING_LINEAR",
    "DRIVE_MAX_ANGULAR",
    "DRIVE_MAX_LINEAR",
    "ENV_BROKER",
    "ENV_DEVICE",
    "ENV_PORT",
    "ENV_PROTOCOL",
    "TCP_PORT",
    "Command",
    "Job",
    "Parser",
    "Renamed",
    "UsageError",
    "arg_type",
    "chance",
    "check_record",
    "deadman_args",
    "device_arg",
    "device_from_env",
    "finite",
    "limit_args",
    "port_args",
    "positive",
    "record_arg",
    "require_port",
]

#: Environment variables that give defaults to the port, ``--device`` and ``--broker``.
ENV_PORT = "CHASSIS_SDK_PORT"
ENV_DEVICE = "CHASSIS_SDK_DEVICE"
#: The old name of ``CHASSIS_SDK_DEVICE``, still read when that is not set.
ENV_PROTOCOL = "CHASSIS_SDK_PROTOCOL"
ENV_BROKER = "CHASSIS_SDK_BROKER"
#: The default limits of every command that drives (``drive``, ``teleop``, ``serve``,
#: ``web``, ``ros2``, ``calibrate``): slow enough to walk beside.
DRIVE_MAX_LINEAR = 0.5
DRIVE_MAX_ANGULAR = 1.0
#: The most ``--max-linear``/``--max-angular`` (or the profile's ``[limits]``) may raise
#: them to: beyond, a typo (``--max-linear 10``) is refused while parsing. Faster is
#: for a program, through the API's ``MotionLimits``.
DRIVE_CEILING_LINEAR = 2.0
DRIVE_CEILING_ANGULAR = 4.0

#: What a command's ``func`` returns: the coroutine to run, or ``None`` when done.
Job: TypeAlias = Coroutine[Any, Any, None] | None
#: A command's ``func``: called with the parsed arguments.
Command: TypeAlias = Callable[[argparse.Namespace], Job]


class UsageError(Exception):
    """A command's arguments do not do (no port given, ...): ``main`` says so the way
    argparse does, with the command's usage and exit status 2."""


#: argparse's refusal of a word that is not one of the choices (its wording from 3.11 on).
_INVALID_CHOICE = re.compile(
    r"(?P<head>argument (?P<name>.+?): invalid choice: )"
    r"(?P<value>'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\")(?P<rest> \(choose from .*)",
    re.S,
)


def _action_name(action: argparse.Action) -> str:
    """The name argparse's messages give ``action`` (``--device``, ``COMMAND``, ...)."""
    if action.option_strings:
        return "/".join(action.option_strings)
    if action.metavar not in (None, argparse.SUPPRESS):
        return str(action.metavar)
    return str(action.dest)


class Parser(argparse.ArgumentParser):
    """The parser of ``chassis-sdk`` and of each command (subparsers take their parent's
    class): a word that is not one of the choices (a command, a device, ``start``/``stop``)
    is refused with the closest choice, if one is close (``did you mean 'monitor'?``),
    as Python 3.14's ``suggest_on_error`` does. (Through argparse's public hooks: the
    actions with choices are kept as they are added, and `error` adds the suggestion.)"""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        #: The arguments added to this parser itself (not to its groups) that take one
        #: of a set of words, the commands among them.
        self.choosing: list[argparse.Action] = []
        super().__init__(*args, **kwargs)

    def add_argument(self, *args: Any, **kwargs: Any) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        if action.choices is not None:
            self.choosing.append(action)
        return action

    def add_subparsers(self, **kwargs: Any) -> Any:
        action = super().add_subparsers(**kwargs)
        self.choosing.append(action)
        return action

    def error(self, message: str) -> NoReturn:
        found = _INVALID_CHOICE.fullmatch(message)
        if found is not None:
            value = ast.literal_eval(found["value"])
            for action in self.choosing:
                if _action_name(action) != found["name"] or action.choices is None:
                    continue
                names = [str(choice) for choice in action.choices]
                close = difflib.get_close_matches(value, names, n=1)
                if close:
                    message = (
                        f"{found['head']}{found['value']}, did you mean {close[0]!r}?"
                        f"{found['rest']}"
                    )
                break
        super().error(message)


class Renamed(argparse.Action):
    """An option that was renamed: given, it is refused naming the new spelling (hidden
    from ``--help``, and from the profile's tables, which read the new name)."""

    def __init__(self, option_strings: Sequence[str], dest: str, *, new: str, **kw: Any) -> None:
        kw.setdefault("default", argparse.SUPPRESS)
        super().__init__(option_strings, f"_renamed_{dest}", nargs="?", **kw)
        self.new = new

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        parser.error(f"argument {option_string}: renamed: use {self.new}")


#: What a failed conversion says, for the converters whose own error is Python's.
_CONVERTED: dict[Callable[[str], Any], str] = {float: "a number", int: "a whole number"}


def arg_type(convert: Callable[[str], Any], check: Callable[[Any], Any]) -> Callable[[str], Any]:
    """An argparse type that refuses what the SDK would refuse, before any port opens."""

    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except (TypeError, ValueError) as exc:  # `abc` for a float: not Python's words
            wanted = _CONVERTED.get(convert)
            raise argparse.ArgumentTypeError(
                f"{text!r} is not {wanted}" if wanted else str(exc)
            ) from None
        try:
            return check(value)
        except (TypeError, ValueError) as exc:  # a wrong type or a bad value: both refused
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


def finite(name: str) -> Callable[[str], Any]:
    """A finite real number, named ``name`` in the refusal."""
    return arg_type(float, lambda v: check_real(v, name))


def positive(name: str) -> Callable[[str], Any]:
    """A finite real number above zero, named ``name`` in the refusal."""
    return arg_type(float, lambda v: check_real(v, name, low=0, low_open=True))


def chance(name: str) -> Callable[[str], Any]:
    """A chance per event (a rate of faults): a finite number from 0 to 1, named ``name``
    in the refusal."""
    return arg_type(float, lambda v: check_probability(v, name))


#: A serial speed: a whole number from 1.
BAUD = arg_type(int, lambda v: check_int(v, "baudrate", low=1))
#: A TCP port to serve on: 0 to 65535 (0: any free one). Every ``--tcp``/``--port``-like
#: option takes it, so 99999 is refused while parsing (exit 2), not when binding.
TCP_PORT = arg_type(int, lambda v: check_int(v, "port", low=0, high=65535))


def port_args(p: argparse.ArgumentParser, *, required: bool = True) -> None:
    """``PORT`` (default ``$CHASSIS_SDK_PORT``) and ``-b/--baudrate``. With
    ``required=False`` no port means every serial port."""
    help_text = f"device path, pty path or socket://host:port (default: ${ENV_PORT})"
    if not required:
        help_text = f"the port (default: ${ENV_PORT}, else every serial port)"
    p.add_argument("port", nargs="?", default=os.environ.get(ENV_PORT) or None, help=help_text)
    p.add_argument("-b", "--baudrate", type=BAUD, default=115200, help="serial speed")


def limit_args(p: argparse.ArgumentParser, clamps: str = "") -> None:
    """``--max-linear`` and ``--max-angular`` (defaults `DRIVE_MAX_LINEAR`,
    `DRIVE_MAX_ANGULAR`, at most `DRIVE_CEILING_LINEAR`,
    `DRIVE_CEILING_ANGULAR`): what they clamp is named in the help (``clamps``)."""
    what = f" (clamps {clamps})" if clamps else ""
    p.add_argument(
        "--max-linear",
        type=_speed_limit("max_linear", DRIVE_CEILING_LINEAR, "m/s"),
        default=DRIVE_MAX_LINEAR,
        help=f"m/s{what}; default %(default)s, at most {DRIVE_CEILING_LINEAR:g}",
    )
    p.add_argument(
        "--max-angular",
        type=_speed_limit("max_angular", DRIVE_CEILING_ANGULAR, "rad/s"),
        default=DRIVE_MAX_ANGULAR,
        help=f"rad/s{what}; default %(default)s, at most {DRIVE_CEILING_ANGULAR:g}",
    )


def _speed_limit(name: str, ceiling: float, unit: str) -> Callable[[str], Any]:
    return arg_type(
        float, lambda v: check_real(v, name, low=0, low_open=True, high=ceiling, unit=unit)
    )


def deadman_args(p: argparse.ArgumentParser, sender: str) -> None:
    """``--command-timeout`` (0.5 s after ``sender``'s last message the robot stops) and
    ``--seconds`` (stop the command after this long)."""
    p.add_argument(
        "--command-timeout",
        type=positive("command_timeout"),
        default=0.5,
        help=f"stop this long after {sender}'s last message (s)",
    )
    p.add_argument("--seconds", type=positive("seconds"), help="stop after this long")


def record_arg(p: argparse.ArgumentParser) -> None:
    """``--record FILE`` (into ``args.record``), the one way every command that drives
    (``drive``, ``move``/``turn``/``goto``, ``teleop``, ``web``, ``serve``, ``ros2``,
    ``bridge``, ``calibrate``) records its session: the device's ``record=`` option,
    so the command's own frames are in the file beside the device's, and the robot
    coming to rest after the last zero (``chassis-sdk record`` cannot run beside a
    command that drives: the port has one owner). The command calls `check_record`
    before its port opens."""
    p.add_argument(
        "--record",
        metavar="FILE",
        help="also record the session, both ways, until the robot is still: FILE.jsonl "
        "(raw bytes) or FILE.mcap (decoded too, for Foxglove; the foxglove extra)",
    )


def check_record(args: argparse.Namespace, command: str) -> str | None:
    """The ``--record`` file of ``args`` (`record_arg`), checked before any port opens:
    its directory exists and is writable, and for ``FILE.mcap`` the foxglove extra is
    installed (`chassis_sdk.cli.extras.require`, as ``COMMAND --record``). ``None``
    when not given.

    Raises:
        ChassisError: The file cannot be written, or the extra is missing (one line).
    """
    file: str | None = getattr(args, "record", None)
    if file is None:
        return None
    from .captures import writable
    from .extras import require

    writable(file, "--record")
    if os.path.splitext(file)[1].lower() == ".mcap":
        require(f"{command} --record", "foxglove")
    return file


def device_from_env() -> tuple[str, str] | None:
    """``(variable, name)`` of the device the environment names (``$CHASSIS_SDK_DEVICE``,
    else its old name ``$CHASSIS_SDK_PROTOCOL``), or ``None``."""
    for variable in (ENV_DEVICE, ENV_PROTOCOL):
        if value := os.environ.get(variable):
            return variable, value
    return None


def device_arg(
    p: argparse.ArgumentParser,
    names: Sequence[str],
    *,
    detected: bool = False,
    default: str | None = None,
    help_text: str | None = None,
) -> None:
    """``--device NAME`` (into ``args.device``), with ``--protocol`` its old name, still
    taken but not shown.

    The default is ``default`` if given, else ``$CHASSIS_SDK_DEVICE`` (or its old name
    ``$CHASSIS_SDK_PROTOCOL``), else
    ``None`` when the device is ``detected`` (from a capture or a port), else the
    first known device. An unknown name from the environment is not checked here
    (argparse checks only what is typed): ``main`` refuses it.
    """
    names = list(names)
    if default is None:
        from_env = device_from_env()
        default = from_env[1] if from_env else (None if detected else names[0])
        help_text = help_text or (
            f"which device (default: ${ENV_DEVICE}, else "
            + ("detected)" if detected else f"{names[0]})")
        )
    p.add_argument("--device", choices=names, default=default, help=help_text)
    # The old name: the same destination, no default of its own, no line in --help.
    p.add_argument(
        "--protocol",
        choices=names,
        dest="device",
        default=argparse.SUPPRESS,
        help=argparse.SUPPRESS,
    )


def require_port(args: argparse.Namespace) -> str:
    """``args.port``, or a `UsageError` saying how to give one."""
    port: str | None = args.port
    if port is None:
        raise UsageError(f"no port given (give PORT, or set {ENV_PORT})")
    return port
