"""The ``chassis-sdk`` command line, built on the public API and the device registry.

Every command prints one clear line and exits non-zero on the everyday failures (no
such port, permission denied, nothing answering, the wrong device on the port, the
cable pulled) instead of a traceback. Commands loop over
`chassis_sdk.devices.profiles`: a device registered or installed as a package is
simulated, detected, recorded, replayed and driven like the built-in ones, and a
device's own commands (``demo``, ``info``, ``monitor``, ``plot``) come from its
profile.

Each command is a module with an ``add_parser(sub, names)`` that registers its
subparser and its ``func`` (see `chassis_sdk.cli.arguments`); `main` calls
``args.func`` and nothing else, so no command can fall through to another.

``CHASSIS_SDK_PORT`` and ``CHASSIS_SDK_DEVICE`` give the defaults of the port and of
``--device`` (``--protocol`` and ``CHASSIS_SDK_PROTOCOL`` are their old names, still
taken), so a robot's service file or a shell profile sets them once. The robot profile
(``--config FILE``, ``$CHASSIS_SDK_CONFIG``, ``./chassis-sdk.toml``, the user config
dir; `chassis_sdk.cli.profile`) gives every command's defaults below those: a flag
beats the environment, the environment beats the file, the file beats the default.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from typing import Any

from ..core.run import run
from ..devices import profiles
from ..devices.config import ProfileError, load_profile
from ..errors import ChassisError, MotionBlockedError, RequestTimeoutError
from . import (
    bridge_args,
    calibrate_command,
    clear_faults_command,
    config_command,
    demo_command,
    detect_command,
    dock_command,
    drive_command,
    estop_command,
    export_command,
    info_command,
    monitor_command,
    move_command,
    plot_command,
    ports_command,
    record_command,
    replay_command,
    ros2_args,
    serve_args,
    sim_command,
    teleop_args,
    web_args,
)
from .arguments import (
    ENV_BROKER,
    ENV_DEVICE,
    ENV_PORT,
    Command,
    Parser,
    UsageError,
    device_from_env,
)
from .common import blocked_line
from .info_command import EXIT_FAULT
from .profile import apply, config_argument, config_from_argv, subparsers

__all__ = ["ENV_BROKER", "ENV_DEVICE", "ENV_PORT", "build_parser", "main", "parse"]

#: Every command's module, in the order ``--help`` lists them.
COMMANDS = (
    demo_command,
    ports_command,
    detect_command,
    sim_command,
    info_command,
    monitor_command,
    estop_command,
    clear_faults_command,
    dock_command,
    drive_command,
    move_command,
    calibrate_command,
    teleop_args,
    bridge_args,
    ros2_args,
    web_args,
    record_command,
    export_command,
    serve_args,
    replay_command,
    plot_command,
    config_command,
)


class _Version(argparse.Action):
    """``--version``: the package's version, Python's, and which decoders run (the
    compiled fast path, or the pure code and why), then exit 0."""

    def __init__(self, option_strings: list[str], version: str, dest: str = "version") -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version and exit")
        self.version = version

    def __call__(self, parser: argparse.ArgumentParser, *_: Any) -> None:
        import platform

        from ..core import compiled
        from ..devices.board import protocol as _board  # noqa: F401  (each reports its path)
        from ..devices.chassis import protocol as _chassis  # noqa: F401

        print(
            f"chassis-sdk {self.version} (Python {platform.python_version()}, "
            f"decoders: {compiled.status()})"
        )
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The ``chassis-sdk`` parser, for the devices registered now: every command sets
    ``func``."""
    from .._version import __version__

    known = profiles()
    names = list(known)
    p = Parser(
        prog="chassis-sdk",
        description="Talk to robot chassis and controller boards, or simulate them.",
        epilog="devices: " + "; ".join(f"{n}: {d.summary}" for n, d in known.items()),
        allow_abbrev=False,
    )
    p.add_argument("--version", action=_Version, version=__version__)
    p.add_argument("-v", "--verbose", action="store_true", help="DEBUG logs with frame hex dumps")
    config_argument(p, top=True)
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.add_parser(sub, names)
    for command in sub.choices.values():
        config_argument(command)
        # No abbreviations: `--conf F` must not parse as --config while the profile,
        # read before parsing, was never found (nor `--max-lin` pass for another).
        command.allow_abbrev = False
    return p


def _sole(group: BaseExceptionGroup[Any]) -> BaseException | None:
    """The one exception a task group failed with, if it failed with only one."""
    leaves: list[BaseException] = []
    pending: list[BaseException] = [group]
    while pending:
        exc = pending.pop()
        if isinstance(exc, BaseExceptionGroup):
            pending.extend(exc.exceptions)
        else:
            leaves.append(exc)
    return leaves[0] if len(leaves) == 1 else None


def parse(parser: argparse.ArgumentParser, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """``argv`` parsed with the robot profile's settings as the defaults (the file is
    read first, since it gives the parsers their defaults); ``args.profile`` is the
    profile.

    Raises:
        ProfileError: The profile cannot be used (one line naming file and key).
    """
    words = list(sys.argv[1:] if argv is None else argv)
    profile = load_profile(config_from_argv(words))
    apply(parser, profile)
    args = parser.parse_args(words)
    args.profile = profile
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``chassis-sdk`` console script."""
    parser = build_parser()
    try:
        args = parse(parser, argv)
    except ProfileError as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 2
    # The CLI says what went wrong itself, in one line; the library's warnings (a
    # stale link, a reconnect) would only come first with a timestamp. -v shows all.
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.ERROR,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    # A usage error found after parsing is told with the command's usage, as argparse
    # tells its own.
    usage = subparsers(parser).get(args.command, parser)
    device = getattr(args, "device", None)
    if device is not None and device not in profiles():  # from the environment
        variable = (device_from_env() or (ENV_DEVICE, device))[0]
        usage.error(f"{variable}={device!r} is not a known device (known: {', '.join(profiles())})")
    command: Command = args.func
    try:
        job = command(args)  # a command without an event loop is done here
    except UsageError as exc:
        usage.error(str(exc))
    except BrokenPipeError:  # `| head`
        return 0
    except (ChassisError, ValueError, OSError) as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 1
    if job is None:
        return 0
    try:
        try:
            run(job)  # SIGTERM and SIGHUP unwind like Ctrl-C: the robot is stopped first
        except BaseExceptionGroup as group:  # a task group's one failure is told as itself
            sole = _sole(group)
            if sole is None:
                raise
            raise sole from None
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except RequestTimeoutError as exc:
        hint = f"is the device powered, and is it a {device or 'device'}?"
        print(f"chassis-sdk: {exc} ({hint})", file=sys.stderr)
        return 2
    except MotionBlockedError as exc:  # what blocks it, and what to do
        why = str(exc)
        if exc.reasons and exc.reasons != ("DRIVEN",):
            why = blocked_line(
                device or "device", getattr(args, "port", None) or "PORT", exc.reasons
            )
        print(f"chassis-sdk: {why}", file=sys.stderr)
        return EXIT_FAULT
    except (ChassisError, ValueError) as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 1
    return 0
