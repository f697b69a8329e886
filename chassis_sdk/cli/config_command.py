"""``chassis-sdk config [COMMAND]``: the profile in use, every setting it can hold with
the value in effect and where that came from (the file, the environment, or the
default); with ``COMMAND``, that command's settings too. ``--example`` prints a
commented profile to start from."""

from __future__ import annotations

import argparse
import json
import os
from collections.abc import Sequence
from importlib import resources
from typing import TYPE_CHECKING, Any

from ..devices.config import DEVICE_TABLES, Profile
from .arguments import UsageError
from .common import out
from .profile import SHARED, Setting, from_environment, settings, subparsers

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "device_settings"]

#: Device settings the environment can give the command line: (table, key) -> the
#: option it is (:data:`~chassis_sdk.cli.profile.SHARED`), whose variables beat it.
_SHARED_DEST = {where: dest for dest, where in SHARED.items()}
#: Tables whose defaults take effect only when the table is written: without
#: ``[battery]`` a device has no battery model, so no percentage is computed at all
#: (the other tables' defaults are the device's own when they are left out).
_ONLY_WHEN_WRITTEN = {"battery": "no [battery] table: no percentage is computed"}


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``config``."""
    p = sub.add_parser(
        "config", help="the profile in use: every setting, its value and where it came from"
    )
    p.add_argument("for_command", nargs="?", metavar="COMMAND", help="also this command's")
    p.add_argument("--json", action="store_true", help="one JSON object")
    p.add_argument("--example", action="store_true", help="print a commented example profile")
    p.set_defaults(func=config)


def device_settings(profile: Profile) -> dict[str, list[Setting]]:
    """Each device table's settings: the value in effect for the command line and its
    source (``"file"``, ``"$VARIABLE"``, ``"default"``, or ``"unused: ..."`` for a
    table that is not in effect unless written, such as ``[battery]``)."""
    found: dict[str, list[Setting]] = {}
    for table, keys in DEVICE_TABLES.items():
        rows = []
        if table in _ONLY_WHEN_WRITTEN and not profile.table(table):
            note = _ONLY_WHEN_WRITTEN[table]
            found[table] = [Setting(key, None, f"unused: {note}") for key in keys]
            continue
        for key, spec in keys.items():
            dest = _SHARED_DEST.get((table, key))
            variable = from_environment(dest) if dest is not None else None
            if variable is not None:
                rows.append(Setting(key, os.environ[variable[1:]], variable))
            elif key in profile.table(table):
                rows.append(Setting(key, profile.table(table)[key], "file"))
            else:
                rows.append(Setting(key, spec.default, "default"))
        found[table] = rows
    return found


def _parser(args: argparse.Namespace) -> argparse.ArgumentParser:
    from . import build_parser
    from .profile import apply

    parser = build_parser()
    apply(parser, args.profile)
    return parser


def config(args: argparse.Namespace) -> Job:
    """Print the effective settings (a command with no event loop: done here)."""
    if args.example:
        out(example_profile().rstrip())
        return None
    profile: Profile = args.profile
    tables = device_settings(profile)
    command_rows: list[Setting] = []
    if args.for_command is not None:
        commands = subparsers(_parser(args))
        if args.for_command not in commands or args.for_command == "config":
            known = ", ".join(n for n in commands if n != "config")
            raise UsageError(f"no command {args.for_command!r} (known: {known})")
        command_rows = settings(commands[args.for_command], args.for_command, profile)
    if args.json:
        document: dict[str, Any] = {
            "profile": str(profile.path) if profile.path else None,
            "found_by": profile.found_by or None,
            "tables": {t: {s.key: _row(s) for s in rows} for t, rows in tables.items()},
        }
        if args.for_command is not None:
            document["command"] = {
                "name": args.for_command,
                "settings": {s.key: _row(s) for s in command_rows},
            }
        out(json.dumps(document, default=str))
        return None
    if profile.path is None:
        out("profile: none found (--config FILE, $CHASSIS_SDK_CONFIG, ./chassis-sdk.toml,")
        out("         or the user config dir); `chassis-sdk config --example` prints one")
    else:
        out(f"profile: {profile.path} (found by {profile.found_by})")
    for table, rows in tables.items():
        _show(f"[{table}]", rows, profile)
    if args.for_command is not None:
        _show(f"[{args.for_command}] (and the shared settings it takes)", command_rows, profile)
    return None


def _row(setting: Setting) -> dict[str, Any]:
    return {"value": _plain(setting.value), "source": setting.source}


def _plain(value: Any) -> Any:
    """``value`` as JSON holds it (a path or an enum as its text)."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return str(value)


def _show(title: str, rows: list[Setting], profile: Profile) -> None:
    out()
    out(title)
    if rows and all(s.source.startswith("unused: ") for s in rows):
        out(f"  not in effect ({rows[0].source.removeprefix('unused: ')}); its keys:")
        out(f"  {', '.join(s.key for s in rows)}")
        return
    width = max((len(s.key) for s in rows), default=0)
    for s in rows:
        value = "-" if s.value is None else _text(s.value)
        source = f"{profile.name}" if s.source == "file" else s.source
        if s.source.startswith("["):
            source = f"{profile.name} {s.source}"
        out(f"  {s.key:<{width}}  {value:<24} {source}")


def _text(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return value
    return json.dumps(_plain(value))


def example_profile() -> str:
    """The commented example profile shipped in the package (and in the docs)."""
    return (
        resources.files("chassis_sdk.devices")
        .joinpath("chassis-sdk.example.toml")
        .read_text(encoding="utf-8")
    )
