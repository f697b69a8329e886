"""Export a capture (JSON lines or MCAP) as CSV: one file per stream.

The raw bytes are decoded again by the device's own code, never connected: the same
streams an application subscribes to (``telemetry``, ``power``, ``odometry``,
``events``, ... for a chassis; ``imu``, ``velocity``, ``battery``, ... for a board),
and the commands the host wrote where the recording holds them (one file per command
type). Every file starts with ``t``, seconds since the start of the recording; nested
fields are flattened (``wheels.front_left``), enums and flags are written by name.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from ..core.notifier import Notifier
from ..core.plain import json_schema, plain
from ..devices import profile
from .capture import read_capture

__all__ = ["Exported", "export_csv", "flatten"]


@dataclass(frozen=True, slots=True)
class Exported:
    """One CSV written: its path and how many rows it holds."""

    path: Path
    rows: int


def flatten(value: object, prefix: str = "") -> Iterator[tuple[str, Any]]:
    """``(column, value)`` pairs of a message: nested objects and sequences flattened
    with dots (``wheels.front_left``, ``accel.0``), a bare value as ``value``."""
    value = plain(value)
    if isinstance(value, dict):
        for key, item in value.items():
            yield from flatten(item, f"{prefix}{key}.")
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            yield from flatten(item, f"{prefix}{i}.")
    else:
        yield (prefix[:-1] or "value"), value


def _columns(schema: dict[str, Any], prefix: str = "") -> Iterator[str]:
    """The flattened columns of an object's JSON schema (`json_schema`), nested
    objects with dots; a sequence has none (its length is the row's)."""
    for key, prop in schema.get("properties", {}).items():
        if prop.get("type") == "object":
            yield from _columns(prop, f"{prefix}{key}.")
        elif prop.get("type") != "array":
            yield f"{prefix}{key}"


class _Tables:
    """CSV files opened as their first row arrives, each with the columns of that row's
    type (a field the row leaves out is an empty cell)."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self._files: dict[str, tuple[IO[str], Any, list[str]]] = {}
        self.rows: dict[str, int] = {}

    def write(self, name: str, t: float, message: object) -> None:
        row = {"t": round(t, 6), **dict(flatten(message))}
        entry = self._files.get(name)
        if entry is None:
            f = (self.directory / f"{name}.csv").open("w", newline="", encoding="utf-8")
            # Every field of the type, those the first row leaves out (None) too, then
            # what only the row says (the items of a sequence).
            columns = ["t", *_columns(json_schema(type(message)))]
            columns += [c for c in row if c not in columns]
            writer = csv.DictWriter(f, columns, extrasaction="ignore")
            writer.writeheader()
            entry = self._files[name] = (f, writer, columns)
            self.rows[name] = 0
        entry[1].writerow(row)
        self.rows[name] += 1

    def close(self) -> dict[str, Exported]:
        for f, _, _ in self._files.values():
            f.close()
        return {name: Exported(self.directory / f"{name}.csv", n) for name, n in self.rows.items()}


def export_csv(path: str | Path, directory: str | Path, device: str) -> dict[str, Exported]:
    """Write one CSV per stream (and per command type) of the capture ``path`` into
    ``directory`` (made if missing). Returns what was written, by name.

    Raises:
        ValueError: An unknown device, or a file that is not a capture.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    spec = profile(device)
    decoding = spec.device(str(path))  # never connected: it only decodes
    tables = _Tables(out)
    now = 0.0

    def listener(name: str) -> Any:
        return lambda message: tables.write(name, now, message)

    notifier = Notifier(decoding)
    for name in notifier.stream_names:
        notifier.listen(name, listener(name))
    try:
        for now, data in read_capture(path):
            decoding.feed(data, now)
        decoder = spec.codec.command_decoder()
        for t, data in read_capture(path, sent=True):
            for command in decoder.feed(data, t):
                tables.write(f"commands_{type(command).__name__}", t, command)
    finally:
        notifier.close()
        written = tables.close()
    return written
